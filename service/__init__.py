"""shaftgauge: lathe-side shaft diameter measurement with a line laser and a camera."""
