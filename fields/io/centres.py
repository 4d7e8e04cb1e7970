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


def read_centres(path: str | Path) -> EOP:
    """Read camera centres `image,X,Y,Z[,omega,phi,kappa][,sX,sY,sZ]` (m, deg; blanks = not given, NaN)."""
    tab = read_table(path, ("image", "x", "y", "z"), ("omega", "phi", "kappa", "sx", "sy", "sz"))
    for c in ("x", "y", "z"):
        validate.values_in_range(tab[c], -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, tab.path, c,
                                 tab.lines, unit="m")
    n = len(tab)
    opk = np.column_stack([tab.get(c, np.full(n, np.nan)) for c in ("omega", "phi", "kappa")])
    for j, c in enumerate(("omega", "phi", "kappa")):
        validate.values_in_range(opk[:, j], -validate.MAX_ANGLE_DEG, validate.MAX_ANGLE_DEG, tab.path, c, tab.lines,
                                 allow_nan=True, unit="deg")
    sig = None
    if any(c in tab for c in ("sx", "sy", "sz")):
        s3 = np.column_stack([tab.get(c, np.full(n, np.nan)) for c in ("sx", "sy", "sz")])
        for j, c in enumerate(("sx", "sy", "sz")):
            validate.positive_values(s3[:, j], tab.path, c, tab.lines, allow_nan=True, hi=validate.MAX_COORDINATE_M,
                                     what="sigma")
        sig = np.column_stack([s3, np.full((n, 3), np.nan)])
    image = np.array([str(v) for v in tab["image"]], dtype=object)
    _, first = np.unique(image, return_index=True)
    if len(first) < n:
        dup = int(np.setdiff1d(np.arange(n), first)[0])
        raise InputError(f"image {image[dup]!r} appears twice", tab.path, int(tab.lines[dup]), "image")
    return EOP(image, np.column_stack([tab["x"], tab["y"], tab["z"]]), opk, sig, None, tab.lines, tab.path)


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
