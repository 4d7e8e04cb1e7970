"""The calibration report of a campaign (`dgcal run`): one printable HTML page and one JSON file with every
number of the chain — camera, aerial triangulation, POS, mounting (each method, sigmas, correlations), DG
accuracy on the check points against the predicted budget — and every warning, read from the JSON outputs
of the steps; figures are embedded (base64 PNG) and the per-step reports are linked.

With a simulation's `truth.json` (campaign key `truth`) the report also compares the estimates with the truth
(errors and error/sigma ratios). The honesty table (dgcal.reports.honesty) gathers the steps' own (check points,
withheld fixes) and, with a truth, the mounting, camera, trajectory and EOPs against it.
"""
from __future__ import annotations

import datetime
import json
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import camera_from_json_dict
from dgcal.calib.mounting.methods import canonical_method
from dgcal.fields.crs import R_ecef_to_ned_at, geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.formats import read_eop, read_points, read_trajectory
from dgcal.pos.ins.interpolate import interpolate_trajectory
from dgcal.reports.boresight import CAPTION as BORESIGHT_CAPTION
from dgcal.reports.boresight import boresight_angles_deg, matrix_text
from dgcal.reports.distortion import CAPTION as DISTORTION_CAPTION
from dgcal.reports.distortion import distortion_figure
from dgcal.reports.glossary import METHOD_NOTE, label, method_name
from dgcal.reports.honesty import add_honesty, honesty_rows, honesty_section, merge_sections, no_reference
from dgcal.reports.html import HtmlReport, new_figure
from dgcal.reports.mounting import (IMPROVEMENT_NOTE, LEVER_NOTE, MOUNT_HEADER, mount_row, add_boresight_matrices,
                                    improvement_pct)
from dgcal.reports.tables import add_residual_table, parameter_rows, parameter_unit
from dgcal.reports.units import pm, value_sigma

METHOD_ORDER = ("joint", "iso", "two-step")  # canonical names (dgcal.calib.mounting.methods)


def _load(path: Path | None) -> dict | None:
    if path is None:
        return None
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _rpy_deg(R) -> list[float]:
    """Roll, pitch, yaw (deg) of a boresight R_cam_to_body = Rz(yaw) Ry(pitch) Rx(roll)."""
    return [float(v) for v in Rotation.from_matrix(np.asarray(R, float)).as_euler("ZYX", degrees=True)[::-1]]


def collect(cfg: dict, out: Path, files: dict, steps: dict | None = None, timings: dict | None = None) -> dict:
    """Every number of the campaign's outputs in one dictionary (the content of report.json), read from the
    step files `files` (see `write_campaign_report`)."""
    out = Path(out)
    d: dict = {"campaign": str(cfg.get("_path", "")), "name": cfg.get("name", ""), "crs": cfg.get("crs"),
               "generated_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
               "steps": steps or {}, "timings_s": timings or {}, "warnings": []}
    cam = _load(files["camera"].get("camera"))
    if cam is not None:
        d["camera"] = {k: cam.get(k) for k in ("model", "image_size", "parameters", "sigmas", "rms_px",
                                               "n_observations", "n_rejected", "n_images", "sigma0", "opencv",
                                               "opencv_max_error_px", "fixed_parameters")}
        d["warnings"] += [f"camera: {w}" for w in cam.get("warnings", [])]
    tri = _load(files["triangulation"].get("summary"))
    if tri is not None:
        d["triangulation"] = tri
        d["warnings"] += [f"triangulation: {w}" for w in tri.get("warnings", [])]
    pos = _load(files["pos"].get("summary"))
    if pos is not None:
        d["pos"] = pos
    mounts = {}
    for name, mfiles in files["mounts"].items():
        m = _load(mfiles.get("mounting"))
        if m is None:
            continue
        m = {k: v for k, v in m.items() if k != "per_epoch"}
        m["boresight_rpy_deg"] = _rpy_deg(m["boresight_R_cam_to_body"])
        mounts[name] = m
        d["warnings"] += [f"mount {name}: {w}" for w in m.get("warnings", [])]
    if mounts:
        rank = {k: METHOD_ORDER.index(_canonical(k, m)) if _canonical(k, m) in METHOD_ORDER else len(METHOD_ORDER)
                for k, m in mounts.items()}
        order = sorted(mounts, key=rank.get)
        d["mounting"] = {k: mounts[k] for k in order}
        chosen = next(iter(files["mounts"]))  # the campaign's method; the others are compared with it
        d["mounting_method"] = chosen if chosen in mounts else order[0]
    chk = _load(files["check"].get("check"))
    if chk is not None:
        d["check"] = chk
        for k, c in chk.get("checks", {}).items():
            d["warnings"] += [f"check {k}: {w}" for w in c.get("warnings", [])]
            d["warnings"] += [f"check {k} (ASPRS): {w}" for w in c.get("asprs_2023", {}).get("warnings", [])]
    truth_path = cfg.get("truth")
    truth_sec = None
    if truth_path:
        tp = Path(truth_path)
        tp = tp if tp.is_absolute() else cfg["_base"] / tp
        truth = _load(tp)
        if truth is not None:
            d["truth_comparison"] = compare_with_truth(d, truth)
            truth_sec = truth_honesty(d, truth, tp.parent, files)
    steps_sec = [(name, (d.get(key) or {}).get("honesty")) for name, key in
                 (("triangulation", "triangulation"), ("pos", "pos"), ("check", "check"))]
    d["honesty"] = merge_sections([s for _, s in steps_sec] + [truth_sec],
                                  [name for name, _ in steps_sec] + ["truth"])
    if not d["honesty"]["rows"] and not d["honesty"]["notes"]:
        d["honesty"] = no_reference("No reference: no step of this campaign has check points or withheld fixes, "
                                    "and there is no simulation truth.")
    return d


def truth_honesty(d: dict, truth: dict, base: Path, files: dict) -> dict:
    """The honesty rows against a simulation's truth (`truth`: truth.json, its files relative to `base`): the
    mounting of every method (delay, lever arm, boresight; the three components of a vector pooled), the camera
    parameters (pooled: their errors in their own units, so no RMS error), the POS trajectory (N/E/D position,
    roll/pitch/heading) and the triangulation's EOPs (X/Y/Z, omega/phi/kappa)."""
    rows = []
    tc = d.get("truth_comparison", {})
    for k, e in tc.get("mounting", {}).items():
        m = d["mounting"][k]
        ref = f"mounting {method_name(k)}"
        rows += honesty_rows([1e3 * e["delay_error_s"]], [1e3 * m.get("delay_sigma_s", np.nan)], ["delay"], ref, "ms")
        rows += honesty_rows(np.asarray(e["lever_arm_error_m"], float),
                             np.asarray(m.get("lever_arm_sigma_m", [np.nan] * 3), float), ["lever arm x/y/z"], ref)
        rows += honesty_rows(np.asarray(e["boresight_error_deg"], float),
                             np.asarray(m.get("boresight_sigma_deg", [np.nan] * 3), float), ["boresight x/y/z"], ref,
                             "deg")
    cam_err = tc.get("camera") or {}
    sig = (d.get("camera") or {}).get("sigmas") or {}
    names = [k for k in cam_err if sig.get(k)]
    if names:
        row = honesty_rows(np.array([cam_err[k]["error"] for k in names]), np.array([sig[k] for k in names]),
                           ["camera parameters"], "camera", "")
        rows += [{**r, "rms_error": None, "median_sigma": None} for r in row]   # mixed units: ratios only
    notes = ["Simulation truth: estimate − truth over the sigma the estimate reports (mounting and camera: one value "
             "per parameter, a vector's components pooled; camera parameters pooled, their error/sigma only)."]
    for what, compare, key, est in (("trajectory", _trajectory_rows, "trajectory", files["pos"].get("trajectory")),
                                    ("EOPs", _eop_rows, "eop", files["triangulation"].get("eop"))):
        try:
            more, note = compare(_truth_file(truth, base, key), est)
        except (InputError, OSError, ValueError) as exc:   # the table must not cost the report
            more, note = [], f"The true {what} could not be compared: {exc}"
        rows, notes = rows + more, notes + [note]
    return honesty_section(rows, notes)


def _truth_file(truth: dict, base: Path, key: str) -> Path | None:
    """A file of the simulation's truth (truth.json `files`: 'path (what it is)'), None when not given."""
    text = (truth.get("files") or {}).get(key)
    if not text:
        return None
    p = Path(str(text).split(" (")[0].strip())
    return p if p.is_absolute() else base / p


TRUTH_SAMPLES = 2000   # the true trajectory is compared at about this many samples at most (evenly spread)


def _trajectory_rows(truth_p: Path | None, traj_p: Path | None) -> tuple[list, str]:
    """The POS trajectory against the true one at the truth's samples inside its span (TRUTH_SAMPLES at most, evenly
    spread): IMU position N/E/D (m, local frame of each true sample) and roll/pitch/heading (deg) over the
    trajectory's sigmas."""
    if truth_p is None or traj_p is None or not Path(truth_p).is_file() or not Path(traj_p).is_file():
        return [], ""
    tr, true = read_trajectory(traj_p), read_trajectory(truth_p)
    if tr.sigma is None:
        return [], "The POS trajectory has no sigmas: not compared with the true trajectory."
    m = (true.t >= tr.t[0]) & (true.t <= tr.t[-1])
    if not m.any():
        return [], ""
    m = np.flatnonzero(m)
    m = m[::max(1, len(m) // TRUTH_SAMPLES)]
    st = interpolate_trajectory(tr, true.t[m])
    p_true = geodetic_to_ecef(true.lat[m], true.lon[m], true.h[m])
    d_ned = np.einsum("nij,nj->ni", R_ecef_to_ned_at(p_true).reshape(-1, 3, 3), st.p_ecef - p_true)
    d_rph = (st.rph - true.rph[m] + 180.0) % 360.0 - 180.0
    ref = "POS trajectory"
    rows = (honesty_rows(d_ned, st.sigma[:, :3], ("N", "E", "D"), ref)
            + honesty_rows(d_rph, st.sigma[:, 3:], ("roll", "pitch", "heading"), ref, "deg"))
    return rows, ("True IMU trajectory: the POS trajectory interpolated at its samples, position N/E/D and roll/pitch/"
                  "heading over the trajectory's sigmas; errors of consecutive samples are correlated in time, so n "
                  "overstates the number of independent values.")


def _eop_rows(truth_p: Path | None, eop_p: Path | None) -> tuple[list, str]:
    """The triangulation's EOPs against the true ones, image by image: X/Y/Z (m, map CRS) and omega/phi/kappa (deg)
    over the EOPs' sigmas."""
    if truth_p is None or eop_p is None or not Path(truth_p).is_file() or not Path(eop_p).is_file():
        return [], ""
    est, true = read_eop(eop_p), read_eop(truth_p)
    if est.sigma is None:
        return [], "The triangulation's EOPs have no sigmas: not compared with the true EOPs."
    row = {str(k): i for i, k in enumerate(true.image)}
    i_est = np.array([i for i, k in enumerate(est.image) if str(k) in row], int)
    i_true = np.array([row[str(est.image[i])] for i in i_est], int)
    if not len(i_est):
        return [], ""
    dx = est.xyz[i_est] - true.xyz[i_true]
    da = (est.opk[i_est] - true.opk[i_true] + 180.0) % 360.0 - 180.0
    ref = "triangulation EOPs"
    rows = (honesty_rows(dx, est.sigma[i_est, :3], ("X", "Y", "Z"), ref)
            + honesty_rows(da, est.sigma[i_est, 3:], ("omega", "phi", "kappa"), ref, "deg"))
    return rows, ("True EOPs: the triangulation's projection centres (map CRS) and omega/phi/kappa over their sigmas, "
                  "image by image.")


def compare_with_truth(d: dict, truth: dict) -> dict:
    """Errors of the estimated mounting (and camera) against a simulation's truth, with error/sigma ratios."""
    out = {"mounting": {}}
    R_true = np.asarray(truth["boresight_R_cam_to_body"], float)
    for k, m in d.get("mounting", {}).items():
        cov = np.asarray(m.get("covariance", np.zeros((7, 7))), float)
        s = np.sqrt(np.clip(np.diag(cov), 0, None))
        dl = np.asarray(m["lever_arm_m"]) - np.asarray(truth["lever_arm_m"])
        # boresight error as the small rotation Exp(theta) = R_est R_true^T (body axes), like the covariance
        th = Rotation.from_matrix(np.asarray(m["boresight_R_cam_to_body"]) @ R_true.T).as_rotvec()
        ddt = float(m["delay_s"]) - float(truth["delay_s"])
        with np.errstate(divide="ignore", invalid="ignore"):
            out["mounting"][k] = {
                "delay_error_s": ddt, "delay_error_over_sigma": float(ddt / s[0]) if s[0] > 0 else None,
                "lever_arm_error_m": dl.tolist(),
                "lever_arm_error_over_sigma": [float(v) if np.isfinite(v) else None for v in dl / s[1:4]],
                "boresight_error_deg": np.degrees(th).tolist(),
                "boresight_error_over_sigma": [float(v) if np.isfinite(v) else None for v in th / s[4:7]],
            }
    cam, tcam = d.get("camera"), truth.get("camera")
    if cam and tcam and cam.get("model") == tcam.get("model"):
        p, tp_ = cam.get("parameters", {}), tcam.get("parameters", {})
        sg = cam.get("sigmas", {}) or {}
        out["camera"] = {k: {"error": float(p[k]) - float(tp_[k]),
                             "error_over_sigma": (float(p[k]) - float(tp_[k])) / sg[k] if sg.get(k) else None}
                         for k in p if k in tp_}
    out["truth"] = {k: truth.get(k) for k in ("lever_arm_m", "delay_s", "boresight_R_cam_to_body",
                                              "boresight_deg_about_nominal", "seed")}
    return out


# ----------------------------------------------------------------------------------------------- figures
def _fig_distortion(cam: dict):
    """The camera's distortion curve, as the camera report draws it (radial part positive outward)."""
    return distortion_figure(camera_from_json_dict(cam))


def _canonical(name: str, m: dict) -> str:
    """The registry name of a mounting record's method (`method_canonical`, else from its name)."""
    return m.get("method_canonical") or canonical_method(m.get("method", name))


def _fig_block(eop_p: Path | None, cfg: dict):
    if eop_p is None or not eop_p.is_file():
        return None
    eop = read_eop(eop_p)
    fig, ax = new_figure(7.0, 6.0)
    sc = ax.scatter(eop.xyz[:, 0], eop.xyz[:, 1], c=eop.xyz[:, 2], s=12, cmap="viridis", label="images")
    fig.colorbar(sc, ax=ax, label="projection-centre height (m)")
    gcp = cfg.get("triangulation", {}).get("gcp")
    if gcp:
        gp = Path(gcp) if Path(gcp).is_absolute() else cfg["_base"] / gcp
        try:
            pts = read_points(gp)
            for role, mk, col in (("control", "^", "red"), ("check", "o", "blue")):
                sel = pts.role == role
                if sel.any():
                    ax.scatter(pts.xyz[sel, 0], pts.xyz[sel, 1], marker=mk, s=40, facecolors="none",
                               edgecolors=col, label=f"{role} points")
        except Exception:  # noqa: BLE001 - the figure is optional; the table reports the numbers
            pass
    ax.set_aspect("equal")
    ax.set_xlabel("grid E (m)")
    ax.set_ylabel("grid N (m)")
    ax.legend(fontsize=8, loc="best")
    ax.ticklabel_format(useOffset=False, style="plain")
    return fig


def _fig_pos_sigma(p: Path | None):
    if p is None or not p.is_file():
        return None
    tr = read_trajectory(p)
    if tr.sigma is None:
        return None
    t = tr.t - tr.t[0]
    fig, (a1, a2) = new_figure(8.0, 5.0, nrows=2, sharex=True)
    for j, lab in enumerate(("north", "east", "height")):
        a1.plot(t, tr.sigma[:, j] * 100, lw=0.8, label=lab)
    for j, lab in enumerate(("roll", "pitch", "heading")):
        a2.plot(t, tr.sigma[:, 3 + j], lw=0.8, label=lab)
    a1.set_ylabel("position sigma (cm)")
    a2.set_ylabel("attitude sigma (deg)")
    a2.set_xlabel("time since start (s)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
        a.legend(fontsize=8, ncol=3)
    return fig


def _fig_correlation(m: dict):
    C = np.array([[np.nan if v is None else v for v in row] for row in m["correlation"]], float)
    names = ["dt", "lx", "ly", "lz", "bx", "by", "bz"]
    fig, ax = new_figure(4.6, 4.0)
    im = ax.imshow(C, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(7), names)
    ax.set_yticks(range(7), names)
    for i in range(7):
        for j in range(7):
            if np.isfinite(C[i, j]):
                ax.text(j, i, f"{C[i, j]:.2f}", ha="center", va="center", fontsize=6,
                        color="white" if abs(C[i, j]) > 0.6 else "black")
    fig.colorbar(im, ax=ax, shrink=0.8)
    return fig


def _fig_per_epoch(mount_files: dict):
    two_step = [f.get("mounting") for k, f in mount_files.items() if canonical_method(k) == "two-step"]
    m = _load(two_step[0]) if two_step else None
    pe = (m or {}).get("per_epoch") or {}
    lev = pe.get("lever_arm_m")
    if not lev:
        return None
    lev = np.asarray(lev, float)
    fig, ax = new_figure(8.0, 3.4)
    for j, lab in enumerate(("x (forward)", "y (right)", "z (down)")):
        ax.plot(lev[:, j], ".", ms=4, label=lab)
    ax.set_xlabel("epoch (image)")
    ax.set_ylabel("per-epoch lever arm (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=3)
    return fig


def _fig_check(chk: dict):
    checks = chk.get("checks", {})
    if not checks:
        return None
    fig, axes = new_figure(8.0, 3.2 * len(checks), nrows=len(checks), squeeze=False, sharex=True)
    for ax, (k, c) in zip(axes[:, 0], checks.items()):
        pts = c.get("points", [])
        ids = [p["id"] for p in pts]
        e = np.array([p["err_enu"] for p in pts], float).reshape(-1, 3)
        s = np.array([p["sigma_pred_enu"] for p in pts], float).reshape(-1, 3)
        x = np.arange(len(ids))
        for j, (lab, off) in enumerate((("E", -0.25), ("N", 0.0), ("U", 0.25))):
            ax.bar(x + off, e[:, j], width=0.25, label=lab)
            ax.errorbar(x + off, np.zeros(len(x)), yerr=s[:, j], fmt="none", ecolor="k", lw=0.6, capsize=1.5)
        ax.set_title(f"{method_name(k)}: DG errors on check points (bars) and predicted 1-sigma (whiskers)",
                     fontsize=9)
        ax.set_ylabel("error (m)")
        ax.grid(alpha=0.3, axis="y")
        ax.set_xticks(x, ids, rotation=90, fontsize=7)
        ax.legend(fontsize=8, ncol=3)
    return fig


# ----------------------------------------------------------------------------------------------- page
def _link(rep: HtmlReport, out: Path, path: Path | None, text: str) -> None:
    if path is not None and Path(path).is_file():
        try:
            rel = Path(path).resolve().relative_to(Path(out).resolve()).as_posix()
        except ValueError:
            rel = Path(path).resolve().as_uri()
        rep.raw(f'<p class="small">Detailed report: <a href="{rel}">{rel}</a> ({text})</p>')


def _mount_rows(mounts: dict) -> list:
    """Every method's estimates with sigmas (the mounting report's rows) and its rejected epochs."""
    return [mount_row(k, m) + [len(m.get("rejected_epochs", []))] for k, m in mounts.items()]


def build_html(d: dict, out: Path, cfg: dict, files: dict) -> str:
    """The report page (one self-contained HTML string)."""
    rep = HtmlReport(f"Calibration report{(' — ' + d['name']) if d.get('name') else ''}")
    rep.raw('<p class="nav small"><a href="#summary">Summary</a><a href="#camera">Camera</a>'
            '<a href="#triangulation">Triangulation</a><a href="#pos">POS</a><a href="#mounting">Mounting</a>'
            '<a href="#dg">DG accuracy</a><a href="#honesty">Honesty</a><a href="#warnings">Warnings</a></p>')
    rep.kv_table([("campaign file", d["campaign"]), ("map CRS", d.get("crs")), ("generated (UTC)", d["generated_utc"])])
    _summary_section(rep, d)
    _camera_section(rep, d, out, files)
    _triangulation_section(rep, d, out, cfg, files)
    _pos_section(rep, d, out, files)
    _mounting_section(rep, d, out, files)
    _dg_section(rep, d, out, files)
    rep.raw('<h2 id="honesty">Honesty: errors against their sigmas</h2>')
    add_honesty(rep, d.get("honesty"), heading=None)
    rep.raw('<h2 id="warnings">Warnings</h2>')
    rep.warnings(d.get("warnings", []))
    return rep.render()


def _summary_section(rep: HtmlReport, d: dict) -> None:
    """The summary: the chosen mounting, DG accuracy per method, steps, errors against a simulation's truth."""
    rep.raw('<h2 id="summary">Summary</h2>')
    mounts = d.get("mounting", {})
    chosen = d.get("mounting_method")
    if chosen:
        m = mounts[chosen]
        theta, _ = boresight_angles_deg(m["boresight_R_cam_to_body"])
        held = m.get("delay_sigma_s", 0.0) == 0.0
        rep.headline([
            ("exposure delay (ms)", "not estimated (0)" if held else pm(1e3 * m["delay_s"],
                                                                        1e3 * m["delay_sigma_s"], "ms")),
            ("lever arm IMU → camera x, y, z, body axes (m)",
             ", ".join(pm(v, s_, "m") for v, s_ in zip(m["lever_arm_m"], m["lever_arm_sigma_m"]))),
            ("boresight θx, θy, θz about body axes (°)",
             ", ".join(pm(v, s_, "°") for v, s_ in zip(theta, m["boresight_sigma_deg"]))),
            ("boresight R_cam_to_body (rows, unitless)", matrix_text(m["boresight_R_cam_to_body"]))],
            f"System calibration by the {method_name(chosen)} method, with 1-sigma: the values to use for direct "
            "georeferencing.")
        rep.text(BORESIGHT_CAPTION, cls="small")
    chk = d.get("check", {}).get("checks", {})
    if chk:
        rep.table(["method", "check points", "RMS E (m)", "RMS N (m)", "RMS U (m)", "RMS 2D (m)", "RMS 3D (m)",
                   "predicted 3D (m)", "achieved / predicted 3D (ratio)"],
                  [[method_name(k), c["stats"]["n"], *(_m(c["stats"]["rms"][a]) for a in ("E", "N", "U", "2D", "3D")),
                    _m(c["budget"]["predicted_rms"]["3D"]), _m(c["budget"]["ratio_achieved_to_predicted"]["3D"], 2)]
                   for k, c in chk.items()])
    if d.get("steps"):
        rep.table(["step", "status", "time (s)"],
                  [[_step_name(k), v, _m(d["timings_s"].get(k), 1)] for k, v in d["steps"].items()])
    tc = d.get("truth_comparison")
    if tc:
        rep.heading("Against the simulation truth")
        rows = []
        for k, e in tc["mounting"].items():
            rows.append([method_name(k), f"{e['delay_error_s'] * 1e3:+.2f} ({_ratio(e['delay_error_over_sigma'])})",
                         *(f"{v * 100:+.2f} ({_ratio(r)})" for v, r in zip(e["lever_arm_error_m"],
                                                                        e["lever_arm_error_over_sigma"])),
                         *(f"{v:+.4f} ({_ratio(r)})" for v, r in zip(e["boresight_error_deg"],
                                                                  e["boresight_error_over_sigma"]))])
        rep.table(["method", "delay (ms)", "lever arm x (cm)", "lever arm y (cm)", "lever arm z (cm)",
                   "boresight θx (°)", "boresight θy (°)", "boresight θz (°)"], rows)
        rep.text("Errors are estimate − truth; in brackets the error in units of the reported sigma.", cls="small")


def _camera_section(rep: HtmlReport, d: dict, out: Path, files: dict) -> None:
    """The camera calibration: model, fit, parameters (against the truth when simulated), distortion."""
    rep.raw('<h2 id="camera">Camera</h2>')
    cam = d.get("camera")
    if cam:
        rep.kv_table([("model", cam["model"]), ("image size (px)", " × ".join(map(str, cam["image_size"]))),
                      ("RMS residual (px)", cam.get("rms_px")), ("observations", cam.get("n_observations")),
                      ("observations rejected", cam.get("n_rejected")), ("images", cam.get("n_images")),
                      ("sigma0", cam.get("sigma0"))])
        sig = cam.get("sigmas") or {}
        truth_cam = (d.get("truth_comparison") or {}).get("camera", {})
        params = cam.get("parameters") or {}
        rows = parameter_rows(list(params), list(params.values()), [sig.get(k) for k in params])
        hdr = ["parameter", "unit", "value (unit column)", "σ (unit column)"]
        if truth_cam:
            hdr += ["error vs truth (unit column)", "error / σ"]
            for r, k in zip(rows, params):
                e = truth_cam.get(k, {})
                r += [value_sigma(e.get("error", float("nan")), sig.get(k), parameter_unit(k), signed=True)[0],
                      _ratio(e.get("error_over_sigma"))]
        rep.table(hdr, rows)
        try:
            rep.figure(_fig_distortion(cam), DISTORTION_CAPTION)
        except Exception as exc:  # noqa: BLE001 - a missing figure must not lose the report
            rep.text(f"(distortion plot unavailable: {exc})", cls="small")
        _link(rep, out, files["camera"].get("report"), "residuals, correlations, coverage")
    else:
        rep.text("No camera step in this campaign.")


def _triangulation_section(rep: HtmlReport, d: dict, out: Path, cfg: dict, files: dict) -> None:
    """The aerial triangulation: fit statistics, check/control RMSE, the block plot."""
    rep.raw('<h2 id="triangulation">Aerial triangulation</h2>')
    tri = d.get("triangulation")
    if tri:
        pairs = [(k, tri[k]) for k in ("n_images", "n_oriented", "sigma0", "n_observations", "n_points", "n_control",
                                       "n_check", "n_rejected") if k in tri and not isinstance(tri[k], (dict, list))]
        datum = tri.get("datum")
        rep.kv_table(pairs + [("datum", datum.get("text") if isinstance(datum, dict) else datum)])
        for key, what in (("check_rmse_m", "check-point RMSE"), ("control_rmse_m", "control-point RMSE")):
            r = tri.get(key)
            if isinstance(r, dict):
                rep.kv_table([(f"{what} E, N, U (m)", ", ".join(_m(r.get(a)) for a in "ENU")),
                              (f"{what} horizontal (m)", _m(r["horizontal"]) if "horizontal" in r else None),
                              (f"{what}: points", r.get("n"))])
        rep.figure(partial(_fig_block, files["triangulation"].get("eop"), cfg),
                   "Projection centres (colour: height) and ground points of the calibration flight.")
        _link(rep, out, files["triangulation"].get("report"), "residuals, EOP sigmas, footprints")
    else:
        rep.text("No triangulation step in this campaign.")


def _pos_section(rep: HtmlReport, d: dict, out: Path, files: dict) -> None:
    """The GNSS/INS smoothing: summary, residuals, the sigma plot."""
    rep.raw('<h2 id="pos">POS (GNSS/INS smoothing)</h2>')
    pos = d.get("pos")
    if pos:
        rep.kv_table([(k, v) for k, v in pos.items() if not isinstance(v, dict) and k not in POS_SKIPPED])
        add_residual_table(rep, pos.get("residuals") or {})
        rep.figure(partial(_fig_pos_sigma, files["pos"].get("trajectory")),
                   "Smoothed trajectory: 1-sigma of position and attitude over the flight.")
        _link(rep, out, files["pos"].get("report"), "smoother details")
    else:
        rep.text("No POS step in this campaign (an external trajectory was used).")


def _mounting_section(rep: HtmlReport, d: dict, out: Path, files: dict) -> None:
    """The mounting of every method: table, correlations of the chosen one, per-epoch plot."""
    rep.raw('<h2 id="mounting">Mounting: lever arm, boresight, exposure delay</h2>')
    mounts = d.get("mounting", {})
    chosen = d.get("mounting_method")
    if mounts:
        rep.table(MOUNT_HEADER + ["rejected epochs"], _mount_rows(mounts))
        rep.text(LEVER_NOTE + " " + METHOD_NOTE, cls="small")
        m = mounts[chosen]
        add_boresight_matrices(rep, m["boresight_R_cam_to_body"])
        rep.figure(partial(_fig_correlation, m),
                   f"Correlations of the {method_name(chosen)} estimate (delay, lever arm, boresight).")
        rep.figure(partial(_fig_per_epoch, files["mounts"]),
                   "Per-epoch lever arms of the two-step method (seed 003 Fig. 22): a non-zero delay shows as a shift "
                   "that depends on the speed and heading.")
        for k in mounts:
            _link(rep, out, files["mounts"].get(k, {}).get("report"), f"{method_name(k)}: per-epoch plots, residuals")
    else:
        rep.text("No mounting step in this campaign.")


def _dg_section(rep: HtmlReport, d: dict, out: Path, files: dict) -> None:
    """DG accuracy on check points per method: statistics, predicted budget, ASPRS 2023, improvement rates."""
    rep.raw('<h2 id="dg">Direct georeferencing accuracy on check points</h2>')
    chk = d.get("check", {}).get("checks", {})
    if chk:
        for k, c in chk.items():
            rep.heading(method_name(k), 3)
            st = c["stats"]
            rep.table(["statistic", "E (m)", "N (m)", "U (m)", "2D (m)", "3D (m)"],
                      [[s.upper(), *(_m(st[s][a]) for a in ("E", "N", "U", "2D", "3D"))]
                       for s in ("avg", "std", "rms")])
            b = c["budget"]
            rep.table(["predicted RMS from", "E (m)", "N (m)", "U (m)", "2D (m)", "3D (m)"],
                      [[label(src), *(_m(v[a]) for a in ("E", "N", "U", "2D", "3D"))]
                       for src, v in b["sources"].items()]
                      + [["all sources", *(_m(b["predicted_rms"][a]) for a in ("E", "N", "U", "2D", "3D"))],
                         ["achieved", *(_m(b["achieved_rms"][a]) for a in ("E", "N", "U", "2D", "3D"))]])
            a = c.get("asprs_2023", {})
            rep.kv_table([(asprs_label(key), v) for key, v in a.items() if not isinstance(v, list)])
        imp = {k: v for k, v in d["check"].items() if k.startswith("improvement_over_") and v}
        for k in imp:
            ref = k[len("improvement_over_"):]
            rows = improvement_pct(chk, ref)
            rep.heading(f"Improvement over the {method_name(ref)} method", 3)
            rep.table(["method", "2D improvement (%)", "3D improvement (%)"],
                      [[method_name(m_), r["2D"], r["3D"]] for m_, r in rows.items()])
            rep.text(IMPROVEMENT_NOTE, cls="small")
        rep.figure(partial(_fig_check, d["check"]), "Check-point errors of direct georeferencing per method.")
        _link(rep, out, files["check"].get("report"), "per-point table")
    else:
        rep.text("No DG check in this campaign.")


def _m(v, nd: int = 3) -> str:
    """A number with `nd` decimals (metres to the mm), '–' for missing values."""
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if not np.isfinite(v) else f"{v:.{nd}f}"


def _ratio(v) -> str:
    return "–" if v is None else f"{v:+.1f}σ"


def _step_name(step: str) -> str:
    """A campaign step as words: 'mount_proposed' → 'mount (joint)'."""
    if step.startswith("mount_"):
        return f"mount ({method_name(step[len('mount_'):])})"
    return {"pos": "POS", "triangulate": "triangulation", "check": "DG check"}.get(step, step.replace("_", " "))


def asprs_label(key: str) -> str:
    """Words for a key of the ASPRS 2023 record ('RMSE_H' → 'ASPRS 2023 RMSE horizontal (m)')."""
    if key == "n_checkpoints":
        return "ASPRS 2023 check points"
    words = str(key).replace("RMSE_H", "RMSE horizontal").replace("RMSE_V", "RMSE vertical").replace("_", " ")
    return f"ASPRS 2023 {words} (m)"


POS_SKIPPED = ("warnings", "honesty", "integrity")   # shown elsewhere (warnings, honesty table) or too long


def write_campaign_report(cfg: dict, out: Path, files: dict, steps: dict | None = None,
                          timings: dict | None = None, into: Path | None = None) -> dict:
    """Write DIR/report.json and DIR/report.html for the campaign outputs in `out`; returns their paths.

    `files` are the step files the verbs declare (dgcal.campaign.report_files): "camera", "triangulation",
    "pos", "check" (role -> path) and "mounts" (method as the campaign names it -> role -> path; the first
    is the campaign's method). `into`: write the two files there instead (a staging folder that becomes
    `out`; the links of the page stay relative to `out`).
    """
    out = Path(out)
    dest = out if into is None else Path(into)
    d = collect(cfg, out, files, steps, timings)
    page = build_html(d, out, cfg, files)
    with atomic_write(dest / "report.json") as fh:
        json.dump(d, fh, indent=1, default=_json_default)
    with atomic_write(dest / "report.html", encoding="utf-8") as fh:
        fh.write(page)
    return {"html": dest / "report.html", "json": dest / "report.json"}


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
