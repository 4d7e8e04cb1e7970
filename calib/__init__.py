"""Camera models, target detection, intrinsic and system calibration, direct georeferencing."""
