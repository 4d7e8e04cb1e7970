"""Mounting methods on one simulated campaign: GCP-only bundle EOPs -> traditional / proposed; ISO on the same
image measurements; DG check points of the mapping flight for each. Prints accuracies, sigmas and times.

    .venv/bin/python bench/mounting_methods.py [SEED]
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

# run as a script, bench/ is first on sys.path and bench/pos.py would shadow the `pos` package
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))


def bundle_eop(sim, flight):
    """EOPs (map CRS, with full covariances) of a GCP-only bundle of the flight's image measurements."""
    from dgcal.bundle.adjustment import BundleInput, adjust
    from dgcal.bundle.intersection import intersect
    from dgcal.fields.io.formats import EOP
    from dgcal.fields.pose import Poses
    world = flight.world
    names = [str(s) for s in flight.eop.image]
    p0 = world.eop_to_poses(flight.eop.xyz, flight.eop.opk)
    C0, R0 = p0.C_world, p0.R_cam_to_world
    m = flight.measurements
    img = {k: i for i, k in enumerate(names)}
    pts = list(dict.fromkeys(str(k) for k in m.id))
    pid = {k: j for j, k in enumerate(pts)}
    oi = np.array([img[str(k)] for k in m.image])
    op = np.array([pid[str(k)] for k in m.id])
    X0 = intersect(sim.camera, C0, R0, oi, op, m.xy, m.sigma, len(pts)).xyz
    gid = sim.ground.index()
    prior = np.full((len(pts), 3), np.nan)
    psig = np.full((len(pts), 3), np.nan)
    for k, j in pid.items():
        r = gid[k]
        if sim.ground.role[r] == "control":
            prior[j] = world.to_world(sim.ground.xyz[r][None])[0]
            psig[j] = sim.ground.sigma[r]
    inp = BundleInput(sim.camera, names, p0.R_world_to_cam, C0, pts, X0, oi, op, m.xy, m.sigma, prior, psig)
    from dgcal.bundle.adjustment import BundleOptions
    res = adjust(inp, BundleOptions(loss="none"))
    print(f"bundle pose covariance: min diagonal {np.min(np.diagonal(res.cov_pose, axis1=1, axis2=2)):.3g}")
    xyz, opk, cov = world.poses_to_eop(Poses(res.R_world_to_cam, res.C_world, res.cov_pose))
    sig = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    return EOP(flight.eop.image, xyz, opk, sig, cov), res.sigma0


def main(seed: int = 7) -> None:
    from dgcal.calib.dg.accuracy import check_points_dg
    from dgcal.calib.mounting.methods import calibrate_mounting
    from dgcal.fields.pose import so3_log
    from dgcal.calib.mounting.integrated import calibrate_iso
    from dgcal.fields.crs import MapGrid
    from dgcal.sim.mounting import simulate_mounting
    sim = simulate_mounting(seed)
    c, mp, g = sim.calibration, sim.mapping, MapGrid(sim.crs)
    t = time.perf_counter()
    eop_ba, s0 = bundle_eop(sim, c)
    print(f"GCP-only bundle: {time.perf_counter() - t:.1f} s, sigma0 {s0:.3f}, median EOP sigma "
          f"{np.median(eop_ba.sigma[:, :3]):.3f} m, {np.median(eop_ba.sigma[:, 3:]):.4f} deg")
    runs = {"traditional": lambda: calibrate_mounting(eop_ba, g, c.traj, c.events, "traditional"),
            "proposed": lambda: calibrate_mounting(eop_ba, g, c.traj, c.events, "proposed"),
            "iso": lambda: calibrate_iso(eop_ba, g, c.traj, c.events, c.measurements, sim.ground, sim.camera)}
    print(f"{'method':12s} {'time s':>6s} {'d delay ms':>10s} {'d lever cm (x,y,z)':>24s} {'d bore deg':>24s} "
          f"{'max |z|':>7s} {'DG 3D RMS m':>11s} {'pred m':>7s}")
    for name, f in runs.items():
        t = time.perf_counter()
        r = f()
        dt = time.perf_counter() - t
        e = np.r_[r.delay_s - sim.delay_s, r.lever_arm_m - sim.lever_arm_m,
                  so3_log(r.R_cam_to_body @ sim.R_cam_to_body.T)]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(r.sigmas > 0, np.abs(e) / r.sigmas, np.nan)
        ck = check_points_dg(g, mp.traj, mp.events, r, sim.camera, mp.measurements, sim.ground, ("check", "control"),
                             pos_correlation_time_s=sim.noise["pos_error_kernel_s"])
        print(f"{name:12s} {dt:6.1f} {e[0] * 1e3:10.2f} {np.array2string(e[1:4] * 100, precision=2):>24s} "
              f"{np.array2string(np.degrees(e[4:]), precision=4):>24s} {np.nanmax(z):7.2f} "
              f"{ck.stats['rms']['3D']:11.3f} {ck.budget['predicted_rms']['3D']:7.3f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7)
