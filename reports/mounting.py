"""HTML reports (single file, PNG plots embedded as base64) of the mounting calibration and of DG check points."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.calib.dg.accuracy import DgCheck
from dgcal.calib.mounting.methods import MountingRun
from dgcal.fields.io.csv_tables import atomic_write, write_table
from dgcal.reports.boresight import CAPTION as BORESIGHT_CAPTION
from dgcal.reports.boresight import boresight_angles_deg
from dgcal.reports.glossary import METHOD_NOTE, label, method_name
from dgcal.reports.honesty import add_honesty, combined_sigma, honesty_rows, honesty_section, no_reference
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.units import fmt_number, fmt_value, pm, with_unit


def improvement_pct(checks: dict, reference: str | None = None) -> dict:
    """Improvement of every method's 2D and 3D check-point RMS over the `reference` method's (default: the first),
    in percent of the old: (old − new) / old × 100 (positive: the method is better)."""
    if not checks:
        return {}
    ref = reference if reference in checks else next(iter(checks))
    old = checks[ref]["stats"]["rms"]
    return {k: {q: (100.0 * (old[q] - c["stats"]["rms"][q]) / old[q] if old[q] else float("nan"))
                for q in ("2D", "3D")} for k, c in checks.items() if k != ref}


IMPROVEMENT_NOTE = ("Improvement = (old − new) / old × 100 %, old the RMS error of the reference method: the share of "
                    "its error the method removes (100 % = no error left; negative: worse). The seed paper's Tables "
                    "4–5 divide by the new RMS instead, (old − new) / new, which exceeds 100 % when the error drops "
                    "below half.")


def mount_row(name: str, r: dict) -> list:
    """One method's estimates as text: delay, lever arm x/y/z and boresight angles about body x/y/z with sigmas."""
    held = r.get("delay_sigma_s", 0.0) == 0.0          # two-step (or a held delay): not estimated
    theta, _ = boresight_angles_deg(r["boresight_R_cam_to_body"])
    return ([method_name(name), "not estimated (0)" if held else pm(1e3 * r["delay_s"], 1e3 * r["delay_sigma_s"],
                                                                   "ms")]
            + [pm(v, s, "m") for v, s in zip(r["lever_arm_m"], r["lever_arm_sigma_m"])]
            + [pm(v, s, "°") for v, s in zip(theta, r["boresight_sigma_deg"])] + [r.get("n_epochs", "")])


MOUNT_HEADER = ["method", "exposure delay (ms)", "lever arm x (m)", "lever arm y (m)", "lever arm z (m)",
                "boresight θx (°)", "boresight θy (°)", "boresight θz (°)", "epochs"]
LEVER_NOTE = ("Lever arm: IMU origin → camera perspective centre, body axes (x forward, y right, z down). Exposure "
              "delay = exposure time − event time.")


def add_boresight_matrices(rep: HtmlReport, R_cam_to_body) -> None:
    """R_cam_to_body and the nominal mounting it is measured from, as two small tables, with the caption."""
    theta, R_nom = boresight_angles_deg(R_cam_to_body)
    R = np.asarray(R_cam_to_body, float)
    rep.table(["R_cam_to_body (unitless)", "camera x", "camera y", "camera z"],
              [[f"body {'xyz'[i]}", *(f"{v:+.8f}" for v in R[i])] for i in range(3)])
    rep.table(["R_nominal (unitless)", "camera x", "camera y", "camera z"],
              [[f"body {'xyz'[i]}", *(f"{v:+.0f}" for v in R_nom[i])] for i in range(3)])
    rep.text(BORESIGHT_CAPTION, cls="small")


def _per_epoch_plots(results: dict) -> list:
    figs = []
    fig, axes = new_figure(10, 7, nrows=3, ncols=1, sharex=True)
    for name, res in results.items():
        pe = res.get("per_epoch") or {}
        if "lever_arm_m" not in pe:
            continue
        la = np.array(pe["lever_arm_m"])
        for k, ax in enumerate(axes):
            ax.plot(la[:, k], ".", ms=3, label=f"{method_name(name)} per epoch")
            ax.axhline(res["lever_arm_m"][k], lw=1, color=ax.lines[-1].get_color())
            ax.set_ylabel(f"lever {'xyz'[k]} (m)")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("epoch")
    fig.suptitle("Lever arm per epoch (seed 003 Fig. 22): an uncalibrated delay shows as a speed-dependent bias")
    figs.append(fig)
    fig, axes = new_figure(10, 6, nrows=3, ncols=1, sharex=True)
    for name, res in results.items():
        pe = res.get("per_epoch") or {}
        if "boresight_deg" not in pe:
            continue
        b = np.array(pe["boresight_deg"])
        for k, ax in enumerate(axes):
            ax.plot(b[:, k], ".", ms=3, label=method_name(name))
            ax.set_ylabel(f"about body {'xyz'[k]} (deg)")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("epoch")
    fig.suptitle("Boresight per epoch, relative to the estimate")
    figs.append(fig)
    for name, res in results.items():
        pe = res.get("per_epoch") or {}
        if "residual_position_m" in pe:
            rp, rr = np.array(pe["residual_position_m"]), np.array(pe["residual_rotation_deg"])
            rej = np.array(pe.get("rejected", [False] * len(rp)))
            fig, axes = new_figure(10, 5, nrows=2, ncols=1, sharex=True)
            for k in range(3):
                axes[0].plot(rp[:, k], ".", ms=3, label="ENU"[k])
                axes[1].plot(rr[:, k], ".", ms=3, label=f"cam {'xyz'[k]}")
            if rej.any():
                axes[0].plot(np.nonzero(rej)[0], rp[rej, 0], "kx", label="rejected")
            axes[0].set_ylabel("position residual (m)")
            axes[1].set_ylabel("rotation residual (deg)")
            axes[0].legend(fontsize=8, ncol=4)
            axes[1].legend(fontsize=8, ncol=3)
            axes[1].set_xlabel("epoch")
            fig.suptitle(f"{method_name(name)}: residuals per epoch")
            figs.append(fig)
    return figs


MOUNT_NO_REFERENCE = ("No reference: the mounting's errors are known only against a simulation's truth (the "
                      "campaign report with `truth`); on real data its sigmas are checked through the DG check "
                      "points (dgcal check).")


def mount_report_html(main: dict, others: dict | None = None) -> str:
    """The mounting report: the estimate with sigmas at the top, every method beside it, correlations, warnings,
    per-epoch plots and residuals."""
    results = {main["method"]: main, **(others or {})}
    rep = HtmlReport("dgcal mounting calibration")
    m = main
    theta, _ = boresight_angles_deg(m["boresight_R_cam_to_body"])
    held = m.get("delay_sigma_s", 0.0) == 0.0
    rep.headline([
        ("method", method_name(m["method"])),
        ("exposure delay (ms)", "not estimated (0)" if held else pm(1e3 * m["delay_s"], 1e3 * m["delay_sigma_s"],
                                                                    "ms")),
        ("lever arm x, y, z (m)", ", ".join(pm(v, s, "m") for v, s in zip(m["lever_arm_m"],
                                                                           m["lever_arm_sigma_m"]))),
        ("boresight θx, θy, θz about body axes (°)", ", ".join(pm(v, s, "°") for v, s in
                                                               zip(theta, m["boresight_sigma_deg"]))),
        ("epochs", m.get("n_epochs"))], "The mounting to use for direct georeferencing, with 1-sigma:")
    rep.heading("Estimates of every method")
    rep.table(MOUNT_HEADER, [mount_row(k, r) for k, r in results.items()])
    rep.text(LEVER_NOTE + " " + METHOD_NOTE, cls="small")
    add_boresight_matrices(rep, m["boresight_R_cam_to_body"])
    if m.get("correlation"):
        names = [label(n) for n in m.get("parameters", [])]
        corr = m["correlation"]
        rep.heading("Correlations (unitless)")
        rep.table(["correlation (unitless)"] + names,
                  [[names[i]] + ["" if v is None else fmt_number(v, "", decimals=3) for v in corr[i]]
                   for i in range(len(names))])
    rep.kv_table([(k, m[k]) for k in ("sigma0", "redundancy", "covariance_scaled_by") if k in m])
    rep.heading("Warnings")
    rep.warnings(m.get("warnings", []))
    if m.get("rejected_epochs"):
        rep.heading("Rejected epochs")
        rep.text(", ".join(map(str, m["rejected_epochs"])))
    add_honesty(rep, no_reference(MOUNT_NO_REFERENCE))
    rep.heading("Per-epoch values")
    for fig in _per_epoch_plots(results):
        rep.figure(fig)
    return rep.render()


def check_honesty(checks: dict) -> dict:
    """The honesty record of a DG check (dgcal.reports.honesty) from its JSON record per method (`checks`): every
    check point's E/N/U error over its predicted sigma (all sources of the budget) and the check points' own survey
    sigma in quadrature. The survey sigmas are known here as their RMS over the points (ASPRS 2023 record:
    E = N = checkpoint RMSE_H/sqrt(2), U = checkpoint RMSE_V), so each point is given that RMS."""
    rows, surveyed = [], []
    for name, c in checks.items():
        pts = c.get("points", [])
        err = np.array([p["err_enu"] for p in pts], float).reshape(-1, 3)
        sig = np.array([p["sigma_pred_enu"] for p in pts], float).reshape(-1, 3)
        a = c.get("asprs_2023", {})
        survey = None
        if a.get("checkpoint_RMSE_H") is not None and a.get("checkpoint_RMSE_V") is not None:
            survey = np.array([a["checkpoint_RMSE_H"] / np.sqrt(2.0)] * 2 + [a["checkpoint_RMSE_V"]])
            surveyed.append(name)
        rows += honesty_rows(err, combined_sigma(sig, survey), ("E", "N", "U"), f"check points, {method_name(name)}")
    if not rows:
        return no_reference("No check point was evaluated: nothing to compare the DG coordinates with.")
    notes = ["Check points (role check in the ground point file): each point's DG error (map E, N, height) over "
             "its predicted sigma from the error budget (image measurements, POS, delay, lever arm, boresight)."]
    if surveyed:
        notes.append("The check points' own survey sigmas are added in quadrature (their RMS over the points: "
                     "E = N = checkpoint RMSE_H/√2, U = checkpoint RMSE_V).")
    if len(surveyed) < len(checks):
        notes.append("Without survey sigmas for every check point (" + ", ".join(k for k in checks if k not in
                     surveyed) + ") the check points are taken as exact there.")
    notes.append("Check points seen from the same strips share its POS errors: their errors are correlated, so n "
                 "overstates the number of independent values.")
    return honesty_section(rows, notes)


AXES = ("E", "N", "U", "2D", "3D")


def check_report_html(checks: dict, improvement: dict | None = None, honesty: dict | None = None) -> str:
    """DG check-point report: the RMS per method at the top, seed Table 2 per method, improvement over the first
    method ((old − new)/old, recomputed from the RMS; `improvement` only says whether to show it), ASPRS 2023,
    predicted budget, the honesty table (`honesty`; None: from `checks`), plot."""
    rep = HtmlReport("dgcal DG check points")
    rep.headline([(f"{method_name(k)}: RMS 2D, 3D on {c['stats']['n']} check points (m)",
                   [c["stats"]["rms"]["2D"], c["stats"]["rms"]["3D"]]) for k, c in checks.items()],
                 "Direct georeferencing on the check points:")
    rep.heading("DG check-point errors, seed 003 Table 2")
    rep.table(["method", "check points", "statistic", *(f"{a} (m)" for a in AXES)],
              [[method_name(name), c["stats"]["n"], what.upper(), *(c["stats"][what][k] for k in AXES)]
               for name, c in checks.items() for what in ("avg", "std", "rms")])
    add_honesty(rep, honesty if honesty is not None else check_honesty(checks))
    imp = improvement_pct(checks)
    if improvement is not None and imp:
        ref = method_name(next(iter(checks)))
        rep.heading(f"Improvement over the {ref} method")
        rep.table(["method", "2D improvement (%)", "3D improvement (%)"],
                  [[method_name(k), v["2D"], v["3D"]] for k, v in imp.items()])
        rep.text(IMPROVEMENT_NOTE, cls="small")
    rep.heading("ASPRS Positional Accuracy Standards (2023)")
    rep.table(["method", "check points", "RMSE x (m)", "RMSE y (m)", "RMSE horizontal (m)", "RMSE vertical (m)",
               "RMSE horizontal incl. survey (m)", "RMSE vertical incl. survey (m)"],
              [[method_name(name), a["n_checkpoints"], a["RMSE_x"], a["RMSE_y"], a["RMSE_H"], a["RMSE_V"],
                a.get("product_RMSE_H"), a.get("product_RMSE_V")] for name, a in
               ((n, c["asprs_2023"]) for n, c in checks.items())])
    for name, c in checks.items():
        b = c["budget"]
        mag = b.get("magnitudes", {})
        rep.heading(f"{method_name(name)}: error budget (seed Table 6), RMS σ on the ground")
        rep.table(["source", "magnitude", *(f"{a} (m)" for a in AXES)],
                  [[label(k), fmt_value(mag.get(k, "")), *(v[q] for q in AXES)] for k, v in b["sources"].items()]
                  + [["predicted total", "", *(b["predicted_rms"][q] for q in AXES)],
                     ["achieved", "", *(b["achieved_rms"][q] for q in AXES)]])
        rep.text(f"mean flying height {with_unit(round(b['mean_flying_height_m']), 'm')}, mean speed "
                 f"{b['mean_speed_m_s']:.1f} m/s", cls="small")
        rep.warnings(c.get("warnings", []) + c["asprs_2023"].get("warnings", []), f"{method_name(name)}: no warnings.")
    fig, axes = new_figure(5 * len(checks), 4.8, nrows=1, ncols=len(checks), squeeze=False)
    # one arrow scale for all methods, so the panels compare
    emax = max(max(np.hypot(p["err_enu"][0], p["err_enu"][1]) for p in c["points"]) for c in checks.values())
    ref_all = np.array([p["ref"] for c in checks.values() for p in c["points"]])
    origin = ref_all[:, :2].mean(axis=0)
    span = max(float(np.ptp(ref_all[:, 0])), float(np.ptp(ref_all[:, 1])), 1.0)
    k = 0.15 * span / max(emax, 1e-9)  # the largest error is drawn 15 % of the block wide
    for ax, (name, c) in zip(axes[0], checks.items()):
        ref = np.array([p["ref"] for p in c["points"]])[:, :2] - origin
        err = np.array([p["err_enu"] for p in c["points"]])
        ax.quiver(ref[:, 0], ref[:, 1], err[:, 0] * k, err[:, 1] * k, angles="xy", scale_units="xy", scale=1)
        ax.set_title(f"{method_name(name)}: horizontal errors", fontsize=9)
        ax.set_xlabel("E − E0 (m)")
        ax.set_ylabel("N − N0 (m)")
        ax.set_aspect("equal")
    rep.figure(fig, f"Horizontal DG errors on the check points: arrows {with_unit(emax, 'm')} error drawn as "
                    f"{0.15 * span:.0f} m (the same scale in every panel); E0, N0 the check points' centre.")
    return rep.render()


# ----------------------------------------------------------------------------------------------- outputs
def write_mount_outputs(out_dir: str | Path, run: MountingRun, names: Mapping[str, str]) -> dict[str, Path]:
    """Write `dgcal mount`'s files into `out_dir` under `names` (roles mounting, report, epochs): mounting.json,
    the HTML report (with the reference methods) and the per-epoch CSV; returns the paths by role."""
    out = Path(out_dir)
    main = run.result.to_json()
    paths = {role: out / names[role] for role in ("mounting", "report", "epochs")}
    with atomic_write(paths["mounting"]) as fh:
        json.dump(main, fh, indent=2)
        fh.write("\n")
    with atomic_write(paths["report"]) as fh:
        fh.write(mount_report_html(main, {k: r.to_json() for k, r in run.references.items()}))
    if not write_epochs_csv(paths["epochs"], main):
        del paths["epochs"]
    return paths


def write_epochs_csv(path: Path, d: dict) -> bool:
    """Per-epoch values of a mounting.json record as CSV (lever arm m, boresight deg, residuals, rejection);
    False (nothing written) when the record has no per-epoch values."""
    pe = d.get("per_epoch") or {}
    if "image" not in pe:
        return False
    cols = [("lever_x", "lever_arm_m", 0), ("lever_y", "lever_arm_m", 1), ("lever_z", "lever_arm_m", 2),
            ("bore_x_deg", "boresight_deg", 0), ("bore_y_deg", "boresight_deg", 1), ("bore_z_deg", "boresight_deg", 2),
            ("res_e_m", "residual_position_m", 0), ("res_n_m", "residual_position_m", 1),
            ("res_u_m", "residual_position_m", 2), ("res_rx_deg", "residual_rotation_deg", 0),
            ("res_ry_deg", "residual_rotation_deg", 1), ("res_rz_deg", "residual_rotation_deg", 2)]
    cols = [c for c in cols if c[1] in pe]
    rows = []
    for i, im in enumerate(pe["image"]):
        rows.append([im] + [pe[k][i][j] for _, k, j in cols] + [int(bool(pe.get("rejected", [False] * (i + 1))[i]))])
    write_table(path, ["image"] + [c[0] for c in cols] + ["rejected"], rows, fmt="%.6f")
    return True


def write_check_outputs(out_dir: str | Path, res: DgCheck, names: Mapping[str, str]) -> dict[str, Path]:
    """Write `dgcal check`'s files into `out_dir` under `names` (roles check, report, points): the JSON record
    (per method, the improvement over the first, and the honesty record `honesty`: `check_honesty`), the HTML
    report and the per-point CSV (m)."""
    out = Path(out_dir)
    paths = {role: out / names[role] for role in ("check", "report", "points")}
    js = {k: v.to_json() for k, v in res.checks.items()}
    honesty = check_honesty(js)
    with atomic_write(paths["check"]) as fh:
        json.dump({"checks": js, "improvement_over_" + res.reference: res.improvement, "honesty": honesty}, fh,
                  indent=2)
    with atomic_write(paths["report"]) as fh:
        fh.write(check_report_html(js, res.improvement, honesty))
    rows = []
    for k, c in res.checks.items():
        for i in range(len(c.ids)):
            rows.append([k, c.ids[i], *c.xyz_dg[i], *c.err_enu[i], *c.sigma_pred[i], int(c.n_rays[i])])
    write_table(paths["points"], ["method", "id", "x", "y", "z", "dE", "dN", "dU", "sE_pred", "sN_pred", "sU_pred",
                                  "n_rays"], rows, fmt="%.4f")
    return paths


def write_comparison_json(path: str | Path, comparison: dict) -> Path:
    """Write the result of dgcal.calib.mounting.compare.compare_mountings as JSON (atomically)."""
    with atomic_write(path) as fh:
        json.dump(comparison, fh, indent=2)
    return Path(path)
