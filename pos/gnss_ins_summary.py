"""What a GNSS/INS run says about itself (pos_summary.json): spans, sigmas, residual and innovation statistics,
the carrier-phase front end, data integrity, and the trajectory against withheld fixes."""
from __future__ import annotations

import numpy as np
from scipy.special import chdtri

from dgcal.fields.constants import G0
from dgcal.fields.crs import R_ecef_to_ned_at
from dgcal.pos.gnss.solution_files import GnssSolution
from dgcal.pos.ins.error_model import imu_grade
from dgcal.pos.ins.integrity import ImuIntegrity
from dgcal.pos.ins.interpolate import interpolate_trajectory
from dgcal.pos.smoother.batch import HEADING_SPEED_MPS
from dgcal.pos.smoother.heading_budget import heading_determined
from dgcal.pos.smoother.integrity import gnss_warnings


def add_integrity(summary: dict, imu_report: ImuIntegrity | None = None, gnss_rejected: list | None = None,
                  rinex_warnings: list | None = None) -> None:
    """Put the data-integrity findings into a summary: `integrity` (IMU issues and bridges, rejected GNSS
    epochs and observations, RINEX record problems) and one line per finding in `warnings` (appended)."""
    it = summary.setdefault("integrity", {})
    w = summary.setdefault("warnings", [])
    if imu_report is not None:
        it["imu"] = imu_report.summary()
        w += imu_report.warnings()
    if gnss_rejected is not None:
        it["gnss_rejected"] = [{k: v for k, v in r.items() if k != "keyframe"} for r in gnss_rejected]
        w += gnss_warnings(gnss_rejected)
    if rinex_warnings:
        it.setdefault("rinex", []).extend(rinex_warnings)
        w += list(rinex_warnings)


def antenna_ecef(sol, lever_arm_b) -> np.ndarray:
    """Antenna positions (K,3) ECEF m of a smoother solution's keyframes (IMU pose + lever arm)."""
    p_nav = sol.p_nav + np.einsum("kij,j->ki", sol.R_body_to_nav, np.asarray(lever_arm_b, float))
    return sol.frame.to_ecef(p_nav)


def antenna_track(sol, lever_arm_b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The GNSS antenna of a smoothed solution at its keyframes: (t GPS s, ECEF m (K,3) of `antenna_ecef`, 3D position
    sigma m (K,): the IMU position's covariance; the lever arm's attitude part is millimetres)."""
    sig = np.sqrt(np.einsum("kii->k", sol.cov_p_nav)) if sol.cov_pose is not None else np.full(len(sol.t), np.inf)
    return sol.t, antenna_ecef(sol, lever_arm_b), sig


def carrier_summary(res) -> dict:
    """TC with carrier phase: PPK fix rate, the arcs' integers, double differences used, slips, TC minus PPK."""
    fe, sol = res.carrier, res.smoothed
    pk = fe.ppk
    lever = sol.problem.lever_arm_b
    p_tc = antenna_ecef(sol, lever)
    j = np.clip(np.searchsorted(pk.t_gps, sol.t - 1e-3), 0, len(pk.t_gps) - 1)
    same = np.abs(pk.t_gps[j] - sol.t) < 1e-3
    st = np.where(same, pk.status[j], 0)
    n_phase = np.array([int(np.sum(d.cur.kind == 0)) if k in sol.problem.dd else 0
                        for k, d in ((k, sol.problem.dd.get(k)) for k in range(len(sol.t)))])
    out = {"ppk_counts": {name: int(np.sum(pk.status == i)) for i, name in enumerate(("none", "single", "float",
                                                                                      "fixed"))},
           "ppk_fix_rate": float(np.mean(pk.status == 3)) if len(pk.status) else 0.0,
           "slips_flagged_rover": pk.slips_rover, "slips_flagged_base": pk.slips_base,
           "integers": fe.integers.info if fe.integers is not None else None, **fe.info,
           "keyframes_with_phase": int(np.sum(n_phase > 0)),
           "keyframes_with_phase_and_lt4_sats": int(np.sum((n_phase > 0) & (sol.n_sat < 4))),
           "dd_rows_dropped": sol.info.get("dd_rows_dropped", 0)}
    tr = np.trace(np.nan_to_num(pk.P[j], nan=np.inf), axis1=1, axis2=2)
    for name, m in (("fixed", st == 3), ("float", (st == 2) & (tr < 1.0))):   # floats good to a metre
        if m.any():
            d = p_tc[m] - pk.p[j[m]]
            out[f"tc_minus_ppk_{name}_rms_m"] = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
    out["ppk_float_epochs_worse_than_1m"] = int(np.sum((st == 2) & (tr >= 1.0)))
    return out


def summarize(res) -> dict:
    """Numbers for pos_summary.json: spans, counts, sigmas, residual and innovation statistics."""
    sol = res.smoothed
    s = res.keyframes.sigma
    out = {
        "mode": res.mode, "keyframes": int(len(sol.t)), "t_start_gps": float(sol.t[0]), "t_end_gps": float(sol.t[-1]),
        "nav_frame_origin_deg_m": [sol.frame.lat0, sol.frame.lon0, sol.frame.h0],
        "epochs_with_gnss": int(sol.gnss_update.sum()),
        "epochs_without_gnss_update": int((~sol.gnss_update).sum()),
        "systems": list(sol.info.get("systems", [])),
        "median_sigma_m": np.median(s[:, :3], axis=0).round(4).tolist() if s is not None else None,
        "median_sigma_deg": np.median(s[:, 3:], axis=0).round(5).tolist() if s is not None else None,
        "max_sigma_m": np.max(s[:, :3], axis=0).round(3).tolist() if s is not None else None,
        "gyro_bias_deg_h_mean": np.degrees(sol.bias[:, 3:].mean(0) * 3600).round(3).tolist(),
        "accel_bias_mg_mean": (sol.bias[:, :3].mean(0) / (G0 * 1e-3)).round(4).tolist(),
        "residuals": {k: _stats(v) for k, v in sol.residuals.items()},
        "smoother": {k: sol.info[k] for k in ("lm_iterations", "second_pass_reoptimised", "timing",
                                              "static_start_end_s", "static_white_noise", "imu_noise_used",
                                              "atmosphere_budget_m", "dd_rows_dropped", "lc_fix_errors",
                                              "lc_velocity", "imu_white_noise_scale", "imu_variance_factor",
                                              "imu_redundancy", "tilt_budget_deg", "heading_budget_deg",
                                              "heading_course_disagreement_deg", "heading_course_offset_deg")
                     if k in sol.info},
        "events": int(len(res.events.t)) if res.events is not None else 0,
    }
    if res.forward is not None:
        out["innovations"] = {k: _stats(v) for k, v in res.forward.residuals.items()}
        out["normalised_innovations"] = {k: _nis_stats(v) for k, v in res.forward.info.get("nis", {}).items()}
        d = res.forward.p_nav - sol.p_nav
        out["forward_minus_smoothed_rms_m"] = np.sqrt((d ** 2).mean(0)).round(4).tolist()
    return out


def _nis_stats(rows) -> dict:
    """Normalised innovations of one factor kind: n, the mean NIS per dimension (1 if the filter's predicted
    covariance and the measurement noise are right), and the share of factors beyond the chi-square 99 % point."""
    k, v, m = rows
    return {"n": int(len(v)), "nis_per_dim": float(np.sum(v) / np.sum(m)),
            "rms_normalised": float(np.sqrt(np.sum(v) / np.sum(m))),
            "share_beyond_99pc": float(np.mean(v > chdtri(m, 0.01)))}


def _stats(rows) -> dict:
    k, e, sig = rows
    z = e / sig
    return {"n": int(len(e)), "rms": float(np.sqrt(np.mean(e ** 2))),
            "rms_normalised": float(np.sqrt(np.nanmean(z ** 2))),
            "max_abs": float(np.max(np.abs(e))), "share_beyond_3sigma": float(np.mean(np.abs(z) > 3))}


def withheld_fix_residuals(traj, withheld: GnssSolution, lever_arm_b) -> tuple:
    """At the withheld fixes inside the trajectory's span: (those fixes, the trajectory's antenna (IMU position +
    R_body_to_ecef lever arm) minus each fix, N/E/D m (n,3) in the local frame of each fix, the trajectory's N/E/D
    position sigmas there (n,3) or None)."""
    ok = (withheld.t >= traj.t[0]) & (withheld.t <= traj.t[-1])
    w = withheld.subset(ok)
    if len(w) == 0:
        return w, np.zeros((0, 3)), None
    st = interpolate_trajectory(traj, w.t)
    p_ant = st.p_ecef + np.einsum("nij,j->ni", st.R_body_to_ecef, np.asarray(lever_arm_b, float))
    d_ned = np.einsum("nij,nj->ni", R_ecef_to_ned_at(w.p_ecef).reshape(-1, 3, 3), p_ant - w.p_ecef)
    return w, d_ned, None if st.sigma is None else st.sigma[:, :3]


def withheld_fix_errors(traj, withheld: GnssSolution, lever_arm_b) -> dict:
    """The trajectory against the withheld fixes inside the outages (`withheld_fix_residuals`): counts and RMS (m)
    along N, E, D and 3D, by fix quality, and error/sigma per axis (the trajectory's sigma and the fix's own)."""
    w, d_ned, s_traj = withheld_fix_residuals(traj, withheld, lever_arm_b)
    if len(w) == 0:
        return {"n": 0}
    out = {"n": int(len(w)), "rms_ned_m": np.sqrt(np.mean(d_ned ** 2, axis=0)).round(4).tolist(),
           "rms_3d_m": round(float(np.sqrt(np.mean(np.sum(d_ned ** 2, axis=1)))), 4),
           "max_3d_m": round(float(np.max(np.linalg.norm(d_ned, axis=1))), 4)}
    fixed = w.quality == 1
    if fixed.any() and not fixed.all():
        out["rms_3d_fixed_m"] = round(float(np.sqrt(np.mean(np.sum(d_ned[fixed] ** 2, axis=1)))), 4)
    if s_traj is not None:
        # the trajectory's position sigma (lever arm's attitude part neglected: millimetres) with the fix's own
        z = d_ned / np.sqrt(s_traj ** 2 + w.sigma_ned ** 2)
        out["normalised_rms_ned"] = np.sqrt(np.mean(z ** 2, axis=0)).round(3).tolist()
        out["normalised_max"] = round(float(np.max(np.abs(z))), 2)
    return out


def observability_warnings(sol, grade) -> list[str]:
    """What the motion could not determine: a heading never taken from a course (the platform never moved faster than
    `HEADING_SPEED_MPS`: its sigma is that of an unknown heading), and gyro biases beyond the grade's (3 sigma of its
    turn-on bias and instability): a heading drifting where the motion leaves it unobservable, or a wrong grade."""
    out = []
    v_h = np.hypot(sol.v_nav[:, 0], sol.v_nav[:, 1])
    model = imu_grade(grade) if isinstance(grade, str) else grade
    if not heading_determined(sol, model.smoother_noise()):
        out.append(f"heading not observable: the platform never moved faster than {HEADING_SPEED_MPS:g} m/s (max "
                   f"{v_h.max():.1f} m/s) nor drove straight far enough for a course, so nothing fixed it; its sigma "
                   "is that of an unknown heading")
    if "heading_course_disagreement_deg" in sol.info:
        out.append(f"heading disagrees with the GNSS course of the straight stretches by "
                   f"{sol.info['heading_course_disagreement_deg']:.1f} deg RMS (mean "
                   f"{sol.info['heading_course_offset_deg']:+.1f} deg), beyond their sigmas: its sigma includes that "
                   "disagreement; distrust the heading (a drifting one: a wrong gyro bias; a constant offset: the "
                   "IMU's x axis not along the direction of travel, give its rotation with --imu-set axes...)")
    lim = 3.0 * float(np.hypot(model.gyro_bias_sigma, model.gyro_bias_instability))
    b = np.abs(sol.bias[:, 3:]).max(axis=0)
    if lim > 0 and np.any(b > lim):
        axis = "xyz"[int(np.argmax(b / lim))]
        out.append(f"gyro {axis} bias estimate {np.degrees(b.max()) * 3600:.0f} deg/h is beyond the {model.name} "
                   f"grade's {np.degrees(lim) * 3600:.0f} deg/h (3 sigma): the motion leaves the heading (or that "
                   "axis) unobservable — slow, straight or static — or the grade is wrong; distrust the heading")
    return out


def time_offset_summary(offset) -> dict:
    """pos_summary.json's `imu_time_offset`: what was added to the IMU's tags (offset_ms: 0 when the estimate is
    not determinable), its sigma, the profile's estimate and the jackknife over time windows
    (`dgcal.pos.smoother.time_offset.TimeOffsetEstimate`)."""
    d = offset.as_dict()
    d["estimate_ms"] = d["offset_ms"]
    if not offset.determinable:
        d["offset_ms"] = 0.0
    return d
