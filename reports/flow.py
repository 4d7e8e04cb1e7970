"""Files and HTML report of `dgcal flow` (dgcal.pos.lowcost.flow): the per-pair attitude table, flow.json with seed
001's Table 2 when a truth is given, and plots of attitude, FOE offsets and height above ground."""
from __future__ import annotations

from functools import partial

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.lowcost.flow import ROW_COLUMNS, FlowRun
from dgcal.reports.honesty import add_honesty, honesty_rows, honesty_section, no_reference
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.units import WEEK_S, fmt_number

TRUTH_COLUMNS = ("true_roll", "true_pitch", "true_yaw", "err_roll", "err_pitch", "err_yaw", "true_agl_m", "err_agl_m")


def write_flow_csv(path: Path, run: FlowRun) -> None:
    """One row per frame pair: ROW_COLUMNS (deg, m, normalised image coordinates), then the truth columns."""
    cols = list(ROW_COLUMNS) + [c for c in TRUTH_COLUMNS if any(c in r for r in run.rows)]
    with atomic_write(path) as fh:
        fh.write(",".join(cols) + "\n")
        for r in run.rows:
            cells = []
            for c in cols:
                v = r.get(c, "")
                cells.append(f"{v:.6f}" if isinstance(v, float) else str(v))
            fh.write(",".join(cells) + "\n")


def _col(run: FlowRun, k: str) -> np.ndarray:
    return np.array([r.get(k, np.nan) for r in run.rows], float)


def _attitude(run: FlowRun):
    fig, axs = new_figure(9, 7.5, nrows=3, sharex=True)
    t = _col(run, "t_gps")
    t = t - t[0]
    for a, name in zip(axs, ("roll", "pitch", "yaw")):
        a.errorbar(t, _col(run, name), yerr=_col(run, f"sigma_{name}"), fmt=".", ms=3, lw=0.6, label="flow attitude")
        a.plot(t, _col(run, f"pseudo_{name}"), ".", ms=2, alpha=0.6, label="pseudo (GNSS)")
        if any("true_" + name in r for r in run.rows):
            a.plot(t, _col(run, "true_" + name), "-", lw=0.7, color="k", label="truth")
        a.set_ylabel(f"{name} (deg)")
        a.grid(alpha=0.3)
    axs[0].legend(fontsize=7, ncol=3)
    axs[-1].set_xlabel("time since first pair (s)")
    return fig


def _offsets(run: FlowRun):
    fig, axs = new_figure(9, 5, nrows=2, sharex=True)
    t = _col(run, "t_gps")
    t = t - t[0]
    axs[0].plot(t, _col(run, "angle_of_attack"), ".", ms=3, label="pitch - pseudo-pitch (angle of attack)")
    axs[0].plot(t, _col(run, "drift_angle"), ".", ms=3, label="yaw - pseudo-yaw (drift angle)")
    axs[0].set_ylabel("deg")
    axs[0].legend(fontsize=7)
    axs[1].errorbar(t, _col(run, "agl_m"), yerr=_col(run, "sigma_agl_m"), fmt=".", ms=3, lw=0.6, label="AGL from flow")
    if any("true_agl_m" in r for r in run.rows):
        axs[1].plot(t, _col(run, "true_agl_m"), "-", lw=0.7, color="k", label="truth")
    axs[1].set_ylabel("height above ground (m)")
    axs[1].set_xlabel("time since first pair (s)")
    axs[1].legend(fontsize=7)
    for a in axs:
        a.grid(alpha=0.3)
    return fig


def _errors(run: FlowRun):
    fig, axs = new_figure(9, 6.5, nrows=3, sharex=True)
    t = _col(run, "t_gps")
    t = t - t[0]
    for a, name in zip(axs, ("roll", "pitch", "yaw")):
        s = _col(run, f"sigma_{name}")
        a.fill_between(t, -s, s, alpha=0.25, step="mid", label="1 sigma")
        a.plot(t, _col(run, f"err_{name}"), ".", ms=3, label="error")
        a.set_ylabel(f"{name} error (deg)")
        a.grid(alpha=0.3)
    axs[0].legend(fontsize=7)
    axs[-1].set_xlabel("time since first pair (s)")
    return fig


def flow_honesty(run: FlowRun) -> dict:
    """The honesty record of a flow run (dgcal.reports.honesty): with a true trajectory, every frame pair's roll,
    pitch and yaw error (and height above ground, with a ground height) over the pair's sigma; without one the line
    that there is no reference."""
    if run.table2 is None:
        return no_reference("No reference: give a true trajectory (--truth) to compare the attitudes with it.")
    rows = honesty_rows(np.column_stack([_col(run, f"err_{a}") for a in ("roll", "pitch", "yaw")]),
                        np.column_stack([_col(run, f"sigma_{a}") for a in ("roll", "pitch", "yaw")]),
                        ("roll", "pitch", "yaw"), "true trajectory", "deg")
    rows += honesty_rows(_col(run, "err_agl_m"), _col(run, "sigma_agl_m"), ["height above ground"],
                         "true trajectory")
    return honesty_section(rows, ["True trajectory (--truth; the height above ground with --ground-height): each "
                                  "frame pair's error over its sigma, the truth taken as exact. Errors of "
                                  "neighbouring pairs are correlated in time: n overstates the number of "
                                  "independent values."])


def write_flow_report(path: Path, run: FlowRun) -> Path:
    """One-file HTML report of a `dgcal flow` run."""
    s = run.summary
    rep = HtmlReport("GNSS / optic-flow attitude (seed 001)")
    m = s["median"]
    rep.headline([("median σ roll, pitch, yaw (°)", [m["sigma_roll"], m["sigma_pitch"], m["sigma_yaw"]]),
                  ("frame pairs with an attitude", s["n_pairs"])],
                 "Attitude from GNSS velocity and the forward camera's optic flow: its 1-sigma.")
    rep.kv_table([("frame pairs", s["n_pairs"]), ("pairs that failed", s["n_failed"]),
                  ("a pair every (s)", s["pair_every_s"]), ("frames apart (s)", s["frame_dt_s"]),
                  ("GNSS velocity noise (m/s, per axis)", s["gnss_velocity_sigma_mps"]),
                  ("median angle of attack (°)", m["angle_of_attack"]),
                  ("median drift angle (°)", m["drift_angle"]),
                  ("median height above ground (m)", m["agl_m"]), ("median FOE inliers", m["n_inliers"])])
    rep.warnings([f"pair at {f['t_gps'] % WEEK_S:.2f} s of GPS week: {f['reason']}" for f in s["failed"][:20]],
                 "Every frame pair gave an attitude.")
    add_honesty(rep, s.get("honesty") or flow_honesty(run))
    t2 = run.table2
    if t2 is not None:
        rep.heading("Seed 001 Table 2: Euler angle errors")
        axes = ("roll", "pitch", "yaw")
        rep.table(["quantity (unit)", "roll (unit of the row)", "pitch (unit of the row)", "yaw (unit of the row)"],
                  [["error mean (°)"] + [fmt_number(t2[k]["mean_deg"], "°") for k in axes],
                   ["error std (°)"] + [fmt_number(t2[k]["std_deg"], "°") for k in axes],
                   ["error/σ RMS (unitless)"] + [fmt_number(t2[k]["normalised_rms"], "", decimals=2) for k in axes],
                   ["seed 001 mean (°)"] + [fmt_number(t2["seed001"][k]["mean_deg"], "°") for k in axes],
                   ["seed 001 std (°)"] + [fmt_number(t2["seed001"][k]["std_deg"], "°") for k in axes]])
        po = t2["pseudo_only"]
        txt = (f"Pseudo attitude alone: pitch off by {po['pitch_mean_deg']:.2f}°, "
               f"yaw by {po['yaw_mean_deg']:.2f}° "
               "(angle of attack and drift); the focus of expansion removes them.")
        if "agl" in t2:
            a = t2["agl"]
            txt += (f" Height above ground: error {a['mean_error_m']:.2f} ± {a['std_error_m']:.2f} m "
                    f"(median {100 * a['median_rel_error']:.1f} %).")
        rep.text(txt)
        rep.figure(partial(_errors, run), "Errors against the truth with the claimed 1-sigma band")
    rep.heading("Attitude").figure(partial(_attitude, run), "Flow attitude (with 1 sigma) and the GNSS pseudo attitude")
    rep.heading("FOE offsets and height above ground").figure(partial(_offsets, run),
                                                              "Angle of attack, drift angle, AGL")
    return rep.write(path)


def write_flow_outputs(out_dir: str | Path, run: FlowRun, names: Mapping[str, str]) -> dict[str, Path]:
    """`dgcal flow`'s files in `out_dir`, by role in `names`: pairs (flow.csv), summary (flow.json, with the honesty
    record `honesty`: `flow_honesty`), report (HTML)."""
    out = Path(out_dir)
    paths = {k: out / names[k] for k in ("pairs", "summary", "report")}
    run.summary["honesty"] = flow_honesty(run)
    write_flow_csv(paths["pairs"], run)
    with atomic_write(paths["summary"]) as fh:
        json.dump(run.summary, fh, indent=1)
    write_flow_report(paths["report"], run)
    return paths
