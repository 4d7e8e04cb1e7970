"""Camera-centre CSV (`--gnss`): `image,X,Y,Z[,omega,phi,kappa][,sX,sY,sZ]` in a map CRS, angles may be blank.

The EOP columns of INTERFACES.md where only the projection centre matters (GNSS/RTK/PPK camera centres used as
priors): omega/phi/kappa may be absent or blank (NaN in memory, blank when written), sX,sY,sZ (m) optional (NaN
when blank).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import formatted, read_table, write_columns
from dgcal.fields.io.formats import EOP

CENTRE_COLUMNS = ("image", "X", "Y", "Z", "omega", "phi", "kappa", "sX", "sY", "sZ")


CENTRE_ANGLES = ("omega", "phi", "kappa")
CENTRE_SIGMAS = ("sx", "sy", "sz")


def read_centres(path: str | Path) -> EOP:
    """GNSS camera centres: an EOP CSV `image,X,Y,Z[,omega,phi,kappa][,sX,sY,sZ]` in the map CRS (m, deg) whose
    angles and sigmas may be blank or absent (NaN: angles unknown, sigma the triangulation's default); a full
    EOP file (angles and all six sigmas) reads the same. Every given value is checked; errors name the line."""
    return read_centres_with_flights(path)[0]


def read_centres_with_flights(path: str | Path) -> tuple[EOP, np.ndarray | None]:
    """`read_centres` and the optional `flight` column (a label per row; None without the column)."""
    tab = read_table(path, ("image", "x", "y", "z"),
                     CENTRE_ANGLES + CENTRE_SIGMAS + ("somega", "sphi", "skappa", "flight"),
                     text=("image", "flight") + CENTRE_ANGLES + CENTRE_SIGMAS + ("somega", "sphi", "skappa"))
    image = tab["image"]
    n = len(image)
    seen: dict[str, int] = {}
    for i, name in enumerate(image.tolist()):
        if name in seen:
            raise InputError(f"image {name!r} appears twice", tab.path, int(tab.lines[i]), "image")
        seen[name] = i
    for c in ("x", "y", "z"):
        validate.values_in_range(tab[c], -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, tab.path, c,
                                 tab.lines, unit="m")
    xyz = np.column_stack([tab["x"], tab["y"], tab["z"]])
    opk = np.column_stack([_blank_floats(tab, c) for c in CENTRE_ANGLES])
    for j, c in enumerate(CENTRE_ANGLES):
        validate.values_in_range(opk[:, j], -validate.MAX_ANGLE_DEG, validate.MAX_ANGLE_DEG, tab.path, c, tab.lines,
                                 allow_nan=True, unit="deg")
    sig = np.full((n, 6), np.nan)
    for j, c in enumerate(CENTRE_SIGMAS):
        sig[:, j] = _blank_floats(tab, c)
        validate.positive_values(sig[:, j], tab.path, c, tab.lines, allow_nan=True, hi=validate.MAX_COORDINATE_M,
                                 what="sigma")
    for j, c in enumerate(("somega", "sphi", "skappa")):
        sig[:, 3 + j] = _blank_floats(tab, c)
        validate.positive_values(sig[:, 3 + j], tab.path, c, tab.lines, allow_nan=True, hi=360.0, what="sigma")
    flights = None
    if "flight" in tab:
        flights = np.array([str(v).strip() for v in tab["flight"].tolist()], dtype=object)
        if (flights == "").any():
            i = int(np.argmax(flights == ""))
            raise InputError("blank flight", tab.path, int(tab.lines[i]), "flight")
    return EOP(image, xyz, opk, sig, None, tab.lines, tab.path), flights


def _blank_floats(tab, name: str) -> np.ndarray:
    """A text column as floats, blank cells NaN (a column the file lacks: all NaN); InputError naming the line."""
    if name not in tab:
        return np.full(len(tab), np.nan)
    out = np.full(len(tab), np.nan)
    for i, v in enumerate(tab[name].tolist()):
        v = str(v).strip()
        if v and v.lower() != "nan":
            try:
                out[i] = float(v) if v.isascii() else float("x")
            except ValueError:
                raise InputError(f"not a number: {v[:40]!r}", tab.path, int(tab.lines[i]), name) from None
    return out


def _cells(values: np.ndarray, fmt: str) -> list[str]:
    """Formatted cells, blank where the value is NaN."""
    return ["" if not np.isfinite(v) else fmt % v for v in np.asarray(values, float).tolist()]


def write_centres(path: str | Path, eop: EOP) -> None:
    """Write camera centres `image,X,Y,Z,omega,phi,kappa,sX,sY,sZ` (angles and sigmas blank where NaN; atomic)."""
    n = len(eop)
    sig = eop.sigma[:, :3] if eop.sigma is not None else np.full((n, 3), np.nan)
    cols = [list(map(str, eop.image))] + [formatted(eop.xyz[:, j], "%.4f") for j in range(3)]
    cols += [_cells(eop.opk[:, j], "%.6f") for j in range(3)] + [_cells(sig[:, j], "%.4f") for j in range(3)]
    write_columns(path, list(CENTRE_COLUMNS), cols)
