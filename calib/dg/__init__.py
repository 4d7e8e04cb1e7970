"""Direct georeferencing with a calibrated payload: DG EOPs, check-point accuracy, single-image georeferencing, DEMs."""
