"""Inertial data and trajectories: IMU data and error models, navigation frame, interpolation, SBET."""
