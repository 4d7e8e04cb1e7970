"""Positioning and orientation: IMU and GNSS readers, time, GNSS front end, GNSS/INS smoothing."""
