"""Files and HTML report of `dgcal pos --mode ukf` (dgcal.pos.lowcost.ukf_pos): the UKF trajectory, events,
the accuracy table beside the LC smoother (against the truth when given), sigma envelopes and innovations."""
from __future__ import annotations

from functools import partial

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import write_trajectory
from dgcal.pos.lowcost.ukf_pos import UkfPosResult, errors_vs_truth
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.tables import flat_pairs
from dgcal.reports.units import canonical_unit, fmt_number, pm

ACCURACY_COLUMNS = ("solution", "quantity", "unit", "median_sigma", "mean", "std", "rms", "normalised_rms")
SEED000 = {"roll": 2.6, "pitch": 2.1}  # seed 000 (real flight, vs a vertical gyro): std of the UKF errors, deg


def write_accuracy_csv(path: Path, table: list[dict]) -> None:
    """The accuracy table as CSV (columns ACCURACY_COLUMNS; empty where there is no truth)."""
    with atomic_write(path) as fh:
        fh.write(",".join(ACCURACY_COLUMNS) + "\n")
        for r in table:
            fh.write(",".join("" if r.get(c) is None else (f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c]))
                              for c in ACCURACY_COLUMNS) + "\n")


def _shade_outages(axs, res: UkfPosResult, t0: float) -> None:
    """Grey bands over the GNSS outages the UKF predicted through."""
    for i, o in enumerate(res.summary.get("gnss_outages", [])):
        for a in axs:
            a.axvspan(o["t_start_gps"] - t0, o["t_start_gps"] + o["length_s"] - t0, color="grey", alpha=0.15, lw=0,
                      label="GNSS outage" if i == 0 and a is axs[0] else None)


def _sigmas(res: UkfPosResult):
    fig, axs = new_figure(9, 5.5, nrows=2, sharex=True)
    k = res.keyframes
    t = k.t - k.t[0]
    _shade_outages(axs, res, k.t[0])
    for j, name in enumerate(("north", "east", "down")):
        axs[0].plot(t, k.sigma[:, j], lw=0.8, label=f"UKF {name}")
    for j, name in enumerate(("roll", "pitch", "heading")):
        axs[1].plot(t, k.sigma[:, 3 + j], lw=0.8, label=f"UKF {name}")
    if res.smoother is not None and res.smoother.sigma is not None:
        ts = res.smoother.t - k.t[0]
        axs[0].plot(ts, np.linalg.norm(res.smoother.sigma[:, :3], axis=1), "--", lw=0.8, color="grey",
                    label="smoother 3D")
        axs[1].plot(ts, res.smoother.sigma[:, 3], "--", lw=0.8, color="grey", label="smoother roll")
    axs[0].set_ylabel("position sigma (m)")
    axs[1].set_ylabel("attitude sigma (deg)")
    axs[1].set_xlabel("time since start (s)")
    for a in axs:
        a.set_yscale("log")
        a.legend(fontsize=7, ncol=3)
        a.grid(alpha=0.3)
    return fig


def _errors(res: UkfPosResult):
    fig, axs = new_figure(9, 7, nrows=3, sharex=True)
    k = res.keyframes
    d_att, _ = errors_vs_truth(k, res.truth)
    t = k.t - k.t[0]
    _shade_outages(axs, res, k.t[0])
    for i, (a, name) in enumerate(zip(axs, ("roll", "pitch", "heading"))):
        a.plot(t, d_att[:, i], lw=0.7, label="UKF error")
        a.fill_between(t, -k.sigma[:, 3 + i], k.sigma[:, 3 + i], alpha=0.25, label="UKF 1 sigma")
        if res.smoother is not None:
            ds, _ = errors_vs_truth(res.smoother, res.truth)
            a.plot(res.smoother.t - k.t[0], ds[:, i], lw=0.7, label="smoother error")
        a.set_ylabel(f"{name} (deg)")
        a.grid(alpha=0.3)
    axs[0].legend(fontsize=7, ncol=3)
    axs[-1].set_xlabel("time since start (s)")
    return fig


def _innovations(res: UkfPosResult):
    fig, ax = new_figure(9, 3)
    u = res.ukf
    ax.plot(u.t - u.t[0], u.nis, ".", ms=1, alpha=0.5)
    _shade_outages([ax], res, u.t[0])
    ax.axhline(1.0, color="#d33", lw=0.7)
    ax.set_yscale("log")
    ax.set_ylabel("NIS / dof")
    ax.set_xlabel("time since start (s)")
    ax.grid(alpha=0.3)
    return fig


# summary keys shown on the page (or left to pos_summary.json); any other, such as one a later version adds, is
# shown under "Further results"
UKF_SHOWN = {"mode", "filter", "keyframes", "t_start_gps", "t_end_gps", "median_sigma_m", "median_sigma_deg",
             "gyro_bias_deg_h_mean", "accel_bias_mg_mean", "nis_mean", "events", "epochs_without_gnss_update",
             "gnss_outages", "events_in_gnss_outages", "start", "compared_epochs", "skip_s", "truth",
             "smoother_compared", "accuracy", "integrity", "warnings", "honesty", "smoother"}


def write_ukf_report(path: Path, res: UkfPosResult) -> Path:
    """One-file HTML report of a `dgcal pos --mode ukf` run."""
    s = res.summary
    rep = HtmlReport("GNSS/INS trajectory (seed 000 UKF)")
    rep.headline([("median σ north, east, down (m)", s["median_sigma_m"]),
                  ("median σ roll, pitch, heading (°)", s["median_sigma_deg"])],
                 "The UKF trajectory's 1-sigma (the accuracy table below: against the truth, when given).")
    outages = s.get("gnss_outages", [])
    st = s.get("start") or {}
    head = ("from the GNSS course at the start" if st.get("heading_known") else
            "unknown at the start (slower than the alignment speed)"
            + (f", from the GNSS course after {st['t_heading_aligned'] - s['t_start_gps']:.1f} s"
               if st.get("t_heading_aligned") is not None else ", never moving fast enough for the course"))
    rep.kv_table([("filter", s["filter"]), ("epochs (every GNSS fix; the output rate where no fix is near)",
                                            s["keyframes"]),
                  ("epochs predicted without a GNSS update", s.get("epochs_without_gnss_update")),
                  ("GNSS outages bridged by the IMU (longest, s)",
                   f"{len(outages)} ({max(o['length_s'] for o in outages):.1f})" if outages else "none"),
                  ("events inside GNSS outages", s.get("events_in_gnss_outages")),
                  ("start: roll, pitch (°)", ", ".join(pm(v, sg, "°") for v, sg in zip(
                      st.get("roll_pitch_deg") or [], st.get("roll_pitch_sigma_deg") or []))
                   + f" ({st.get('levelled')})" if st else None),
                  ("start: heading", head if st else None),
                  ("duration (s)", f"{s['t_end_gps'] - s['t_start_gps']:.1f}"),
                  ("gyro bias, mean x, y, z (°/h)", s["gyro_bias_deg_h_mean"]),
                  ("accelerometer bias, mean x, y, z (mg)", s["accel_bias_mg_mean"]),
                  ("NIS per dimension, mean (unitless)", s["nis_mean"]),
                  ("events", s["events"]), ("epochs compared (after convergence)", s["compared_epochs"])])
    warn = []
    if s["nis_mean"] is not None and s["nis_mean"] > 2.0:
        warn.append(f"innovations are {s['nis_mean']:.1f} times their predicted variance: check --imu-grade and the "
                    "GNSS sigmas")
    rows = res.table
    if res.truth is not None:
        for r in rows:
            z = r.get("normalised_rms")
            if z is not None and not 0.5 <= z <= 2.0:
                warn.append(f"{r['solution']} {r['quantity']}: error / sigma RMS {z:.2f} (1 when the sigmas are "
                            "honest)")
    more = flat_pairs(s, UKF_SHOWN)
    if more:
        rep.heading("Further results")
        rep.kv_table(more)
    rep.warnings(warn)
    rep.heading("Accuracy: the UKF beside the smoother")
    rep.text("Median 1-sigma each solution claims" + (", and its errors against the true trajectory (mean, std, "
             "RMS) with the RMS of error / sigma" if res.truth is not None else " (give --truth for the errors)")
             + f", over the epochs after the first {s['skip_s']:g} s that both share"
             + ("; rows ukf_outages: the UKF alone on its epochs inside the GNSS outages" if outages else "")
             + f". Seed 000 (real flight, vs a vertical gyro): roll std {SEED000['roll']} deg, pitch std "
             f"{SEED000['pitch']} deg.")
    rep.table(["solution", "quantity", "unit", "median σ (unit column)", "mean error (unit column)",
               "error std (unit column)", "error RMS (unit column)", "error/σ RMS"],
              [[r.get("solution"), r.get("quantity"), canonical_unit(r.get("unit"))]
               + [fmt_number(r.get(c), r.get("unit")) for c in ACCURACY_COLUMNS[3:7]]
               + [fmt_number(r.get("normalised_rms"), "", decimals=2)] for r in rows])
    rep.heading("Sigma envelopes").figure(partial(_sigmas, res), "1-sigma of the UKF (and the smoother, dashed)")
    if res.truth is not None:
        rep.heading("Errors against the truth").figure(partial(_errors, res),
                                                       "Attitude errors with the UKF's 1-sigma band")
    rep.heading("Innovations").figure(partial(_innovations, res), "Normalised innovation squared per degree of freedom")
    return rep.write(path)


def write_ukf_outputs(out_dir: str | Path, res: UkfPosResult, names: Mapping[str, str], report: bool = True
                      ) -> dict[str, Path]:
    """`dgcal pos --mode ukf`'s files in `out_dir`, by role in `names`: trajectory (output rate), events (one row per
    event), trajectory_fixes (every filter epoch: each fix, and the IMU's predictions where no fix is near, as in GNSS
    outages), accuracy (CSV), summary (JSON), report (HTML, unless `report` is False); returns the paths."""
    out = Path(out_dir)
    paths = {"trajectory": out / names["trajectory"]}
    write_trajectory(paths["trajectory"], res.trajectory)
    if res.events is not None:
        paths["events"] = out / names["events"]
        write_trajectory(paths["events"], res.events)
    paths["trajectory_fixes"] = out / names["trajectory_fixes"]
    write_trajectory(paths["trajectory_fixes"], res.keyframes)
    paths["accuracy"] = out / names["accuracy"]
    write_accuracy_csv(paths["accuracy"], res.table)
    paths["summary"] = out / names["summary"]
    with atomic_write(paths["summary"]) as fh:
        json.dump(res.summary, fh, indent=2)
    if report:
        paths["report"] = write_ukf_report(out / names["report"], res)
    return paths
