"""Simulators of calibration data sets with known truth.

Each module that defines `NAME`, `HELP`, `add_arguments(parser)` and `run(args)` becomes a
`dgcal simulate NAME` sub-command; every simulator also has a plain Python entry point.
"""
