"""Quality engineering, pure: control charts, capability and run rules (``spc``), the
type-1 gauge study (``gauge_study``) and one record per part (``parts``). Numbers in,
dataclasses out; no I/O."""
