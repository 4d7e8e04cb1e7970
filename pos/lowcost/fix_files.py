"""GNSS fixes as files: the low-cost simulator's `gnss_fixes.csv` (t_gps, antenna ECEF position and velocity, NED
sigmas) written and read, so `run_ukf(imu, read_gnss_fixes(path), grade)` works on a written data set."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import atomic_write, read_table
from dgcal.pos.smoother.initial import GnssFixes

FIX_COLUMNS = ("t_gps", "x", "y", "z", "vx", "vy", "vz", "s_n", "s_e", "s_d", "s_vn", "s_ve", "s_vd")


def write_gnss_fixes(path: str | Path, fx: GnssFixes) -> None:
    """CSV t_gps,x,y,z,vx,vy,vz,s_n,s_e,s_d,s_vn,s_ve,s_vd (continuous GPS s; ECEF m, m/s; NED sigmas m, m/s)."""
    n = len(fx.t)
    v = fx.v_ecef if fx.v_ecef is not None else np.full((n, 3), np.nan)
    sv = fx.sigma_v_ned if fx.sigma_v_ned is not None else np.full((n, 3), np.nan)
    rows = np.column_stack([fx.t, fx.p_ecef, v, fx.sigma_ned, sv])
    with atomic_write(path) as fh:
        fh.write(",".join(FIX_COLUMNS) + "\n")
        np.savetxt(fh, rows, delimiter=",", fmt=["%.4f"] + ["%.4f"] * 12)


def read_gnss_fixes(path: str | Path) -> GnssFixes:
    """GnssFixes from a `write_gnss_fixes` CSV (velocity columns optional); errors name file, line and field."""
    tab = read_table(path, FIX_COLUMNS[:4] + FIX_COLUMNS[7:10], FIX_COLUMNS[4:7] + FIX_COLUMNS[10:])
    for c in FIX_COLUMNS[:4] + FIX_COLUMNS[7:10]:
        bad = np.flatnonzero(~np.isfinite(tab[c]))
        if len(bad):
            raise InputError("not a finite number", tab.path, int(tab.lines[bad[0]]), c)
    for c in FIX_COLUMNS[7:10]:
        bad = np.flatnonzero(tab[c] <= 0)
        if len(bad):
            raise InputError("a sigma must be positive", tab.path, int(tab.lines[bad[0]]), c)
    validate.gps_seconds_values(tab["t_gps"], tab.path, "t_gps", tab.lines)
    validate.ecef_near_surface(np.column_stack([tab[c] for c in ("x", "y", "z")]), tab.path, tab.lines, "x")
    for c in FIX_COLUMNS[7:10] + FIX_COLUMNS[10:]:   # velocities and their sigmas may be NaN: not given
        if c in tab:
            validate.positive_values(tab[c], tab.path, c, tab.lines, allow_nan=c in FIX_COLUMNS[10:],
                                     hi=validate.MAX_COORDINATE_M / 1e3, what="sigma")
    for c in FIX_COLUMNS[4:7]:
        if c in tab:
            validate.values_in_range(tab[c], -validate.MAX_SPEED_M_S, validate.MAX_SPEED_M_S, tab.path, c, tab.lines,
                                     allow_nan=True, unit="m/s")
    t = tab["t_gps"]
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError("time does not increase", tab.path, int(tab.lines[back[0] + 1]), "t_gps")
    p = np.column_stack([tab[c] for c in ("x", "y", "z")])
    s = np.column_stack([tab[c] for c in ("s_n", "s_e", "s_d")])
    v = sv = None
    if all(c in tab for c in FIX_COLUMNS[4:7]):
        v = np.column_stack([tab[c] for c in ("vx", "vy", "vz")])
        if all(c in tab for c in FIX_COLUMNS[10:]):
            sv = np.column_stack([tab[c] for c in ("s_vn", "s_ve", "s_vd")])
        else:
            sv = np.full((len(t), 3), 0.1)
        if not np.isfinite(v).all() or not np.isfinite(sv).all():
            v = sv = None
    return GnssFixes(t, p, s, v, sv)
