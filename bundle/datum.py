"""The datum of an aerial triangulation: what fixes its position, scale and rotation, and how well.

A block of images measured among themselves is known up to a 3-D similarity (7 parameters); the datum
sources fix them: GNSS camera-centre priors (RTK/PPK centres, `--gnss`) and control points with their
coordinates. `datum_statement` says from the sources' geometry alone which of position, scale and rotation
are fixed (a line of sources leaves the rotation about that line free). `weak_datum` reads the adjustment's
pose covariances: a datum that is fixed in principle but weakly (control within a metre of a strip's
centreline) shows as a block rotation whose sigma, times the camera-to-ground distance, moves the ground by
several times the sources' own sigmas. `focal_height_correlation` reads the correlation of a refined focal
length with the block's height above the ground (mean camera Z minus mean point Z): nadir images from one
height cannot separate them, so with free f the error goes into the heights. `principal_point_correlation` does
the same for a refined principal point: a shift of d px is a tilt of d/f or a horizontal shift of H d/f of the
centres (or, with 0 GCPs, of the ground), which nadir images of flat ground cannot tell apart; its figure is the
multiple correlation of cx/cy with those block-level combinations (`pp_combinations`).

Frames: world (a local Cartesian ENU frame of the problem, m); pose covariances [C (m), dtheta (rad, camera
axes)] as `dgcal.fields.pose`.
"""
from __future__ import annotations

import numpy as np

from dgcal.bundle.adjustment import BundleResult

COLLINEAR_SIGMAS = 5.0     # datum sources within this many of their sigmas (RMS) of a line leave the rotation about it
                           # free (farther, the rotation is fixed, perhaps weakly: `weak_datum` says how well)
WEAK_FACTOR = 5.0          # a datum effect beyond this many source sigmas is weak
F_HEIGHT_CORRELATION = 0.9  # |rho(f, height above ground)| above this is reported
PP_CORRELATION = 0.9        # rho(cx or cy, the block-level combinations of `pp_combinations`) above this is reported
PP_COMBINATIONS = ("centres", "ground_E", "ground_N", "tilt")   # the block-level combinations of `pp_combinations`
PP_PARTS = {"rho_centres": "the centres' shift along the image axes", "rho_ground": "the ground's horizontal position",
            "rho_tilt": "the mean tilt (omega/phi)"}


def _sigma_text(s: np.ndarray) -> str:
    """'2/2/5 cm' from (3,) sigmas in m ('1.2/0.05/3 m' when one exceeds a metre)."""
    s = np.asarray(s, float)
    if np.nanmax(s) >= 1.0:
        return "/".join(f"{v:.2g}" for v in s) + " m"
    return "/".join(f"{v * 100:.2g}" if v < 0.1 else f"{v * 100:.0f}" for v in s) + " cm"


def _azimuth_deg(axis: np.ndarray) -> float:
    """Azimuth (deg, 0-180: an axis has no sense) of a world vector's horizontal part."""
    az = float(np.degrees(np.arctan2(axis[0], axis[1])) % 180)
    return 0.0 if az >= 179.5 else az


def datum_statement(centres_world: np.ndarray, centre_sigma_m: np.ndarray, control_world: np.ndarray,
                    control_sigma_m: np.ndarray) -> dict:
    """What fixes position, scale and rotation: camera centres (k,3) and control points (g,3) in the world frame
    (m) with sigmas (k,3)/(g,3) (m). Sources within COLLINEAR_SIGMAS of their sigmas of a line leave the rotation
    about it free (within that of a point: the scale). Returns a JSON-able dict with `text` (one line)."""
    C = np.asarray(centres_world, float).reshape(-1, 3)
    G = np.asarray(control_world, float).reshape(-1, 3)
    P = np.vstack([C, G])
    n_c, n_g = len(C), len(G)
    c_sig = np.median(np.asarray(centre_sigma_m, float).reshape(-1, 3), axis=0) if n_c else None
    g_sig = np.median(np.asarray(control_sigma_m, float).reshape(-1, 3), axis=0) if n_g else None
    limit = COLLINEAR_SIGMAS * max(min(float(np.sqrt(np.mean(s ** 2))) for s in (c_sig, g_sig) if s is not None)
                                   if len(P) else 0.0, 1e-3)
    fixes, free = [], []
    line = None
    if len(P):
        fixes.append("position")
        d = P - P.mean(0)
        if np.max(np.linalg.norm(d, axis=1)) > limit:
            fixes.append("scale")
        _, s, Vt = np.linalg.svd(d, full_matrices=False)
        lateral = float(s[1] / np.sqrt(len(P))) if len(s) > 1 else 0.0
        if lateral > limit:
            fixes.append("rotation")
        elif "scale" in fixes:
            ax = Vt[0]
            line = {"azimuth_deg": _azimuth_deg(ax), "lateral_rms_m": lateral}
            free.append(f"rotation about the line of the datum sources (azimuth {line['azimuth_deg']:.0f} deg; "
                        f"they lie within {lateral:.2g} m RMS of it)")
        else:
            free.append("rotation")
    if "scale" not in fixes:
        free.insert(0, "scale")
    if not fixes:
        free.insert(0, "position")
    sources = []
    if n_c:
        sources.append(f"{n_c} camera centre{'s' if n_c > 1 else ''} (σ {_sigma_text(c_sig)})")
    if n_g:
        sources.append(f"{n_g} GCP{'s' if n_g > 1 else ''} (σ {_sigma_text(g_sig)})")
    verb = "fixes" if len(sources) == 1 and (n_c + n_g) == 1 else "fix"
    text = (" and ".join(sources) + f" {verb} " + ", ".join(fixes)) if fixes else "nothing fixes the datum"
    if free:
        text += "; not fixed: " + ", ".join(free)
    if not n_g:
        text += "; 0 GCPs"
    elif not n_c:
        text += "; no camera centres"
    return {"text": text, "n_centres": n_c, "centre_sigma_m": None if c_sig is None else c_sig.tolist(),
            "n_control": n_g, "control_sigma_m": None if g_sig is None else g_sig.tolist(),
            "fixed": fixes, "not_fixed": free, "line": line}


def reference_sigma_m(centre_sigma_m: np.ndarray | None, control_sigma_m: np.ndarray | None, gsd_m: float) -> float:
    """The datum sources' typical sigma (m): the best of the median centre and control sigmas (RMS over the
    axes), never below a ground sample distance (held control has no sigma to compare with)."""
    vals = [float(np.sqrt(np.mean(np.median(np.asarray(s, float).reshape(-1, 3), axis=0) ** 2)))
            for s in (centre_sigma_m, control_sigma_m) if s is not None and len(np.asarray(s).reshape(-1, 3))]
    return max(min(vals) if vals else 0.0, gsd_m)


def weak_datum(res: BundleResult, ref_sigma_m: float) -> tuple[dict, list[str]]:
    """The block's datum precision from the pose covariances: the median (over images) rotation covariance in
    world axes, its worst axis and sigma (rad), that sigma times the median camera-to-point distance (m, the
    shift it makes at the ground), the median position sigmas (m); warnings when either exceeds `WEAK_FACTOR`
    times `ref_sigma_m`."""
    cov = res.cov_pose
    ok = np.isfinite(cov).all(axis=(1, 2))
    if not ok.any():
        return {"rotation_sigma_deg": None}, ["the datum cannot be judged: no image has a finite covariance"]
    R_cam_to_world = np.swapaxes(res.R_world_to_cam[ok], -1, -2)
    S_world = R_cam_to_world @ cov[ok][:, 3:, 3:] @ np.swapaxes(R_cam_to_world, -1, -2)
    M = np.median(S_world, axis=0)
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    sig_rot = float(np.sqrt(max(lam[-1], 0.0)))
    axis = V[:, -1]
    d = np.linalg.norm(res.X_world[res.obs_point] - res.C_world[res.obs_image], axis=1)
    depth = float(np.median(d)) if len(d) else float("nan")
    ground = sig_rot * depth
    sig_pos = np.median(np.sqrt(np.clip(np.diagonal(cov[ok][:, :3, :3], axis1=1, axis2=2), 0, None)), axis=0)
    if abs(axis[2]) > 0.7:
        axis_text = "the vertical"
    else:
        axis_text = f"a horizontal axis at azimuth {_azimuth_deg(axis):.0f} deg"
    out = {"rotation_sigma_deg": float(np.degrees(sig_rot)), "rotation_axis_world": axis.tolist(),
           "ground_shift_m": ground, "camera_to_ground_m": depth, "position_sigma_m": sig_pos.tolist(),
           "reference_sigma_m": ref_sigma_m, "weak": False}
    warn = []
    limit = WEAK_FACTOR * ref_sigma_m
    if ground > limit or float(np.max(sig_pos)) > limit:
        out["weak"] = True
        warn.append(f"weak datum: the block's rotation about {axis_text} is determined to σ "
                    f"{np.degrees(sig_rot):.3g} deg ({ground:.3g} m at the ground {depth:.0f} m from the cameras) and "
                    f"the EOP positions to σ {_sigma_text(sig_pos)} (median), more than {WEAK_FACTOR:g}x the datum "
                    f"sources' {ref_sigma_m * 100:.2g} cm: control in a line (e.g. along a strip's centreline) "
                    "leaves the rotation about it loose; add control away from that line, or camera centres of "
                    "more than one strip")
    return out, warn


def focal_height_correlation(res: BundleResult) -> dict | None:
    """The correlation of the refined focal length f with the block's height above the ground (mean camera Z
    minus mean point Z, world Up), its sigma (px) and the height error (m) that sigma means; None without f."""
    if "f" not in res.refine:
        return None
    cv = res.covariance
    N, M = res.problem.n_poses, res.problem.n_points
    nc = res.problem.n_camera_side
    g = 6 * N + list(res.refine).index("f")
    free_pose = ~cv.camera_side.bad[:6 * N].reshape(N, 6)[:, 2]
    free_pt = res.normals.observed_x.reshape(-1, 3)[:, 2] if M else np.zeros(0, bool)
    if not free_pose.any():
        return None
    l_c = np.zeros(nc)
    l_c[6 * np.flatnonzero(free_pose) + 2] = 1.0 / free_pose.sum()
    l_x = np.zeros(3 * M)
    if free_pt.any():
        l_x[3 * np.flatnonzero(free_pt) + 2] = -1.0 / free_pt.sum()
    y_c, y_x = cv.response(l_c, l_x)
    var_h = float(l_c @ y_c + l_x @ y_x)
    var_f = float(cv.global_cofactors()[g - 6 * N, g - 6 * N])
    cov_fh = float(y_c[g])
    if not (var_h > 0 and var_f > 0):
        return None
    rho = cov_fh / np.sqrt(var_h * var_f)
    f = float(res.camera["f"])
    sig_f = float(np.sqrt(var_f * res.scale2))
    depth = float(np.median(np.abs(res.C_world[:, 2][res.obs_image] - res.X_world[res.obs_point, 2])))
    return {"rho": float(rho), "sigma_f_px": sig_f, "sigma_f_relative": sig_f / f,
            "height_above_ground_m": depth, "height_sigma_from_f_m": sig_f / f * depth,
            "sigma_height_above_ground_m": float(np.sqrt(var_h * res.scale2))}


def focal_height_warning(fh: dict | None) -> str | None:
    """The warning of a high f-height correlation (see `focal_height_correlation`), or None."""
    if fh is None or abs(fh["rho"]) <= F_HEIGHT_CORRELATION:
        return None
    return (f"focal length and flying height are correlated (ρ = {fh['rho']:.2f}): σf = {fh['sigma_f_px']:.2g} px "
            f"({100 * fh['sigma_f_relative']:.2g} %), {fh['height_sigma_from_f_m'] * 100:.2g} cm in heights at "
            f"{fh['height_above_ground_m']:.0f} m above the ground; nadir images from one height cannot separate f "
            "from the height: add oblique images, cross strips or a second flying height, or GCPs with heights, "
            "or fix f (leave it out of --refine)")



def _focal_px(camera, axis: int) -> float:
    """The focal length (px) along image axis 0 (x) or 1 (y): f, or fx/fy of a model with two."""
    return float(camera["f"] if "f" in camera.PARAMS else camera[("fx", "fy")[axis]])


def pp_combinations(res: BundleResult, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The block-level combinations a principal-point shift of d px along image axis `axis` (0: x, 1: y) moves, as
    rows over the camera side (nc,4) and the points (3M,4), in `PP_COMBINATIONS` order: the centres' mean shift
    along that camera axis times f/H (px; H the image's height above the ground: a shift of H d/f is d), the
    ground's mean position E and N (m, free points weighted by their observations), and the mean rotation about
    the other camera axis times f (px: a tilt of d/f is d). Held parameters get 0."""
    N, M = res.problem.n_poses, res.problem.n_points
    bad = res.covariance.camera_side.bad
    oj = res.obs_point
    H = np.abs(res.C_world[:, 2] - np.median(res.X_world[oj, 2])) if len(oj) else np.ones(N)
    f = _focal_px(res.camera, axis)
    e_world = res.R_world_to_cam[:, axis, :]            # the camera axis, world components
    l_c = np.zeros((res.problem.n_camera_side, 4))
    l_x = np.zeros((3 * M, 4))
    pose = 6 * np.arange(N)
    l_c[pose[:, None] + np.arange(3), 0] = e_world * (f / np.maximum(H, 1e-6))[:, None] / N
    l_c[pose + 4 - axis, 3] = f / N
    w = np.bincount(oj, minlength=M) / max(len(oj), 1)
    l_x[0::3, 1], l_x[1::3, 2] = w, w
    l_c[bad] = 0.0
    if M:
        l_x[~res.normals.observed_x] = 0.0
    return l_c, l_x


def multiple_correlation(C: np.ndarray, sel: np.ndarray) -> float:
    """The multiple correlation of variable 0 of covariance matrix C with the variables `sel` (indices > 0): the
    largest correlation with any linear combination of them, sqrt(c^T C_ss^-1 c / C_00); 0 for none."""
    sel = np.asarray(sel, int)
    sel = sel[np.diag(C)[sel] > 0]
    if not len(sel) or not C[0, 0] > 0:
        return 0.0
    d = np.sqrt(np.diag(C)[sel])
    R = C[np.ix_(sel, sel)] / np.outer(d, d)            # on one scale: the combinations are in px and m
    c = C[sel, 0] / (d * np.sqrt(C[0, 0]))
    a = np.linalg.lstsq(R, c, rcond=1e-12)[0]
    return float(np.sqrt(np.clip(c @ a, 0.0, 1.0)))


def principal_point_correlation(res: BundleResult) -> dict | None:
    """How far refined cx/cy are separable from the horizontal datum, as lists in the order of `parameters` (cx,
    cy or one of them): `rho`, the multiple correlation with the combinations of `pp_combinations` (the centres'
    shift along the image axis, the ground's horizontal position, the mean tilt), `variance_inflation`
    1/(1 - rho^2), the parts `rho_centres`, `rho_ground`, `rho_tilt`, `sigma_px`, and `shift_per_sigma_m`
    (sigma/f times the height above ground: the horizontal shift of centres or ground that sigma equals); with
    `height_above_ground_m`, the dominant part `mostly` (centres, ground or tilt) and a `text` line; None without
    cx and cy. Four extra solves per coordinate."""
    if not {"cx", "cy"} & set(res.refine):
        return None
    cv = res.covariance
    N = res.problem.n_poses
    bad = cv.camera_side.bad
    depth = float(np.median(np.abs(res.C_world[:, 2][res.obs_image] - res.X_world[res.obs_point, 2])))
    rows = {}
    for axis, p in enumerate(("cx", "cy")):
        if p not in res.refine or bad[6 * N + list(res.refine).index(p)]:
            continue
        g = 6 * N + list(res.refine).index(p)
        l_c, l_x = pp_combinations(res, axis)
        y_c, y_x = cv.response(l_c, l_x)
        B = l_c.T @ y_c + l_x.T @ y_x
        q = float(cv.global_cofactors()[g - 6 * N, g - 6 * N])
        C = np.block([[np.array([[q]]), y_c[g][None]], [y_c[g][:, None], 0.5 * (B + B.T)]])
        if not (np.isfinite(C).all() and q > 0):
            continue
        r = multiple_correlation(C, np.arange(1, 5))
        sig = float(np.sqrt(q * res.scale2))
        rows[p] = {"rho": r, "variance_inflation": 1.0 / max(1.0 - r * r, 1e-12),
                   "rho_centres": multiple_correlation(C, [1]), "rho_ground": multiple_correlation(C, [2, 3]),
                   "rho_tilt": multiple_correlation(C, [4]), "sigma_px": sig,
                   "shift_per_sigma_m": sig / _focal_px(res.camera, axis) * depth}
    if not rows:
        return None
    ps = list(rows)
    out = {"parameters": ps, **{k: [rows[p][k] for p in ps] for k in rows[ps[0]]}, "height_above_ground_m": depth}
    main = max(PP_PARTS, key=lambda k: max(out[k]))
    out["mostly"] = main.removeprefix("rho_")
    out["text"] = (f"{'/'.join(ps)}: ρ {'/'.join(f'{v:.2f}' for v in out['rho'])} with the horizontal datum "
                   f"(mostly {PP_PARTS[main]}), σ {'/'.join(f'{v:.2g}' for v in out['sigma_px'])} px")
    return out


def principal_point_warning(pp: dict | None) -> str | None:
    """The warning of a principal point the block cannot separate from the horizontal datum (see
    `principal_point_correlation`), or None."""
    if pp is None or max(pp["rho"]) <= PP_CORRELATION:
        return None
    what = "/".join(pp["parameters"])

    def fig(key: str, fmt: str) -> str:
        """The figure of cx and cy, 'a/b'."""
        return "/".join(format(v, fmt) for v in pp[key])

    cm = "/".join(f"{100 * v:.2g}" for v in pp["shift_per_sigma_m"])
    return (f"principal point and horizontal datum are correlated ({what}: ρ = {fig('rho', '.2f')}, variance "
            f"inflation {fig('variance_inflation', '.3g')}; mostly {PP_PARTS['rho_' + pp['mostly']]}): σ{what} = "
            f"{fig('sigma_px', '.2g')} px, {cm} cm of horizontal shift of the camera centres or the ground at "
            f"{pp['height_above_ground_m']:.0f} m above the ground; nadir images of flat ground cannot separate the "
            "principal point from the horizontal position of the centres or the ground or from omega/phi, so a "
            "centre error along the image axes (an antenna offset) goes into it: add tilted or oblique images, or "
            f"fix {what} from a lab calibration (leave {what} out of --refine); cross strips, a second flying height "
            "and GCPs well spread lower its σ where the ground follows it (strips all flown one way)")
