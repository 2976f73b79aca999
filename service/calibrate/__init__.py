"""Pure calibration math on OpenCV: images in, calibration pieces and quality figures out.

``intrinsics`` (chessboard -> camera matrix, distortion), ``plane`` (board poses + laser line ->
light plane), ``axis`` (board clamped between the centres at several rotations -> spindle axis),
``report`` (verdicts). Failures are values with a reason that says what to do.
"""
