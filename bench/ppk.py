"""PPK on the real static baseline (rover rinex-sept, base rinex-3034, 5.3 km): dgcal beside RTKLIB (pyrtklib).

Run: .venv/bin/python bench/ppk.py [ROVER NAV BASE X Y Z]
Prints per engine: fix rate, fixed-epoch 3D RMS and mean/std E/N/U error against the known rover position,
and the processing time per epoch (dgcal: forward + backward passes and their combination; RTKLIB: postpos
combined, the same configuration: kinematic, L1+L2+L5, GPS+Galileo+QZSS, ratio 3, fix and hold).
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = ROOT.parent / "shared" / "data"
REF_ECEF = np.array([-3962108.673, 3381309.574, 3668678.638])
BASE_ECEF = [-3959400.631, 3385704.533, 3667523.111]


def line(name: str, p: np.ndarray, fixed: np.ndarray, dt_s: float) -> str:
    from dgcal.fields.crs import ecef_to_geodetic
    from dgcal.fields.frames import R_ecef_to_enu
    lat, lon, _ = ecef_to_geodetic(REF_ECEF)
    e = (p[fixed] - REF_ECEF) @ R_ecef_to_enu(lat, lon).T
    rms = np.sqrt(np.mean(np.sum(e ** 2, axis=1))) if len(e) else np.nan
    return (f"{name:7s} {len(p):4d} epochs  fixed {100 * fixed.mean():5.1f} %  fixed 3D RMS {1e3 * rms:5.1f} mm  "
            f"mean E/N/U {' '.join(f'{1e3 * v:+5.1f}' for v in e.mean(0))} mm  "
            f"std {' '.join(f'{1e3 * v:4.1f}' for v in e.std(0))} mm  {1e3 * dt_s / len(p):6.1f} ms/epoch")


def main() -> None:
    a = sys.argv[1:]
    rover = a[0] if len(a) >= 3 else str(DATA / "rinex-sept" / "SEPT078M1.21O")
    nav = a[1] if len(a) >= 3 else str(DATA / "rinex-sept" / "SEPT078M.21P")
    base = a[2] if len(a) >= 3 else str(DATA / "rinex-3034" / "3034078M1.21O")
    base_pos = [float(v) for v in a[3:6]] if len(a) >= 6 else BASE_ECEF
    from dgcal.pos.gnss.carrier import carrier_observations
    from dgcal.pos.gnss.ppk import PpkOptions, ppk
    from dgcal.pos.gnss.rinex import read_rinex_nav
    from dgcal.pos.gnss.rinex_obs import read_obs_file

    t0 = time.perf_counter()
    nv = read_rinex_nav(nav)
    r = carrier_observations(read_obs_file(rover))
    b = carrier_observations(read_obs_file(base))
    t1 = time.perf_counter()
    res = ppk(r, b, nv, base_pos, PpkOptions(), p_init=r.p_approx_ecef)
    t2 = time.perf_counter()
    print(f"read RINEX + navigation {t1 - t0:.2f} s")
    print(line("dgcal", res.p, res.status == 3, t2 - t1))
    for name, ps in (("  fwd", res.forward), ("  bwd", res.backward)):
        print(line(name, ps.p, ps.status == 3, np.nan))
    try:
        from dgcal.pos.gnss.rtklib import rtklib_ppk
    except ImportError:
        print("RTKLIB: pyrtklib not installed")
        return
    rk = rtklib_ppk(rover, nav, base, base_pos, systems="GEJ")
    print(line("RTKLIB", rk["p_ecef"], rk["q"] == 1, rk["run_s"]))


if __name__ == "__main__":
    main()
