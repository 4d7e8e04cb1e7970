"""Command-line options checked where argparse reads them: a value out of its physical range (a negative sigma, a
significance level of 2, a NaN) or an unknown constellation letter is a usage error naming the option (exit 2),
never a silent result."""
from __future__ import annotations

import argparse
import math


def _number(text: str, kind=float) -> float:
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a {'whole ' if kind is int else ''}number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, not {text}")
    return v


def finite(text: str) -> float:
    """Any finite number."""
    return _number(text)


def positive(text: str) -> float:
    """A finite number > 0 (sigmas, sizes, rates, durations)."""
    v = _number(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, not {text}")
    return v


def non_negative(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text)
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, not {text}")
    return v


def fraction(text: str) -> float:
    """A share within [0, 1]."""
    v = _number(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within 0..1, not {text}")
    return v


def probability(text: str) -> float:
    """A significance level or probability strictly between 0 and 1."""
    v = _number(text)
    if not 0.0 < v < 1.0:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), not {text}")
    return v


def elevation_deg(text: str) -> float:
    """An elevation angle within [0, 90) degrees."""
    v = _number(text)
    if not 0.0 <= v < 90.0:
        raise argparse.ArgumentTypeError(f"must be within 0..90 degrees, not {text}")
    return v


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    v = int(_number(text, int))
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, not {text}")
    return v


def constellations(text: str) -> tuple[str, ...]:
    """Constellation letters of G, E, C, J, R (case ignored), in order, each once."""
    letters = str(text).upper()
    bad = sorted(set(letters) - set("GECJR"))
    if not letters or bad:
        raise argparse.ArgumentTypeError(f"letters of G, E, C, J, R, not {text!r}")
    return tuple(dict.fromkeys(letters))
