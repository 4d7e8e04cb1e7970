"""Robust losses rho(e^2) of whitened residual norms e, and their IRLS weights rho'(e^2)."""
from __future__ import annotations

import numpy as np

LOSSES = ("none", "huber", "cauchy")


def robust_cost_and_weight(loss: str, scale: float, e2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cost rho(e^2) (in units of e^2) and weight rho'(e^2) per item; `scale` is where the loss turns robust."""
    if loss == "none":
        return e2, np.ones_like(e2)
    c2 = scale * scale
    if loss == "huber":
        e = np.sqrt(e2)
        inl = e2 <= c2
        return np.where(inl, e2, 2 * scale * e - c2), np.where(inl, 1.0, scale / np.maximum(e, 1e-300))
    if loss == "cauchy":
        return c2 * np.log1p(e2 / c2), 1.0 / (1.0 + e2 / c2)
    raise ValueError(f"unknown loss {loss!r} (one of {', '.join(LOSSES)})")
