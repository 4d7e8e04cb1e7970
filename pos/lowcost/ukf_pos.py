"""`dgcal pos --mode ukf`: seed 000's 15-state UKF (with three GNSS error states) on the pos pipeline's inputs, the
gtsam LC smoother on the same fixes beside it, and both against a true trajectory when one is given.

The UKF has a state at every fix and, where no fix is near (GNSS outages, the IMU record after the last fix), at the
output rate, predicted by the IMU: the trajectory at the output rate and the events' poses cover the whole span from
the first fix to the end of the IMU record.

The accuracy table has one row per solution and quantity (roll, pitch, heading deg; north, east, down m):
the median 1-sigma the solution claims and, with a truth, the error's mean, std, RMS and the normalised
error RMS (error / claimed sigma: 1 when the sigmas are honest), over the epochs after `skip_s` of
convergence that both solutions share; with GNSS outages, rows `ukf_outages` over the UKF's epochs inside them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.fields.crs import geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_ecef_to_ned
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io.formats import Trajectory, read_trajectory
from dgcal.pos.ins.interpolate import interpolate_trajectory, trajectory_at_events
from dgcal.pos.lowcost.ukf import UkfOptions, UkfSolution, run_ukf
from dgcal.pos.smoother.batch import SmootherOptions, smooth
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.pos.smoother.integrity import gnss_warnings, screen_fixes
from dgcal.pos.smoother.output import solution_trajectory

QUANTITIES = ("roll", "pitch", "heading", "north", "east", "down")


@dataclass
class UkfPosResult:
    """`dgcal pos --mode ukf`: the UKF solution, its trajectory at the output rate and at every fix, the events'
    poses, the comparison smoother's keyframes (or None), the truth (or None), the accuracy table and summary."""

    mode: str
    ukf: UkfSolution
    trajectory: Trajectory
    keyframes: Trajectory
    events: Trajectory | None
    fixes: GnssFixes
    smoother: Trajectory | None = None
    truth: Trajectory | None = None
    table: list[dict] = field(default_factory=list)
    summary: dict = field(default_factory=dict)


def decimate(tr: Trajectory, rate_hz: float) -> Trajectory:
    """The samples of a trajectory nearest to a grid at `rate_hz` (Hz) from its first epoch: at most one per grid step
    (the closest to it), and the last one; irregular epochs (fixes, with predictions in GNSS outages) come out on the
    grid wherever they have a sample near it."""
    t = np.asarray(tr.t, float)
    if len(t) < 2:
        return tr
    step = 1.0 / rate_hz
    g = np.round((t - t[0]) / step)
    off = np.abs((t - t[0]) - g * step)
    order = np.lexsort((off, g))
    first = np.r_[True, g[order][1:] != g[order][:-1]]
    idx = np.unique(np.r_[order[first], len(t) - 1])
    return Trajectory(tr.t[idx], tr.lat[idx], tr.lon[idx], tr.h[idx], tr.v_ned[idx], tr.rph[idx],
                      None if tr.sigma is None else tr.sigma[idx])


def gnss_outages(u: UkfSolution, min_gap_s: float | None = None) -> list[tuple[float, float]]:
    """The spans (t_start, t_end) GPS s in which the UKF predicted without a GNSS update for longer than `min_gap_s`
    (default: 5 median fix intervals, at least 1 s), the end of the IMU record after the last fix included."""
    tu = u.t[u.updated] if u.updated is not None else u.t
    if len(tu) < 2:
        return [(float(u.t[0]), float(u.t[-1]))] if u.t[-1] > u.t[0] else []
    gap = max(1.0, 5.0 * float(np.median(np.diff(tu)))) if min_gap_s is None else float(min_gap_s)
    d = np.diff(tu)
    spans = [(float(tu[k]), float(tu[k + 1])) for k in np.flatnonzero(d > gap)]
    if u.t[-1] - tu[-1] > gap:
        spans.append((float(tu[-1]), float(u.t[-1])))
    return spans


def in_spans(t: np.ndarray, spans: list) -> np.ndarray:
    """Mask of the times strictly inside any of the spans (t_start, t_end)."""
    t = np.asarray(t, float)
    m = np.zeros(len(t), bool)
    for a, b in spans:
        m |= (t > a) & (t < b)
    return m


def errors_vs_truth(tr: Trajectory, truth: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Errors of `tr` against `truth` interpolated at its epochs: attitude (N,3) deg (heading wrapped) and position
    (N,3) m along the truth's local north, east, down."""
    st = interpolate_trajectory(truth, tr.t)
    d_att = tr.rph - st.rph
    d_att[:, 2] = (d_att[:, 2] + 180.0) % 360.0 - 180.0
    p = np.asarray(geodetic_to_ecef(tr.lat, tr.lon, tr.h), float).reshape(-1, 3)
    d_pos = np.einsum("nij,nj->ni", R_ecef_to_ned(st.lat, st.lon), p - st.p_ecef)
    return d_att, d_pos


def accuracy_rows(name: str, tr: Trajectory, truth: Trajectory | None) -> list[dict]:
    """Accuracy-table rows of one solution (see the module documentation)."""
    rows = []
    e = None
    if truth is not None:
        d_att, d_pos = errors_vs_truth(tr, truth)
        e = np.column_stack([d_att, d_pos])
    sig = tr.sigma[:, [3, 4, 5, 0, 1, 2]] if tr.sigma is not None else None
    for i, q in enumerate(QUANTITIES):
        r = {"solution": name, "quantity": q, "unit": "deg" if i < 3 else "m",
             "median_sigma": None if sig is None else float(np.median(sig[:, i]))}
        if e is not None:
            x = e[:, i]
            r.update(mean=float(x.mean()), std=float(x.std()), rms=float(np.sqrt(np.mean(x ** 2))))
            if sig is not None:
                r["normalised_rms"] = float(np.sqrt(np.mean((x / sig[:, i]) ** 2)))
        rows.append(r)
    return rows


def _common(tr: Trajectory, t: np.ndarray) -> Trajectory:
    """The samples of `tr` at times `t` (each within 1 ms of one of them)."""
    j = np.clip(np.searchsorted(tr.t, t - 1e-3), 0, len(tr.t) - 1)
    ok = np.abs(tr.t[j] - t) < 1e-3
    j = j[ok]
    return Trajectory(tr.t[j], tr.lat[j], tr.lon[j], tr.h[j], tr.v_ned[j], tr.rph[j],
                      None if tr.sigma is None else tr.sigma[j])


GNSS_OUTLIER_SIGMA = 5.0   # fixes beyond the IMU's acceleration bound plus this many sigmas are rejected


def process_ukf(imu, grade, lever_arm_b, fixes: GnssFixes, events=None, rate_hz: float = 10.0,
                ukf_opts: UkfOptions | None = None, compare: bool = True, compare_rate_hz: float = 10.0,
                smoother_opts: SmootherOptions | None = None, truth: Trajectory | None = None, skip_s: float = 30.0,
                progress: bool = False) -> UkfPosResult:
    """Run the UKF on IMU + GNSS fixes (antenna lever arm `lever_arm_b`, body FRD m), the LC smoother on the same
    fixes at `compare_rate_hz` when `compare`, and the accuracy table (against `truth` when given)."""
    opts = ukf_opts or UkfOptions()
    opts.lever_arm_b = np.asarray(lever_arm_b, float)
    # the fixes the IMU's accelerations make impossible never reach the filter (as for the smoother)
    fixes, rejected = screen_fixes(fixes, imu, GNSS_OUTLIER_SIGMA)
    u = run_ukf(imu, fixes, grade, opts, progress=progress, rate_hz=rate_hz)
    key = u.to_trajectory()
    traj = decimate(key, rate_hz)
    ev = None
    if events is not None and len(events):
        # every epoch from the first fix to the IMU's end has a state (predicted through GNSS outages): any event in
        # that span is interpolated between its neighbours, however far the fixes are
        ev = trajectory_at_events(key, events, max_gap_s=1.01 * float(np.max(np.diff(key.t))) if len(key.t) > 1
                                  else None)
    sm_tr = None
    if compare:
        step = max(1, int(round(1.0 / (compare_rate_hz * np.median(np.diff(fixes.t))))))
        s = slice(None, None, step)
        lc = GnssFixes(fixes.t[s], fixes.p_ecef[s], fixes.sigma_ned[s],
                       None if fixes.v_ecef is None else fixes.v_ecef[s],
                       None if fixes.sigma_v_ned is None else fixes.sigma_v_ned[s],
                       None if fixes.cov_ned is None else fixes.cov_ned[s])
        sopts = smoother_opts or SmootherOptions()
        sopts.lever_arm_b = np.asarray(lever_arm_b, float)
        sm = smooth(imu, lc, grade, sopts, mode="lc", frame=u.frame)
        sm_tr = solution_trajectory(sm)
    # compare on the epochs both have, after the convergence time
    t = key.t[key.t >= key.t[0] + skip_s]
    if sm_tr is not None:
        t = sm_tr.t[(sm_tr.t >= key.t[0] + skip_s) & (sm_tr.t <= key.t[-1])]
    if truth is not None:
        t = t[(t >= truth.t[0]) & (t <= truth.t[-1])]
    if len(t) < 2:
        raise InputError(f"fewer than two epochs after the {skip_s:g} s the filter needs to converge", field="imu.path")
    table = accuracy_rows("ukf", _common(key, t), truth)
    if sm_tr is not None:
        table += accuracy_rows("smoother", _common(sm_tr, t), truth)
    outages = gnss_outages(u)
    if outages:  # the UKF alone inside the GNSS outages (after the convergence time), every epoch it has there
        m = in_spans(key.t, outages) & (key.t >= key.t[0] + skip_s)
        if truth is not None:
            m &= (key.t >= truth.t[0]) & (key.t <= truth.t[-1])
        if m.sum() >= 2:
            table += accuracy_rows("ukf_outages", _common(key, key.t[m]), truth)
    res = UkfPosResult("ukf", u, traj, key, ev, fixes, sm_tr, truth, table)
    res.summary = summarize_ukf(res, skip_s, int(len(t)), outages)
    if rejected:
        res.summary.setdefault("integrity", {})["gnss_rejected"] = rejected
        res.summary.setdefault("warnings", []).extend(gnss_warnings(rejected))
    return res


def summarize_ukf(res: UkfPosResult, skip_s: float, n_compared: int, outages: list | None = None) -> dict:
    """Numbers for pos_summary.json of `--mode ukf`."""
    s = res.keyframes.sigma
    u = res.ukf
    nis = u.nis[np.isfinite(u.nis)]
    outages = gnss_outages(u) if outages is None else outages
    ev_out = int(in_spans(res.events.t, outages).sum()) if res.events is not None else 0
    out = {"mode": "ukf", "filter": f"UKF, {u.info.get('n_states', 15)} states (seed 000's 15"
           + (" + 3 GNSS error states)" if u.info.get("gnss_error_states") else ")"),
           "keyframes": int(len(u.t)), "t_start_gps": float(u.t[0]), "t_end_gps": float(u.t[-1]),
           "nav_frame_origin_deg_m": [u.frame.lat0, u.frame.lon0, u.frame.h0],
           "median_sigma_m": np.median(s[:, :3], axis=0).round(4).tolist(),
           "median_sigma_deg": np.median(s[:, 3:], axis=0).round(5).tolist(),
           "max_sigma_m": np.max(s[:, :3], axis=0).round(3).tolist(),
           "gyro_bias_deg_h_mean": np.degrees(u.bias[:, 3:].mean(0) * 3600).round(3).tolist(),
           "accel_bias_mg_mean": (u.bias[:, :3].mean(0) / 9.80665e-3).round(4).tolist(),
           "nis_mean": float(nis.mean()) if len(nis) else None,
           "events": int(len(res.events.t)) if res.events is not None else 0,
           "epochs_with_gnss": int(u.updated.sum()), "epochs_without_gnss_update": int((~u.updated).sum()),
           "gnss_outages": [{"t_start_gps": a, "length_s": round(b - a, 3)} for a, b in outages],
           "events_in_gnss_outages": ev_out, "start": u.info.get("start"),
           "compared_epochs": n_compared, "skip_s": skip_s, "truth": res.truth is not None,
           "smoother_compared": res.smoother is not None, "accuracy": res.table}
    return out


def read_true_trajectory(path) -> Trajectory:
    """A true trajectory: dgcal's trajectory CSV, or a simulator's `truth_trajectory.csv`
    (t_gps,lat,lon,h,vn,ve,vd,roll,pitch,heading)."""
    head = ""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            head = fh.readline().lower()
    except OSError as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    if "gps_week" in head:
        return read_trajectory(path)
    cols = ("t_gps", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "heading")
    tab = read_table(path, cols)
    t = tab["t_gps"]
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError("time does not increase", tab.path, int(tab.lines[back[0] + 1]), "t_gps")
    return Trajectory(t, tab["lat"], tab["lon"], tab["h"], np.column_stack([tab["vn"], tab["ve"], tab["vd"]]),
                      np.column_stack([tab["roll"], tab["pitch"], tab["heading"]]), path=tab.path)
