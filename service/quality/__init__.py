"""Quality engineering, pure: control charts, capability and run rules (``spc``), and the
type-1 gauge study (``gauge_study``). Numbers in, dataclasses out; no I/O."""
