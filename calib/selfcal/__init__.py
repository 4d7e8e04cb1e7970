"""Calibrating a camera from images of a target field: detection, self-calibrating bundle adjustment, diagnostics."""
