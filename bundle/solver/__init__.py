"""The one sparse photogrammetric least-squares engine: residual blocks, Levenberg-Marquardt with the points
eliminated by Schur complement, robust losses and covariance recovery. Self-calibration, aerial triangulation
and the integrated mounting adjustment (and the joint mounting method) are problems built on it.
"""
