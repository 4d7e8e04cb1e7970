"""HTML report of a GNSS/INS smoothing run (`dgcal pos --mode tc|lc`): with a base station the carrier phase (PPK
fix rate over time, satellites and fixed phase rows, slips, TC minus PPK), trajectory map, satellites used,
post-fit residuals (DD phase and code), sigma envelopes, smoother vs forward, innovations and normalised
innovations. One self-contained file."""
from __future__ import annotations

from functools import partial

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.crs import geodetic_to_ecef
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import write_trajectory
from dgcal.pos.gnss.solution_files import GnssSolution
from dgcal.pos.gnss_ins import PosResult
from dgcal.pos.gnss_ins_summary import antenna_ecef, withheld_fix_residuals
from dgcal.reports.gnss import TIME_CORRELATED
from dgcal.reports.honesty import add_honesty, combined_sigma, honesty_rows, honesty_section, no_reference
from dgcal.reports.glossary import label
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import add_residual_table, flat_pairs
from dgcal.reports.units import fmt_value, pm, with_unit


def withheld_errors(res, withheld: GnssSolution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At the withheld fixes inside the trajectory's span: the trajectory's antenna minus the fix, N/E/D m (n,3), as
    pos_summary.json withheld_fixes (`dgcal.pos.gnss_ins_summary.withheld_fix_residuals`), the trajectory's N/E/D
    position sigmas there (n,3) and the fixes' own (n,3); empty without trajectory sigmas."""
    w, d_ned, s_traj = withheld_fix_residuals(res.trajectory, withheld, res.smoothed.problem.lever_arm_b)
    if len(w) == 0 or s_traj is None:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    return d_ned, s_traj, w.sigma_ned


def pos_honesty(res, withheld: GnssSolution | None = None) -> dict:
    """The honesty record of a GNSS/INS run (dgcal.reports.honesty): with the withheld fixes (`withheld`, the
    fixes left out in outages) each one's N/E/D error of the trajectory's antenna over the trajectory's sigma and
    the fix's own sigma in quadrature; without them the line that there is no reference, or that the run kept only
    the RMS of its withheld fixes (pos_summary.json withheld_fixes)."""
    if withheld is not None:
        err, s_traj, s_fix = withheld_errors(res, withheld)
        if len(err):
            rows = honesty_rows(err, combined_sigma(s_traj, s_fix), ("N", "E", "D"), "withheld fixes")
            return honesty_section(rows, [
                "GNSS fixes withheld in outages (--gnss-outages): the trajectory's antenna (IMU + lever arm) minus "
                "each withheld fix, N/E/D, over the trajectory's sigma there and the fix's own sigma added in "
                "quadrature (the fix is a measurement, not the truth).", TIME_CORRELATED])
    w = res.summary.get("withheld_fixes") or {}
    if w.get("n"):
        return no_reference(f"{w['n']} fixes were withheld (3D RMS {with_unit(w['rms_3d_m'], 'm')}, the "
                            "withheld-fix record of pos_summary.json), but their per-epoch errors and sigmas were "
                            "not kept with the result: no error/sigma.")
    how = ("withhold some of the GNSS fixes (--gnss-outages START LENGTH PERIOD) to compare the trajectory with "
           "them" if res.mode == "lc" else "the trajectory has no reference in TC mode (a simulation's truth: "
           "the campaign report)")
    return no_reference(f"No reference: {how}.")


def _map(res):
    fig, ax = new_figure(7.5, 6.5)
    sol = res.smoothed
    p = sol.p_nav
    ax.plot(p[:, 1], p[:, 0], "-", lw=0.8, color="#345", label="smoothed (IMU)")
    gap = ~sol.gnss_update
    if gap.any():
        ax.plot(p[gap, 1], p[gap, 0], ".", ms=3, color="#d33", label="no GNSS update")
    if res.mode == "tc" and sol.n_sat is not None:
        few = sol.gnss_update & (sol.n_sat < 4)
        if few.any():
            ax.plot(p[few, 1], p[few, 0], ".", ms=3, color="#e90", label="< 4 satellites")
    if res.events is not None:
        ev = sol.frame.from_ecef(_ecef(res.events))
        ax.plot(ev[:, 1], ev[:, 0], "^", ms=3, color="#393", label="events")
    ax.set_xlabel("East (m, nav frame)")
    ax.set_ylabel("North (m)")
    ax.set_aspect("equal", "datalim")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _ecef(tr):
    return geodetic_to_ecef(tr.lat, tr.lon, tr.h)


def _sigmas(res):
    fig, axs = new_figure(9, 6, nrows=2, sharex=True)
    kt = res.keyframes
    t = kt.t - kt.t[0]
    for j, name in enumerate(("north", "east", "down")):
        axs[0].plot(t, kt.sigma[:, j], lw=0.9, label=f"{name} smoothed")
    if res.forward_keyframes is not None:
        fs = res.forward_keyframes.sigma
        axs[0].plot(t, np.linalg.norm(fs[:, :3], axis=1), "--", lw=0.8, color="grey", label="3D forward")
    axs[0].set_ylabel("position sigma (m)")
    axs[0].set_yscale("log")
    axs[0].legend(fontsize=8, ncol=2)
    for j, name in enumerate(("roll", "pitch", "heading")):
        axs[1].plot(t, kt.sigma[:, 3 + j], lw=0.9, label=name)
    axs[1].set_ylabel("attitude sigma (deg)")
    axs[1].set_yscale("log")
    axs[1].set_xlabel("time since start (s)")
    axs[1].legend(fontsize=8)
    for a in axs:
        a.grid(alpha=0.3)
    return fig


def _satellites(res):
    fig, ax = new_figure(9, 2.8)
    sol = res.smoothed
    t = sol.t - sol.t[0]
    ax.step(t, sol.n_sat, where="mid", lw=0.9)
    ax.axhline(4, color="#d33", lw=0.6, ls=":")
    ax.set_ylabel("satellites used" if res.mode == "tc" else "GNSS fix (1/0)")
    ax.set_xlabel("time since start (s)")
    ax.grid(alpha=0.3)
    return fig


def _residuals(res, which: str):
    rows = (res.smoothed.residuals if which == "post-fit" else res.forward.residuals)
    kinds = [k for k in ("pr", "ddp", "ddp_float", "ddc", "dop", "pos", "vel") if k in rows]
    fig, axs = new_figure(9, 2.6 * max(len(kinds), 1), nrows=max(len(kinds), 1), squeeze=False)
    t = res.smoothed.t - res.smoothed.t[0]
    unit = {"pr": "pseudorange (m)", "dop": "Doppler\nrange rate (m/s)", "pos": "position (m)",
            "vel": "velocity (m/s)", "ddp": "double-differenced\nphase (m)",
            "ddp_float": "double-differenced phase,\nfloat, time-differenced (m)",
            "ddc": "double-differenced\ncode (m)"}
    for ax, kind in zip(axs[:, 0], kinds):
        k, e, s = rows[kind]
        ax.plot(t[k.astype(int)], e, ".", ms=1.5, alpha=0.6)
        ax.set_ylabel(unit[kind])
        ax.grid(alpha=0.3)
    axs[-1, 0].set_xlabel("time since start (s)")
    return fig


def _smooth_vs_forward(res):
    fig, ax = new_figure(9, 3)
    d = res.forward.p_nav - res.smoothed.p_nav
    t = res.smoothed.t - res.smoothed.t[0]
    ax.plot(t, np.linalg.norm(d, axis=1), lw=0.8, label="|forward - smoothed| position (m)")
    ax.plot(t, np.linalg.norm(res.forward_keyframes.sigma[:, :3], axis=1), "--", lw=0.8,
            label="forward 3D sigma (m)")
    ax.plot(t, np.linalg.norm(res.keyframes.sigma[:, :3], axis=1), lw=0.8, label="smoothed 3D sigma (m)")
    ax.set_yscale("log")
    ax.set_xlabel("time since start (s)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _carrier_status(res):
    """PPK status per epoch, running fix rate, satellites in the double differences and slip flags."""
    fe, sol = res.carrier, res.smoothed
    pk = fe.ppk
    t0 = sol.t[0]
    fig, axs = new_figure(9, 6.5, nrows=3, sharex=True)
    colors = {3: "#393", 2: "#e90", 1: "#d33", 0: "#999"}
    names = {3: "fixed", 2: "float", 1: "single", 0: "none"}
    for st, c in colors.items():
        m = pk.status == st
        if m.any():
            axs[0].plot(pk.t_gps[m] - t0, np.full(m.sum(), st), "|", ms=8, color=c, label=names[st])
    axs[0].set_yticks([0, 1, 2, 3], ["none", "single", "float", "fixed"])
    ax2 = axs[0].twinx()
    run = np.cumsum(pk.status == 3) / np.arange(1, len(pk.status) + 1)
    ax2.plot(pk.t_gps - t0, 100 * run, lw=0.8, color="#345")
    ax2.set_ylabel("fix rate so far (%)")
    axs[0].set_title("PPK status (the pass whose fixes give the arcs' integers)", fontsize=9)
    axs[1].step(sol.t - t0, sol.n_sat, where="mid", lw=0.9, label="satellites in the double differences")
    n_phase = np.array([int(np.sum((d.cur.kind == 0) & (d.cur.mode == 0))) if (d := sol.problem.dd.get(k)) else 0
                        for k in range(len(sol.t))])
    axs[1].step(sol.t - t0, n_phase, where="mid", lw=0.9, label="fixed phase rows")
    axs[1].axhline(4, color="#d33", lw=0.6, ls=":")
    axs[1].legend(fontsize=8)
    pair = pk.pair
    if pair is not None and len(pair.t) > 1:
        flags = np.diff(pair.Cr, axis=0).sum(axis=(1, 2))
        k = np.nonzero(flags)[0] + 1
        axs[2].vlines(pair.t[k] - t0, 0, flags[k - 1], color="#d33", lw=0.8, label="rover slip flags (incl. new arcs)")
        if pair.Cb.shape[0] > 1:
            fb = np.diff(pair.Cb, axis=0).sum(axis=(1, 2))
            kb = np.nonzero(fb)[0] + 1
            axs[2].vlines(pair.tb[kb] - t0, 0, -fb[kb - 1], color="#36c", lw=0.8, label="base (down)")
        axs[2].legend(fontsize=8)
    axs[2].set_xlabel("time since start (s)")
    for a in axs:
        a.grid(alpha=0.3)
    return fig


def _ppk_vs_tc(res):
    """TC antenna minus PPK position at PPK's fixed epochs, with the TC 3D sigma."""
    fe, sol = res.carrier, res.smoothed
    pk = fe.ppk
    p = antenna_ecef(sol, sol.problem.lever_arm_b)
    j = np.clip(np.searchsorted(pk.t_gps, sol.t - 1e-3), 0, len(pk.t_gps) - 1)
    m = (np.abs(pk.t_gps[j] - sol.t) < 1e-3) & (pk.status[j] == 3)
    fig, ax = new_figure(9, 3)
    t = sol.t - sol.t[0]
    ax.plot(t[m], 100 * np.linalg.norm(p[m] - pk.p[j[m]], axis=1), ".", ms=2, label="|TC - PPK fixed| (cm)")
    ax.plot(t, 100 * np.linalg.norm(res.keyframes.sigma[:, :3], axis=1), lw=0.8, label="TC 3D sigma (cm)")
    ax.set_yscale("log")
    ax.set_xlabel("time since start (s)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _integrity_section(rep: HtmlReport, it: Mapping) -> None:
    """The data-integrity findings: IMU samples sorted, dropped, bridged or replaced; GNSS epochs and
    observations rejected; RINEX records skipped, sorted or dropped (nothing when all is clean)."""
    imu = it.get("imu") or {}
    rows = [[i["kind"], f"{i['t0_gps']:.3f}", f"{i['t1_gps']:.3f}", i["n"], i["detail"]] for i in imu.get("issues", [])]
    rows += [[f"GNSS {r['kind']}", f"{r['t_gps']:.3f}", "", 1, r["detail"]] for r in it.get("gnss_rejected", [])]
    rows += [["RINEX", "", "", "", w] for w in it.get("rinex", [])]
    if not rows:
        return
    rep.heading("Data integrity")
    rep.text("What the checks of the inputs found and did before smoothing (dgcal.pos.ins.integrity, "
             "dgcal.pos.smoother.integrity, the RINEX reader): IMU samples sorted, dropped, bridged (gaps, with the "
             "smoother's IMU noise raised over them) or replaced (spikes); GNSS epochs and observations rejected; "
             "RINEX records skipped, sorted or dropped. Times are continuous GPS seconds.")
    rep.table(["what", "from (GPS s)", "to (GPS s)", "samples", "detail"], rows[:500])
    more = max(0, len(rows) - 500) + int(imu.get("issues_not_listed", 0))
    if more:
        rep.text(f"{more} more findings in pos_summary.json.")


# summary keys shown on the page's own tables (or left to pos_summary.json: the smoother's bookkeeping); any other
# key, such as one a later version adds, is shown under "Further results"
POS_SHOWN = {"mode", "keyframes", "t_start_gps", "t_end_gps", "nav_frame_origin_deg_m", "epochs_with_gnss",
             "epochs_without_gnss_update", "systems", "median_sigma_m", "median_sigma_deg", "max_sigma_m",
             "gyro_bias_deg_h_mean", "accel_bias_mg_mean", "residuals", "innovations", "normalised_innovations",
             "events", "warnings", "carrier", "honesty", "integrity", "imu_time_offset", "smoother"}


def write_pos_report(path: str | Path, res, honesty: dict | None = None) -> Path:
    """Write DIR/report.html for a dgcal.pos.gnss_ins.PosResult; `honesty`: its honesty record (None: the summary's,
    else `pos_honesty` without withheld fixes)."""
    s = res.summary
    rep = HtmlReport(f"GNSS/INS trajectory ({res.mode.upper()} smoother)")
    rep.headline([("median σ north, east, down (m)", s["median_sigma_m"]),
                  ("median σ roll, pitch, heading (°)", s["median_sigma_deg"])],
                 f"{res.mode.upper()} smoothed trajectory, {s['t_end_gps'] - s['t_start_gps']:.1f} s long: its "
                 "1-sigma over the flight.")
    lat, lon, h = s["nav_frame_origin_deg_m"]
    rep.kv_table([("mode", res.mode.upper()), ("keyframes (one per GNSS epoch)", s["keyframes"]),
                  ("start (GPS time)", s["t_start_gps"]), ("end (GPS time)", s["t_end_gps"]),
                  ("duration (s)", f"{s['t_end_gps'] - s['t_start_gps']:.1f}"),
                  ("epochs with a GNSS update", s["epochs_with_gnss"]),
                  ("epochs without a GNSS update", s["epochs_without_gnss_update"]),
                  ("constellations", ", ".join(s["systems"]) or "–"),
                  ("max σ north, east, down (m)", s["max_sigma_m"]),
                  ("gyro bias, mean x, y, z (°/h)", s["gyro_bias_deg_h_mean"]),
                  ("accelerometer bias, mean x, y, z (mg)", s["accel_bias_mg_mean"]),
                  ("events", s["events"]),
                  ("navigation frame origin (NED; latitude, longitude, height)",
                   f"{lat:.8f}°, {lon:.8f}°, {with_unit(h, 'm')}")])
    warn = []
    for kind, st in s.get("residuals", {}).items():
        if st["rms_normalised"] > 2.0:
            warn.append(f"{label(kind)} residuals are {st['rms_normalised']:.1f} times their sigma: check the noise "
                        "settings")
    if s["epochs_without_gnss_update"] > 0:
        warn.append(f"{s['epochs_without_gnss_update']} keyframes without a GNSS update (IMU only there)")
    warn += list(s.get("warnings", []))
    rep.warnings(warn)
    add_honesty(rep, honesty or s.get("honesty") or pos_honesty(res))
    more = flat_pairs(s, POS_SHOWN)
    if more:
        rep.heading("Further results")
        rep.kv_table(more)
    _integrity_section(rep, s.get("integrity", {}))
    toff = s.get("imu_time_offset")
    if toff is not None:
        rep.heading("IMU-GNSS time offset (estimated)")
        rep.kv_table([("offset added to the IMU tags (ms)", pm(toff["offset_ms"], toff["sigma_ms"], "ms")),
                      ("smoother runs of the χ² profile (offset ms: χ²)",
                       "; ".join(f"{d:+.1f}: {c:.1f}" for d, c in toff["trials"]))])
    c = s.get("carrier")
    if c is not None and res.carrier is not None:
        ints = c.get("integers") or {}
        rep.heading("Carrier phase (TC against a base station)")
        rep.kv_table([("base position (ECEF X, Y, Z) and source",
                       f"{fmt_value(c.get('base_ecef_m'), 'm', coordinate=True)} m ({c.get('base_position_source')})"),
                      ("base minus its own SPP (m)", c.get("base_minus_spp_m")),
                      ("PPK epochs fixed / float / single",
                       f"{c['ppk_counts']['fixed']} / {c['ppk_counts']['float']} / {c['ppk_counts']['single']} "
                       f"({100 * c['ppk_fix_rate']:.1f} % fixed)"),
                      ("phase arcs with an integer / components / inter-system links",
                       f"{ints.get('arcs')} / {ints.get('components')} / {ints.get('inter_system_links')}"),
                      ("arc pairs tied / rejected / conflicting",
                       f"{ints.get('pairs_tied')} / {ints.get('pairs_rejected')} / {ints.get('conflicts')}"),
                      ("keyframes with carrier phase (with < 4 satellites)",
                       f"{c['keyframes_with_phase']} ({c['keyframes_with_phase_and_lt4_sats']})"),
                      ("double differences dropped as outliers", c.get("dd_rows_dropped")),
                      ("slip flags rover / base", f"{c['slips_flagged_rover']} / {c['slips_flagged_base']}"),
                      ("TC minus PPK at fixed epochs, 3D RMS (m)", c.get("tc_minus_ppk_fixed_rms_m")),
                      ("differential-atmosphere budget N/E/D (m)", res.smoothed.info.get("atmosphere_budget_m"))])
        rep.figure(partial(_carrier_status, res), "PPK status and fix rate, satellites and fixed phase rows per "
                   "keyframe, slip flags")
        rep.figure(partial(_ppk_vs_tc, res), "TC (antenna) minus PPK at PPK's fixed epochs, and the TC sigma")
    rep.heading("Trajectory").figure(partial(_map, res),
                                     "Smoothed IMU track in the nav frame (NED at the flight centre)")
    rep.figure(partial(_satellites, res), "Satellites used per epoch (TC) or GNSS fixes (LC)")
    rep.heading("Sigma envelopes").figure(partial(_sigmas, res), "1-sigma of the smoothed solution (from the "
                                          "adjustment covariance)")
    rep.heading("Residuals")
    add_residual_table(rep, s.get("residuals", {}))
    rep.figure(partial(_residuals, res, "post-fit"), "Post-fit residuals of the GNSS factors")
    if res.forward is not None:
        rep.heading("Forward-only solution and innovations")
        rep.text("The forward solution uses each epoch's data and everything before it (a Kalman filter on "
                 "the same factors); innovations are the GNSS errors at the IMU prediction from the previous "
                 "epoch, normalised by the measurement sigma only.")
        add_residual_table(rep, s.get("innovations", {}))
        nis = s.get("normalised_innovations", {})
        if nis:
            rep.text("Normalised innovations: each GNSS factor's innovation squared against its full predicted "
                     "covariance (filter prediction plus measurement noise), per dimension: 1 when both are right.")
            rep.table(["factor", "n", "NIS per dimension", "RMS / σ", "share beyond χ² 99 % (%)"],
                      [[label(k), v["n"], round(v["nis_per_dim"], 3), round(v["rms_normalised"], 3),
                        100 * v["share_beyond_99pc"]] for k, v in nis.items()])
        rep.figure(partial(_smooth_vs_forward, res), "Forward minus smoothed position, and the two sigma envelopes")
        rep.figure(partial(_residuals, res, "innovations"), "Innovations")
    return rep.write(path)


def write_pos_outputs(out_dir: str | Path, res: PosResult, names: Mapping[str, str], report: bool = True,
                      withheld: GnssSolution | None = None) -> dict[str, Path]:
    """`dgcal pos --mode tc|lc`'s files in `out_dir`, named by role in `names`: trajectory (output rate),
    events (one row per event), trajectory_forward (keyframes of the forward solution), summary (JSON, with the
    honesty record `honesty`: `pos_honesty` with the withheld fixes `withheld`, or the result's own `withheld` when
    it keeps them) and report (HTML, unless `report` is False); returns the paths written by role."""
    out = Path(out_dir)
    if withheld is None:
        withheld = getattr(res, "withheld", None)   # the withheld fixes, once the pipeline keeps them with the result
    res.summary["honesty"] = pos_honesty(res, withheld)
    paths = {"trajectory": out / names["trajectory"]}
    write_trajectory(paths["trajectory"], res.trajectory)
    if res.events is not None:
        paths["events"] = out / names["events"]
        write_trajectory(paths["events"], res.events)
    if res.forward_keyframes is not None:
        paths["trajectory_forward"] = out / names["trajectory_forward"]
        write_trajectory(paths["trajectory_forward"], res.forward_keyframes)
    paths["summary"] = out / names["summary"]
    with atomic_write(paths["summary"]) as fh:
        json.dump(res.summary, fh, indent=2)
    if report:
        paths["report"] = write_pos_report(out / names["report"], res)
    return paths
