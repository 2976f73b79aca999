"""Hardware and network boundaries, each behind a small interface with a real and a simulated
implementation: ``camera`` (GigE Vision through Aravis), ``sim`` (the simulated rig and GigE
camera), and later ``plc`` (Modbus TCP)."""
