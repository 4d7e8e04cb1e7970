"""Simulators of calibration data sets with known truth: plain library functions that simulate a data set
and write it (with `truth.json`) to a folder. Their command line, `dgcal simulate NAME`, is in
dgcal.simulators (one module per sub-command).
"""
