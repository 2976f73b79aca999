"""Cameras: one interface (``base.Camera``), an Aravis implementation for any GigE Vision camera
(and Aravis's in-process fake), and a pure-Python simulated camera (``rig.RigCamera``)."""
