"""What a camera is: camera models, camera files of dgcal and other software, conversions between models."""
