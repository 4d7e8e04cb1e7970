"""The GNSS/INS batch smoother (gtsam): factors, IMU preintegration, initial values, covariances, output."""
