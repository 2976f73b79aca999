"""Quality engineering, pure: control charts, capability and run rules (``spc``), and the
type-1 gauge study (``gauge_study``), one record per part (``parts``). Numbers in, dataclasses out; no I/O."""
