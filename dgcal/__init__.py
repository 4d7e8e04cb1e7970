"""dgcal: calibration of UAV photogrammetric payloads for direct georeferencing (command-line front end)."""
__version__ = "0.1.0"
