"""A base station for carrier phase (ppk, tc): its inputs, and its RINEX and position read and checked against the
rover and against the base's own SPP (a base position metres off would move every rover position as much with a
millimetre sigma)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.crs import R_ecef_to_enu_at, geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import calendar_from_gps_seconds, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.gnss.spp import solve_epoch


@dataclass
class BaseStation:
    """A base station's RINEX observations and antenna position (ECEF m, or lat, lon deg and ellipsoidal height m;
    neither: the header's APPROX POSITION, with a warning)."""

    rinex: Path | None = None
    position_ecef: tuple[float, float, float] | None = None
    position_llh: tuple[float, float, float] | None = None


def ymd(t_gps: float) -> str:
    y, mo, d, h, mi, s = calendar_from_gps_seconds(t_gps)
    return f"{y:04d}-{mo:02d}-{d:02d} {h:02d}:{mi:02d}:{s:04.1f}"


def spp_median(raw, nav, sopts, n_max: int = 10) -> tuple[np.ndarray | None, int]:
    """Median SPP position (ECEF m) of up to `n_max` epochs spread over a receiver's file."""
    k = np.unique(np.linspace(0, len(raw.epochs) - 1, min(n_max, len(raw.epochs))).astype(int))
    guess = raw.p_approx_ecef if np.all(np.isfinite(raw.p_approx_ecef)) else None
    ps = []
    for i in k:
        s = solve_epoch(raw.epochs[i], nav, guess, sopts)
        if s.ok:
            ps.append(s.p_ecef)
            guess = s.p_ecef
    return (np.median(ps, axis=0) if ps else None), len(ps)


@dataclass
class CheckedBase:
    """A base station checked against the rover: its observations in the rover's span (`RinexObsFile`), its
    position (ECEF m) and where it came from, its own SPP (median of ten epochs) and the distance to it (m)."""

    rinex: object
    ecef: np.ndarray
    source: str
    spp_ecef: np.ndarray | None
    minus_spp_m: float
    warnings: list[str] = field(default_factory=list)


def read_base(station: BaseStation, rover_rx, nav, sopts, systems: str, max_age_s: float = 30.0) -> CheckedBase:
    """Read and check the base station's RINEX for the rover file `rover_rx` (ppk and tc): common epochs (a base of
    another day is said so), a base epoch within `max_age_s` of a rover epoch, the base position (ECEF, geodetic,
    or the header's with a warning) on the Earth's surface and within 5 sigma of a static SPP of the base's own
    (`base_spp_disagreement`; 3-5 sigma warned). One-line InputError naming the file, line and field otherwise."""
    warnings: list[str] = []
    if len(rover_rx) == 0:
        raise InputError("no observation epochs in the requested time span", rover_rx.path)
    t0, t1 = rover_rx.t_gps[0], rover_rx.t_gps[-1]
    base_all = read_obs_file(station.rinex, systems=systems)
    if len(base_all) == 0:
        raise InputError("no observation epochs", station.rinex)
    tb = base_all.t_gps
    if tb[-1] < t0 - max_age_s or tb[0] > t1 + max_age_s:
        day = abs(np.floor(tb[0] / 86400.0) - np.floor(t0 / 86400.0)) >= 1
        raise InputError(f"no common epochs: base {ymd(tb[0])} - {ymd(tb[-1])}, rover {ymd(t0)} - {ymd(t1)} GPS"
                         + (" (another day)" if day else ""), station.rinex, int(base_all.epoch_line[0]), "EPOCH")
    near = np.abs(tb[np.clip(np.searchsorted(tb, rover_rx.t_gps), 0, len(tb) - 1)] - rover_rx.t_gps)
    near = np.minimum(near, np.abs(tb[np.clip(np.searchsorted(tb, rover_rx.t_gps) - 1, 0, len(tb) - 1)]
                                   - rover_rx.t_gps))
    if not np.any(near <= max_age_s):
        raise InputError(f"no base epoch within {max_age_s:g} s of any rover epoch", station.rinex,
                         int(base_all.epoch_line[0]), "EPOCH")
    keep = (tb >= t0 - max_age_s) & (tb <= t1 + max_age_s)
    base_rx = base_all if keep.all() else \
        read_obs_file(station.rinex, t_start=float(tb[keep][0]), t_end=float(tb[keep][-1]), systems=systems)
    if station.position_ecef is not None:
        base = np.asarray(station.position_ecef, float)
        src = fld = "base.position_ecef"
    elif station.position_llh is not None:
        lat, lon, h = (float(v) for v in station.position_llh)
        if not (-90 <= lat <= 90 and -180 <= lon <= 360):
            raise InputError(f"latitude/longitude out of range: {lat}, {lon}", field="base.position_llh")
        base = np.asarray(geodetic_to_ecef(lat, lon, h), float).reshape(3)
        src = fld = "base.position_llh"
    else:
        base = base_rx.p_approx_ecef
        if not np.all(np.isfinite(base)):
            raise InputError("no base position: give it (ECEF or geodetic); the base header has no APPROX POSITION XYZ",
                             station.rinex, field="APPROX POSITION XYZ")
        src, fld = "header APPROX POSITION XYZ", "APPROX POSITION XYZ"
        warnings.append(f"{station.rinex}: no base position given: the base header's APPROX POSITION XYZ "
                        "is used; its error (often metres) goes into the rover position one to one")
    if not (np.all(np.isfinite(base)) and 6.0e6 < np.linalg.norm(base) < 6.5e6):
        raise InputError(f"base position {base.tolist()} is not on the Earth's surface (ECEF metres?)", field=fld)
    base_raw = read_rinex_obs(station.rinex, systems=sopts.systems, rinex=base_rx)
    base_spp, _ = spp_median(base_raw, nav, sopts)
    d_spp = float(np.linalg.norm(base - base_spp)) if base_spp is not None else np.nan
    if base_spp is not None and d_spp > 100.0:
        raise InputError(f"base position ({src}) is {d_spp:.0f} m from the base's own SPP position "
                         f"{np.round(base_spp, 1).tolist()}: wrong coordinates or wrong file?", field=fld)
    if base_spp is not None and not src.startswith("header"):
        z = base_spp_disagreement(base, base_spp)
        if z > 5.0:
            raise InputError(f"base position ({src}) is {d_spp:.1f} m from the base's own SPP position "
                             f"{np.round(base_spp, 1).tolist()} ({z:.1f} sigma of a static SPP's "
                             f"{BASE_SPP_SIGMA_M[0]:g} m horizontal / {BASE_SPP_SIGMA_M[1]:g} m vertical): every rover "
                             "position would be off by as much with a millimetre sigma; wrong coordinates, another "
                             "datum or epoch, or a height above the marker?", field=fld)
        if z > 3.0:
            warnings.append(f"base position ({src}) is {d_spp:.1f} m from the base's own SPP ({z:.1f} sigma): check "
                            "its coordinates; an error there goes into every rover position")
    return CheckedBase(base_rx, base, src, base_spp, d_spp, warnings)


# a static receiver's SPP averaged over its file: broadcast orbit, clock and ionosphere errors do not average out
BASE_SPP_SIGMA_M = (1.5, 3.0)              # horizontal, vertical (m, 1 sigma)


def base_spp_disagreement(base_ecef: np.ndarray, spp_ecef: np.ndarray) -> float:
    """How many sigmas of a static SPP (`BASE_SPP_SIGMA_M`, local level) a given base position is from the base's
    own SPP: the norm of the local east/north/up difference scaled per axis."""
    d = R_ecef_to_enu_at(np.asarray(spp_ecef, float)) @ (np.asarray(base_ecef, float) - np.asarray(spp_ecef, float))
    sh, sv = BASE_SPP_SIGMA_M
    return float(np.sqrt((d[0] / sh) ** 2 + (d[1] / sh) ** 2 + (d[2] / sv) ** 2))
