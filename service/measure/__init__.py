"""Pure measurement core: one frame and a calibration in, one measurement out.

The data path shows in the module names: ``stripe`` (image -> sub-pixel centres),
``triangulate`` (centres -> 3-D points on the light plane), ``section`` (3-D points -> 2-D points
on the plane perpendicular to the shaft axis), ``fit`` (2-D points -> circle or ellipse) and
``diameter`` (the whole chain for one frame). Nothing here does I/O or keeps global state.
"""
