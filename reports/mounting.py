"""HTML reports (single file, PNG plots embedded as base64) of the mounting calibration and of DG check points."""
from __future__ import annotations

import base64
import html
import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.calib.dg.accuracy import DgCheck
from dgcal.calib.mounting.methods import MountingRun
from dgcal.fields.io.csv_tables import atomic_write, write_table
from dgcal.reports.honesty import combined_sigma, honesty_html, honesty_rows, honesty_section, no_reference
from dgcal.reports.html import figures_png, new_figure


def _png(fig) -> str:
    return _imgs([fig])[0]


def _imgs(figs: list) -> list[str]:
    """<img> elements of figures drawn side by side (`figures_png`)."""
    pngs = figures_png(figs, dpi=90)
    return [f'<img alt="plot" src="data:image/png;base64,{base64.b64encode(p).decode()}">' for p in pngs]


def _table(header, rows) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}table{border-collapse:collapse;"
        "margin:.5em 0}td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}th{background:#eee}"
        ".warn{color:#a40}img{max-width:100%}@media print{img{max-width:90%}}")


def _page(title: str, parts: list[str]) -> str:
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>{''.join(parts)}</body></html>\n")


def _per_epoch_plots(results: dict) -> list[str]:
    figs = []
    fig, axes = new_figure(10, 7, nrows=3, ncols=1, sharex=True)
    for name, res in results.items():
        pe = res.get("per_epoch") or {}
        if "lever_arm_m" not in pe:
            continue
        la = np.array(pe["lever_arm_m"])
        for k, ax in enumerate(axes):
            ax.plot(la[:, k], ".", ms=3, label=f"{name} per epoch")
            ax.axhline(res["lever_arm_m"][k], lw=1, color=ax.lines[-1].get_color())
            ax.set_ylabel(f"lever {'xyz'[k]} (m)")
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
            ax.plot(b[:, k], ".", ms=3, label=name)
            ax.set_ylabel(f"about body {'xyz'[k]} (deg)")
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
            fig.suptitle(f"{name}: residuals per epoch")
            figs.append(fig)
    return _imgs(figs)


MOUNT_NO_REFERENCE = ("No reference: the mounting's errors are known only against a simulation's truth (the "
                      "campaign report with `truth`); on real data its sigmas are checked through the DG check "
                      "points (dgcal check).")


def mount_report_html(main: dict, others: dict | None = None) -> str:
    """The mounting report: estimates with sigmas, correlations, warnings, per-epoch plots and residuals."""
    parts = []
    results = {main["method"]: main, **(others or {})}
    rows = []
    for name, r in results.items():
        held = r.get("delay_sigma_s", 0.0) == 0.0          # two-step (or a held delay): not estimated
        rows.append([name, "not estimated (0)" if held else f"{r['delay_s']:.5f} ± {r['delay_sigma_s']:.5f}"]
                    + [f"{v:.4f} ± {s:.4f}" for v, s in zip(r["lever_arm_m"], r["lever_arm_sigma_m"])]
                    + [f"{v:.4f}" for v in r["boresight_rpy_deg"]]
                    + [f"{s:.4f}" for s in r["boresight_sigma_deg"]] + [r.get("n_epochs", "")])
    parts.append("<h2>Estimates</h2>" + _table(
        ["method", "delay (s)", "lever x (m)", "lever y (m)", "lever z (m)", "bore roll (deg)", "bore pitch (deg)",
         "bore yaw (deg)", "σ about x (deg)", "σ about y (deg)", "σ about z (deg)", "epochs"], rows))
    parts.append("<p>Lever arm: IMU → camera perspective centre, body FRD. Boresight: R_cam_to_body = "
                 "Rz(yaw) Ry(pitch) Rx(roll) (CV camera → body); its sigmas are small rotations about body axes. "
                 "Delay = t_exposure − t_event.</p>")
    R_cam_to_body = np.array(main["boresight_R_cam_to_body"])
    parts.append("<h3>R_cam_to_body</h3>" + _table(["", "cam x", "cam y", "cam z"],
                                                   [[f"body {'xyz'[i]}"] + [f"{v:.8f}" for v in R_cam_to_body[i]]
                                                    for i in range(3)]))
    if main.get("correlation"):
        names = main.get("parameters", [])
        corr = main["correlation"]
        parts.append("<h2>Correlations</h2>" + _table(
            [""] + names, [[names[i]] + ["" if v is None else f"{v:+.3f}" for v in corr[i]]
                           for i in range(len(names))]))
    for k in ("sigma0", "redundancy", "covariance_scaled_by", "boresight_parameterisation", "propagation"):
        if k in main:
            parts.append(f"<p><b>{k}</b>: {html.escape(str(main[k]))}</p>")
    warn = main.get("warnings", [])
    parts.append("<h2>Warnings</h2>"
                 + ("".join(f"<p class='warn'>{html.escape(w)}</p>" for w in warn) or "<p>none</p>"))
    if main.get("rejected_epochs"):
        parts.append("<h2>Rejected epochs</h2><p>" + html.escape(", ".join(main["rejected_epochs"])) + "</p>")
    parts.append(honesty_html(no_reference(MOUNT_NO_REFERENCE)))
    parts.append("<h2>Per-epoch values</h2>" + "".join(_per_epoch_plots(results)))
    return _page("dgcal mounting calibration", parts)


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
        rows += honesty_rows(err, combined_sigma(sig, survey), ("E", "N", "U"), f"check points, {name}")
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


def check_report_html(checks: dict, improvement: dict | None = None, honesty: dict | None = None) -> str:
    """DG check-point report: seed Table 2 per method, improvement rates, ASPRS 2023, predicted budget, the honesty
    table (`honesty`; None: from `checks`), plot."""
    parts = []
    rows = []
    for name, c in checks.items():
        s = c["stats"]
        for what in ("avg", "std", "rms"):
            rows.append([f"{name} ({s['n']})", what.upper()]
                        + [f"{s[what][k]:.4f}" for k in ("E", "N", "U", "2D", "3D")])
    parts.append("<h2>DG check-point errors (m), seed 003 Table 2</h2>"
                 + _table(["method", "", "E", "N", "U", "2D", "3D"], rows))
    parts.append(honesty_html(honesty if honesty is not None else check_honesty(checks)))
    if improvement:
        parts.append("<h2>Improvement rates (%), seed Tables 4-5: (old − new)/new</h2>" + _table(
            ["method", "2D", "3D"], [[k, f"{v['2D']:.2f}", f"{v['3D']:.2f}"] for k, v in improvement.items()]))
    rows = []
    for name, c in checks.items():
        a = c["asprs_2023"]
        rows.append([name, a["n_checkpoints"], f"{a['RMSE_x']:.4f}", f"{a['RMSE_y']:.4f}", f"{a['RMSE_H']:.4f}",
                     f"{a['RMSE_V']:.4f}", f"{a.get('product_RMSE_H', float('nan')):.4f}",
                     f"{a.get('product_RMSE_V', float('nan')):.4f}"])
    parts.append("<h2>ASPRS Positional Accuracy Standards (2023)</h2>" + _table(
        ["method", "check points", "RMSE_x", "RMSE_y", "RMSE_H", "RMSE_V", "RMSE_H incl. survey",
         "RMSE_V incl. survey"], rows))
    for name, c in checks.items():
        b = c["budget"]
        mag = b.get("magnitudes", {})
        rows = [[k, mag.get(k, "")] + [f"{v[q]:.4f}" for q in ("E", "N", "U", "2D", "3D")]
                for k, v in b["sources"].items()]
        rows.append(["predicted total", ""] + [f"{b['predicted_rms'][q]:.4f}" for q in ("E", "N", "U", "2D", "3D")])
        rows.append(["achieved", ""] + [f"{b['achieved_rms'][q]:.4f}" for q in ("E", "N", "U", "2D", "3D")])
        parts.append(f"<h2>{html.escape(name)}: error budget (seed Table 6), RMS σ on the ground (m)</h2>"
                     + _table(["source", "magnitude", "E", "N", "U", "2D", "3D"], rows)
                     + f"<p>mean flying height {b['mean_flying_height_m']:.0f} m, mean speed "
                       f"{b['mean_speed_m_s']:.1f} m/s</p>")
        for w in c.get("warnings", []) + c["asprs_2023"].get("warnings", []):
            parts.append(f"<p class='warn'>{html.escape(w)}</p>")
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
        ax.set_title(f"{name}: horizontal errors", fontsize=9)
        ax.set_xlabel("E − E0 (m)")
        ax.set_ylabel("N − N0 (m)")
        ax.set_aspect("equal")
    fig.suptitle(f"arrows: {emax:.3f} m error drawn as {0.15 * span:.0f} m (same scale in every panel)", fontsize=9)
    parts.append(_png(fig))
    return _page("dgcal DG check points", parts)


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
