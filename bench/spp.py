"""SPP on the real SEPT RINEX data: dgcal vs RTKLIB's pntpos (via pyrtklib), and SPP speed.

Run: .venv/bin/python bench/spp.py [OBS NAV]
Prints the 3D RMS / mean ENU error of both solvers against the known antenna position, and the
wall time per epoch of dgcal's SPP on real and simulated data.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT.parent / "shared" / "data" / "rinex-sept"
REF_ECEF = np.array([-3962108.673, 3381309.574, 3668678.638])


from dgcal.pos.gnss.rtklib import rtklib_pntpos  # noqa: E402  (after the sys.path set-up)


def enu_errors(p_ecef: np.ndarray) -> np.ndarray:
    from dgcal.fields.crs import ecef_to_geodetic
    from dgcal.fields.frames import R_ecef_to_enu
    lat, lon, _ = ecef_to_geodetic(REF_ECEF)
    return (p_ecef - REF_ECEF) @ R_ecef_to_enu(lat, lon).T


def summary(name: str, p: np.ndarray) -> str:
    e = enu_errors(p)
    rms3 = np.sqrt(np.mean(np.sum(e ** 2, axis=1)))
    return (f"{name:8s} epochs {len(p):4d}  3D RMS {rms3:6.3f} m  mean E/N/U "
            f"{e[:, 0].mean():+6.3f} {e[:, 1].mean():+6.3f} {e[:, 2].mean():+6.3f} m  "
            f"std E/N/U {e[:, 0].std():5.3f} {e[:, 1].std():5.3f} {e[:, 2].std():5.3f} m")


def main() -> None:
    obs_path = sys.argv[1] if len(sys.argv) > 2 else str(DATA / "SEPT078M1.21O")
    nav_path = sys.argv[2] if len(sys.argv) > 2 else str(DATA / "SEPT078M.21P")
    from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
    from dgcal.pos.gnss.spp import SppOptions, spp

    t0 = time.perf_counter()
    nav = read_rinex_nav(nav_path)
    obs = read_rinex_obs(obs_path)
    t1 = time.perf_counter()
    sol = spp(obs, nav, SppOptions())
    t2 = time.perf_counter()
    print(f"read RINEX {t1 - t0:.2f} s; dgcal SPP {len(obs)} epochs in {t2 - t1:.2f} s "
          f"({1e3 * (t2 - t1) / len(obs):.1f} ms/epoch)")
    print(summary("dgcal", sol.p_ecef[sol.ok]))
    sig = np.sqrt(np.mean(np.diagonal(sol.cov_p, axis1=1, axis2=2)[sol.ok], axis=0))
    print(f"dgcal    mean sigma X/Y/Z {sig[0]:.2f} {sig[1]:.2f} {sig[2]:.2f} m; mean n_sat "
          f"{sol.n_sat[sol.ok].mean():.1f}, PDOP {np.nanmean(sol.dop['pdop']):.2f}; "
          f"speed RMS {np.sqrt(np.nanmean(np.sum(sol.v_ecef ** 2, axis=1))):.3f} m/s")
    try:
        t3 = time.perf_counter()
        tr, pr = rtklib_pntpos(obs_path, nav_path)
        t4 = time.perf_counter()
        print(f"RTKLIB pntpos {len(tr)} epochs in {t4 - t3:.2f} s")
        print(summary("RTKLIB", pr))
        common, ia, ib = np.intersect1d(np.round(sol.t_gps, 3), np.round(tr, 3), return_indices=True)
        d = sol.p_ecef[ia] - pr[ib]
        print(f"dgcal - RTKLIB over {len(common)} common epochs: RMS 3D "
              f"{np.sqrt(np.mean(np.sum(d ** 2, axis=1))):.3f} m")
    except ImportError:
        print("pyrtklib not installed: .venv/bin/pip install pyrtklib==0.2.7")

    # simulated: a 10-minute circle at 1 Hz
    from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss
    t = DEFAULT_T0_GPS + np.arange(0.0, 600.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 100.0, 200.0, 15.0)
    t5 = time.perf_counter()
    sim = simulate_gnss(t, p, v, nav, seed=3, systems=("G", "E", "J"), prepare=False)
    t6 = time.perf_counter()
    s2 = spp(sim, nav, SppOptions(code_sigma_zenith_m=0.5, doppler_sigma_zenith_mps=0.05,
                                  model_errors=False))
    t7 = time.perf_counter()
    err = s2.p_ecef - p
    sig = np.sqrt(np.diagonal(s2.cov_p, axis1=1, axis2=2))
    print(f"simulate 600 epochs {t6 - t5:.2f} s; SPP {t7 - t6:.2f} s; error RMS X/Y/Z "
          f"{np.sqrt(np.mean(err ** 2, axis=0)).round(3)} m; normalised RMS "
          f"{np.sqrt(np.mean((err / sig) ** 2, axis=0)).round(2)}")


if __name__ == "__main__":
    main()
