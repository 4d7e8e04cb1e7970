"""GNSS / optic-flow attitude of seed 001: a forward camera's flow, de-rotated with the GNSS pseudo-rates,
gives the focus of expansion (FOE) = the velocity direction in the body frame; with the GNSS velocity and
pseudo-roll that fixes pitch and yaw (angle of attack and drift angle); flow magnitudes give depth and
height above ground (seed 001 eq. 9-12).

Geometry (exact for two discrete frames, not only the instantaneous motion field): with R_cam1_to_ned,
R_cam2_to_ned the camera-to-NED rotations at the two frames and T the camera displacement, a ground point's ray
in frame 2 rotated into frame 1 axes, d2' = R_cam2_to_cam1 d2 with R_cam2_to_cam1 = R_cam1_to_ned^T
R_cam2_to_ned, satisfies d2' ~ P1 - t_c, t_c = R_cam1_to_ned^T T. So after de-rotation
every flow line x1 -> x2' passes through the FOE e = t_c / t_c,z (normalised image coordinates), and by
the law of sines the range to the point from camera 1 is |D1| = |T| sin(gamma2) / sin(Delta), gamma2 the
angle between t_c and d2' and Delta the angle between d1 and d2' — seed eq. 11 (|D| = sin(gamma) |V| / Omega)
in its finite-step form. Height above level ground: AGL = |D| sin(lambda), lambda the depression of the
line of sight (eq. 12).
Attitude: roll = pseudo-roll (seed 001); pitch and yaw solve R_body_to_ned(roll, pitch, yaw) v_b = v_ned/|v|
for the body velocity direction v_b from the FOE (exactly; the seed adds the FOE offsets "normal to" and
"tangential to" the roll angle, the same to first order).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from dgcal.fields.frames import R_body_to_ned_from_rph
from dgcal.fields.pose import so3_exp

# forward camera looking along body x: camera x = body y (right), camera y = body z (down), camera z = body x
R_CAM_TO_BODY_FORWARD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# tracks whose forward-backward Lucas-Kanade round trip misses by more than this (px) are dropped: the bound of a
# track's error, so a focus-of-expansion fit whose residual RMS exceeds it is not tracking noise
FB_MAX_PX = 0.3


def track_features(img1: np.ndarray, img2: np.ndarray, mask: np.ndarray | None = None, max_corners: int = 500,
                   quality: float = 0.005, min_distance: int = 6, win: int = 21, levels: int = 3,
                   fb_max_px: float = FB_MAX_PX) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas-Kanade tracks (px) of good features from img1 to img2, kept when the
    forward-backward round trip closes within `fb_max_px`; ((M,2), (M,2))."""
    a = _to_u8(img1)
    b = _to_u8(img2)
    m = None if mask is None else mask.astype(np.uint8) * 255
    p0 = cv2.goodFeaturesToTrack(a, max_corners, quality, min_distance, mask=m, blockSize=7)
    if p0 is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, winSize=(win, win), maxLevel=levels, criteria=crit)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, winSize=(win, win), maxLevel=levels, criteria=crit)
    fb = np.linalg.norm((p0 - p0b).reshape(-1, 2), axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < fb_max_px)
    return p0.reshape(-1, 2)[ok].astype(float), p1.reshape(-1, 2)[ok].astype(float)


def _to_u8(img: np.ndarray) -> np.ndarray:
    if img.dtype == np.uint8:
        return img
    x = np.asarray(img, np.float32)
    return np.clip(np.rint(x * 255.0 if x.max() <= 1.0 + 1e-6 else x), 0, 255).astype(np.uint8)


def derotate(camera, uv1: np.ndarray, uv2: np.ndarray, R_cam2_to_cam1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays d1 (frame 1) and d2' (frame 2 rays rotated into frame 1 axes) of tracked pixels; (M,3) each."""
    d1 = camera.ray(uv1)
    d2 = camera.ray(uv2) @ np.asarray(R_cam2_to_cam1, float).T
    return d1, d2 / np.linalg.norm(d2, axis=1, keepdims=True)


@dataclass
class Foe:
    """Focus of expansion in normalised image coordinates with its covariance, and the inlier mask."""

    e: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    rms_rad: float
    # the residual rotation: from the axes the pseudo-rates de-rotated frame 2's rays into to camera 1's
    R_derotated_to_cam1: np.ndarray = field(default_factory=lambda: np.eye(3))
    sigma_rotation_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cov_formal: np.ndarray | None = None   # from the residual scatter, tracks taken as independent
    n_blocks: int = 0                      # image blocks of the delete-a-block jackknife (0: not used)
    vif: np.ndarray = field(default_factory=lambda: np.ones(2))   # FOE variance with / without the rotation
    rotation_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))   # the residual rotation (x, y, z)
    flow_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))       # de-rotated flow length of each inlier
    # the jackknife's replicates: block left out of each, [e, rotation] (rad) without it
    jack_blocks: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    jack_rotation_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    jack_e: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def t_hat_cam(self) -> np.ndarray:
        """Unit translation direction in the camera frame (forward, +z)."""
        t = np.array([self.e[0], self.e[1], 1.0])
        return t / np.linalg.norm(t)


def focus_of_expansion(d1: np.ndarray, d2: np.ndarray, estimate_rotation: str = "xyz", huber_k: float = 2.0,
                       min_flow_rad: float = 1e-4, blocks: np.ndarray | None = None) -> Foe:
    """FOE of de-rotated flow (rays d1 -> d2') by weighted line intersection — the seed's weighted voting
    done as robust least squares (Huber). Residual of a line: its flow vector's component perpendicular to
    the direction from the FOE, L sin(angle), which has the same variance (the tracking noise) for every
    line. The FOE is very sensitive to rotation left in the flow (a rotation error moves it by the error
    times distance/flow length, ~10x), so the residual rotation of the GNSS pseudo-rates is estimated
    jointly: about the optical axis ("z", the noisy pseudo roll-rate) it turns flow tangentially, which no
    FOE shift can mimic; about "x"/"y" it is separable from translation because translational flow scales
    with inverse depth and a forward camera over ground sees a wide range of depths.

    `blocks` (an image-region label per ray) turns on the delete-a-block jackknife for `cov`: tracking errors
    are correlated between neighbouring tracks (shared texture, the warp, the residual rotation), which the
    formal covariance (`cov_formal`, tracks independent) misses by a factor of about two."""
    x1 = d1[:, :2] / d1[:, 2:3]
    x2 = d2[:, :2] / d2[:, 2:3]
    f = x2 - x1
    L = np.linalg.norm(f, axis=1)
    keep = L > min_flow_rad
    x1, x2, L = x1[keep], x2[keep], L[keep]
    if len(L) < 4:
        raise ValueError("fewer than four flow vectors to locate the focus of expansion")

    axes = ["xyz".index(a) for a in estimate_rotation]
    D2 = d2[keep]

    def R_derotated_to_cam1_at(p):
        w = np.zeros(3)
        w[axes] = p[2:]
        return so3_exp(w)

    def res(p):
        e = p[:2]
        if axes:
            d = D2 @ R_derotated_to_cam1_at(p).T
            xr = d[:, :2] / d[:, 2:3]
        else:
            xr = x2
        g = xr - x1
        q = x1 - e
        rho = np.maximum(np.linalg.norm(q, axis=1), 1e-6)
        return (g[:, 0] * q[:, 1] - g[:, 1] * q[:, 0]) / rho

    # start: unweighted line intersection
    n = np.column_stack([-(x2 - x1)[:, 1], (x2 - x1)[:, 0]]) / L[:, None]
    e0 = np.linalg.lstsq(n, np.einsum("ij,ij->i", n, x1), rcond=None)[0]
    p0 = np.r_[e0, np.zeros(len(axes))]
    r0 = res(p0)
    D2_all, x1_all = D2, x1
    scale = max(1.4826 * float(np.median(np.abs(r0))), 1e-9)
    sol = least_squares(res, p0, loss="huber", f_scale=huber_k * scale, x_scale="jac")
    r = res(sol.x)
    scale = max(1.4826 * float(np.median(np.abs(r))), 1e-12)
    sol = least_squares(res, sol.x, loss="huber", f_scale=huber_k * scale, x_scale="jac")
    r = res(sol.x)
    inl = np.abs(r) < 3 * huber_k * scale
    Jm = sol.jac[inl]
    s2 = float(np.sum(r[inl] ** 2) / max(inl.sum() - len(sol.x), 1))
    cov = np.linalg.inv(Jm.T @ Jm) * s2
    # how much estimating the rotation costs the FOE: formal variance with it over without it, per FOE axis
    vif = np.diag(cov)[:2] / np.diag(np.linalg.inv(Jm[:, :2].T @ Jm[:, :2]) * s2)
    mask = np.zeros(len(keep), bool)
    mask[np.flatnonzero(keep)[inl]] = True
    R_derotated_to_cam1 = R_derotated_to_cam1_at(sol.x) if axes else np.eye(3)
    cov_e = cov[:2, :2]
    nb = 0
    jack_blocks, jack_e, jack_rot = np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3))
    if blocks is not None:
        lab = np.asarray(blocks)[keep][inl]
        ids = np.unique(lab)
        if len(ids) >= 6:
            sub_x1, sub_D2 = x1_all[inl], D2_all[inl]
            est = []
            for b in ids:  # refit without one block, from the full solution
                m = lab != b
                est.append(_refit(sub_x1[m], sub_D2[m], sol.x, axes, huber_k * scale))
            est = np.array(est)
            nb = len(ids)
            dev = est - est.mean(axis=0)
            cov_j = (nb - 1) / nb * dev.T @ dev
            cov_e = cov_j[:2, :2]
            jack_blocks, jack_e = ids, est[:, :2]
            jack_rot = np.zeros((nb, 3))
            jack_rot[:, axes] = est[:, 2:]
    w_fit = np.zeros(3)
    w_fit[axes] = sol.x[2:]
    d_fit = D2_all[inl] @ R_derotated_to_cam1.T
    flow = np.linalg.norm(d_fit[:, :2] / d_fit[:, 2:3] - x1_all[inl], axis=1)
    return Foe(e=sol.x[:2], cov=cov_e, inliers=mask, rms_rad=float(np.sqrt(s2)),
               R_derotated_to_cam1=R_derotated_to_cam1, sigma_rotation_rad=np.sqrt(np.diag(cov)[2:]),
               cov_formal=cov[:2, :2], n_blocks=nb, rotation_rad=w_fit, flow_rad=flow, jack_blocks=jack_blocks,
               jack_rotation_rad=jack_rot, jack_e=jack_e, vif=vif)


def _refit(x1: np.ndarray, D2: np.ndarray, p0: np.ndarray, axes: list[int], f_scale: float) -> np.ndarray:
    """FOE and residual rotation (as `focus_of_expansion`) of a subset of the flow, from `p0`."""
    def res(p):
        w = np.zeros(3)
        w[axes] = p[2:]
        d = D2 @ so3_exp(w).T if axes else D2
        g = d[:, :2] / d[:, 2:3] - x1
        q = x1 - p[:2]
        rho = np.maximum(np.linalg.norm(q, axis=1), 1e-6)
        return (g[:, 0] * q[:, 1] - g[:, 1] * q[:, 0]) / rho
    return least_squares(res, p0, loss="huber", f_scale=f_scale, x_scale="jac").x


def pitch_yaw_from_velocity(v_hat_b: np.ndarray, v_ned: np.ndarray, roll_deg: float) -> tuple[float, float]:
    """Pitch and yaw (deg) such that R_body_to_ned(roll, pitch, yaw) v_hat_b = v_ned / |v_ned|."""
    n = np.asarray(v_ned, float) / np.linalg.norm(v_ned)
    a = R_body_to_ned_from_rph(roll_deg, 0.0, 0.0) @ (np.asarray(v_hat_b, float) / np.linalg.norm(v_hat_b))
    r = np.hypot(a[0], a[2])
    beta = np.arctan2(a[2], a[0])
    theta = beta - np.arcsin(np.clip(n[2] / r, -1.0, 1.0))  # z of Ry(theta) a = sin(beta - theta) r = n_D
    b = R_body_to_ned_from_rph(0.0, np.degrees(theta), 0.0) @ a
    psi = np.arctan2(n[1], n[0]) - np.arctan2(b[1], b[0])
    return float(np.degrees(theta)), float(np.degrees(psi) % 360.0)


def depth_from_flow(d1: np.ndarray, d2: np.ndarray, t_hat_c: np.ndarray, baseline_m: float) -> np.ndarray:
    """Range (m) from camera 1 to each tracked point: seed eq. 9-11 in the finite-step (law of sines) form."""
    delta = np.arccos(np.clip(np.einsum("ij,ij->i", d1, d2), -1.0, 1.0))
    gamma2 = np.arccos(np.clip(d2 @ t_hat_c, -1.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return baseline_m * np.sin(gamma2) / np.sin(delta)


def height_above_ground(ranges_m: np.ndarray, d1_ned: np.ndarray) -> np.ndarray:
    """Seed eq. 12: AGL = |D| sin(lambda), lambda the depression of each line of sight (NED rays (M,3))."""
    return ranges_m * d1_ned[:, 2] / np.linalg.norm(d1_ned, axis=1)


@dataclass
class FlowAttitude:
    """Attitude of one frame pair (deg) at the first frame, with the FOE offsets and height above ground."""

    roll: float
    pitch: float
    yaw: float
    sigma_pitch: float
    sigma_yaw: float
    pitch_offset: float   # pitch - pseudo-pitch: angle of attack (+ wind)
    yaw_offset: float     # yaw - pseudo-yaw: drift angle
    agl_m: float
    sigma_agl_m: float
    n_tracks: int
    n_inliers: int
    sigma_roll: float = float("nan")      # the pseudo-roll's (given) with the flow's pseudo roll-rate error
    foe: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))   # FOE, normalised image coordinates
    foe_cov: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    pseudo_pitch: float = float("nan")    # flight-path angle (deg)
    pseudo_yaw: float = float("nan")      # course over ground (deg)
    n_blocks: int = 0
    quality: dict = field(default_factory=dict)   # the fit's diagnostics (see `flow_attitude`)
    # pitch, yaw, AGL variance parts (deg^2, m^2): "jackknife", "formal", "other" (see `flow_attitude`)
    variance: dict = field(default_factory=dict)


def variance_ratios(fas: list[FlowAttitude]) -> np.ndarray:
    """The imagery's correlation factor over a run of pairs: per quantity (pitch, yaw, AGL) the median over the pairs
    with a jackknife of its variance over the formal one (tracks taken as independent)."""
    r = [fa.variance["jackknife"] / np.maximum(fa.variance["formal"], 1e-300) for fa in fas
         if fa.variance.get("n_blocks")]
    return np.median(r, axis=0) if r else np.full(3, 4.0)


def pool_sigmas(fa: FlowAttitude, ratios: np.ndarray) -> None:
    """A pair's pitch, yaw and AGL sigmas (in place) with the run's evidence: a jackknife over a dozen image blocks
    has about as many degrees of freedom and now and then falls well short, while the pair's formal variance times
    the run's `ratios` (`variance_ratios`: the tracking errors' correlation) has one per track. Their mean, scaled
    for the degrees of freedom of the two (2 nu: error / sigma is Student-t, whose variance is 2nu / (2nu - 2)),
    raises the jackknife's variance, never lowers it (a pair with few or clustered tracks keeps its own)."""
    v = fa.variance
    nu2 = 2.0 * (v["n_blocks"] - 1)
    t = nu2 / (nu2 - 2.0) if v["n_blocks"] else 1.0
    pooled = t * 0.5 * (v["jackknife"] + np.asarray(ratios) * v["formal"])
    sig = np.sqrt(np.maximum(v["jackknife"], pooled) + v["other"])
    fa.sigma_pitch, fa.sigma_yaw, fa.sigma_agl_m = (float(x) for x in sig)


def ground_mask(camera, R_cam_to_ned: np.ndarray, min_depression_deg: float = 12.0, step: int = 1) -> np.ndarray:
    """Pixels whose line of sight points at least `min_depression_deg` below the horizon (bool H x W)."""
    w, h = camera.image_size
    u, v = np.meshgrid(np.arange(0, w, step, dtype=float), np.arange(0, h, step, dtype=float))
    d = camera.ray(np.column_stack([u.ravel(), v.ravel()])) @ np.asarray(R_cam_to_ned, float).T
    m = (d[:, 2] > np.sin(np.radians(min_depression_deg))).reshape(u.shape)
    if step > 1:
        m = np.repeat(np.repeat(m, step, 0), step, 1)[:h, :w]
    return m


def ground_homography(K: np.ndarray, R_cam2_to_cam1: np.ndarray, t_c1: np.ndarray, n_c1: np.ndarray,
                       d_m: float) -> np.ndarray:
    """Pixel homography frame 1 -> frame 2 induced by the ground plane n.X = d (cam-1 frame, n unit towards
    the ground): X2 = R_cam2_to_cam1^T (I - t n^T / d) X1 with t the camera-2 centre in cam-1 axes (m)."""
    M = np.asarray(R_cam2_to_cam1, float).T @ (np.eye(3) - np.outer(t_c1, n_c1) / d_m)
    return K @ M @ np.linalg.inv(K)


def _apply_h(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def mean_velocity(t: np.ndarray, v_ned: np.ndarray, t1: float, t2: float, n: int = 41) -> tuple[np.ndarray, float]:
    """Mean of a sampled velocity (linear between samples) over [t1, t2] (s) — the camera's chord over a frame
    pair divided by its length — and the noise gain of that mean (sigma of the mean / sigma of one sample)."""
    t = np.asarray(t, float)
    tt = np.linspace(t1, t2, n)
    W = np.zeros((n, len(t)))
    j = np.clip(np.searchsorted(t, tt) - 1, 0, len(t) - 2)
    a = np.clip((tt - t[j]) / (t[j + 1] - t[j]), 0.0, 1.0)
    W[np.arange(n), j] = 1 - a
    W[np.arange(n), j + 1] += a
    w = np.trapezoid(W, tt, axis=0) / (t2 - t1) if t2 > t1 else W[0]
    return w @ np.asarray(v_ned, float), float(np.linalg.norm(w))


def _agl_of(d1: np.ndarray, d2: np.ndarray, e: np.ndarray, v_ned: np.ndarray, roll: float, R_cam_to_body,
            baseline: float) -> np.ndarray:
    """Height above level ground (m) of each track for a FOE `e` (normalised) and baseline (m)."""
    t_c = np.array([e[0], e[1], 1.0]) / np.hypot(np.hypot(e[0], e[1]), 1.0)
    p, y = pitch_yaw_from_velocity(np.asarray(R_cam_to_body) @ t_c, v_ned, roll)
    R_cam_to_ned = R_body_to_ned_from_rph(roll, p, y) @ R_cam_to_body
    return height_above_ground(depth_from_flow(d1, d2, t_c, baseline), d1 @ R_cam_to_ned.T)


def _agl_formal_var(d1, d2, foe, v_ned, roll, R_cam_to_body, baseline, med) -> float:
    """Variance (m^2) of the median height above ground without the jackknife: the FOE's covariance propagated
    and the median's standard error from the tracks' scatter (taken as independent)."""
    def m(e):
        a = _agl_of(d1, d2, e, v_ned, roll, R_cam_to_body, baseline)
        a = a[np.isfinite(a) & (a > 0)]
        return float(np.median(a)) if len(a) else np.nan
    J = np.array([(m(foe.e + h) - med) / 1e-5 for h in np.eye(2) * 1e-5])
    a = _agl_of(d1, d2, foe.e, v_ned, roll, R_cam_to_body, baseline)
    a = a[np.isfinite(a) & (a > 0)]
    cov = foe.cov_formal if foe.cov_formal is not None else foe.cov
    return float(J @ cov @ J) + (1.4826 * np.median(np.abs(a - med)) * 1.2533) ** 2 / max(len(a), 1)


def image_blocks(uv: np.ndarray, image_size, n: int = 5) -> np.ndarray:
    """Label (int) of the cell of an n x n grid over the image that holds each pixel (M,2)."""
    w, h = image_size
    i = np.clip((np.asarray(uv)[:, 0] / w * n).astype(int), 0, n - 1)
    j = np.clip((np.asarray(uv)[:, 1] / h * n).astype(int), 0, n - 1)
    return j * n + i


def flow_attitude(camera, img1: np.ndarray, img2: np.ndarray, dt: float, pseudo_rph1_deg: np.ndarray,
                  omega_b: np.ndarray, v_ned_mid: np.ndarray, R_cam_to_body: np.ndarray = R_CAM_TO_BODY_FORWARD,
                  min_depression_deg: float = 10.0, max_corners: int = 600, refine: int = 2,
                  agl_guess_m: float | None = None, sigma_roll_deg: float = 0.0, sigma_v_mps: float = 0.0,
                  blocks: int = 5, roll_lag_s: float = 0.0) -> FlowAttitude:
    """Seed 001 attitude from one frame pair `dt` s apart: pseudo-roll (deg) at frame 1, pseudo body rates
    `omega_b` (rad/s) over the pair for the de-rotation, GNSS velocity (NED m/s) along the chord: its mean over
    the pair (`mean_velocity`; the velocity at mid-pair differs from it where the path's curvature changes).

    `refine` extra passes warp frame 2 by the ground-plane homography of the previous pass (attitude, FOE,
    AGL) before tracking, so Lucas-Kanade measures only a small, locally uniform residual flow — plain LK
    over-estimates the strongly non-uniform ground flow of a forward camera by a few per cent, and its bias
    follows the residual flow, which moves every track's FOE line alike; two passes converge it to a few
    hundredths of a degree. The warp uses the pinhole part of the camera (distortion is handled by
    `camera.ray` in the geometry).

    Sigmas of pitch and yaw: the FOE covariance by the delete-a-block jackknife over a `blocks` x `blocks`
    image grid (tracking errors are correlated between neighbours; 0: the formal covariance times four), plus the
    roll's and the GNSS velocity's `sigma_v_mps` (per axis) propagated through `pitch_yaw_from_velocity`, plus the
    change of pitch and yaw in the last pass (what the warp still moves). The roll's sigma is the pseudo-roll's
    `sigma_roll_deg` and, where the flow finds the pseudo roll-rate off (the residual rotation about body x over the
    pair), that rate error times `roll_lag_s`: the pseudo-roll comes from the same smoothed derivatives and is
    off by about that much (a ramp's corner under a moving average of width w: the rate off by half its change,
    the angle by w/8 of it, so w/4 for the pseudo attitude's derivative window w). The height above ground's:
    the jackknife's replicates (each refits FOE and rotation without one block), the GNSS speed, the roll, and
    the last pass's change. `variance` keeps the parts (`pool_sigmas` uses a run of pairs) and
    `quality` the fit's diagnostics: residual RMS and median de-rotated flow (px), residual rotation (deg), the
    pseudo roll-rate error (deg/s), the jackknife's blocks and the last pass's changes."""
    rph1 = np.asarray(pseudo_rph1_deg, float)
    R_cam1_to_ned = R_body_to_ned_from_rph(*rph1) @ R_cam_to_body
    mask = ground_mask(camera, R_cam1_to_ned, min_depression_deg, step=4)
    w_c = np.asarray(R_cam_to_body, float).T @ np.asarray(omega_b, float)
    R_cam2_to_cam1 = so3_exp(w_c * dt)
    speed = float(np.linalg.norm(v_ned_mid))
    K = camera.pinhole_K()
    H = None
    if agl_guess_m is not None:
        n_c1 = R_cam1_to_ned.T @ np.array([0.0, 0.0, 1.0])
        H = ground_homography(K, R_cam2_to_cam1, (R_cam1_to_ned.T @ v_ned_mid) * dt, n_c1, agl_guess_m)
    prev = None
    pitch = yaw = med = None  # the previous pass's, for `prev`
    for k in range(refine + 1):
        if H is None:
            uv1, uv2 = track_features(img1, img2, mask, max_corners=max_corners)
        else:
            w, h = camera.image_size
            src = np.asarray(img2, np.float32)
            img2w = cv2.warpPerspective(src, H, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                                        borderMode=cv2.BORDER_REPLICATE)
            img2w = np.clip(img2w, float(src.min()), float(src.max()))  # cubic overshoot
            uv1, uvw = track_features(img1, img2w, mask, max_corners=max_corners)
            uv2 = _apply_h(H, uvw)
        if len(uv1) < 8:
            raise ValueError(f"only {len(uv1)} tracked ground features")
        d1, d2 = derotate(camera, uv1, uv2, R_cam2_to_cam1)
        last = k == refine
        labels = image_blocks(uv1, camera.image_size, blocks) if blocks and last else None
        foe = focus_of_expansion(d1, d2, blocks=labels)
        d2_pre = d2
        d2 = d2 @ foe.R_derotated_to_cam1.T
        R_cam2_to_cam1_fit = foe.R_derotated_to_cam1 @ R_cam2_to_cam1
        t_c = foe.t_hat_cam
        v_b = R_cam_to_body @ t_c
        if k:
            prev = (pitch, yaw, med)
        pitch, yaw = pitch_yaw_from_velocity(v_b, v_ned_mid, rph1[0])
        inl = foe.inliers
        D = depth_from_flow(d1[inl], d2[inl], t_c, speed * dt)
        R_cam1_to_ned_est = R_body_to_ned_from_rph(rph1[0], pitch, yaw) @ R_cam_to_body
        agl = height_above_ground(D, d1[inl] @ R_cam1_to_ned_est.T)
        agl = agl[np.isfinite(agl) & (agl > 0)]
        if len(agl) == 0:
            raise ValueError("no ground ranges from the flow")
        med = float(np.median(agl))
        n_c1 = R_cam1_to_ned_est.T @ np.array([0.0, 0.0, 1.0])
        H = ground_homography(K, R_cam2_to_cam1_fit, t_c * speed * dt, n_c1, med)
    # sigma of pitch/yaw: FOE, pseudo-roll and GNSS velocity through pitch_yaw_from_velocity (numerical Jacobians)
    def py(e, v, r):
        p_, y_ = pitch_yaw_from_velocity(R_cam_to_body @ np.array([e[0], e[1], 1.0]), v, r)
        return np.array([p_ - pitch, (y_ - yaw + 180.0) % 360.0 - 180.0])
    # the pseudo roll-rate's error over the pair, as the flow sees it (the residual rotation about body x): the
    # pseudo-roll, from the same derivatives of the GNSS velocity, is off by about that rate over `roll_lag_s`
    rate_err = float((np.asarray(R_cam_to_body, float) @ foe.rotation_rad)[0]) / dt
    sigma_roll = float(np.hypot(sigma_roll_deg, np.degrees(rate_err) * roll_lag_s))
    J = np.column_stack([py(foe.e + h, v_ned_mid, rph1[0]) / 1e-5 for h in np.eye(2) * 1e-5])
    Jv = np.column_stack([py(foe.e, v_ned_mid + h, rph1[0]) / 1e-4 for h in np.eye(3) * 1e-4])
    Jr = py(foe.e, v_ned_mid, rph1[0] + 1e-4) / 1e-4
    # pitch and yaw variances, three parts: the FOE's by the jackknife (without it the formal covariance times four:
    # it misses the neighbours' correlation, about a factor two in sigma), the FOE's formal one (tracks independent:
    # for `pool_sigmas`) and the rest (GNSS velocity, the roll, the last pass's change)
    inflate = 1.0 if foe.n_blocks else 4.0
    v_jack = inflate * np.diag(J @ foe.cov @ J.T)
    v_formal = np.diag(J @ foe.cov_formal @ J.T) if foe.cov_formal is not None else v_jack / inflate
    C_other = sigma_v_mps ** 2 * Jv @ Jv.T + sigma_roll ** 2 * np.outer(Jr, Jr)
    if prev is not None:  # the warp's own effect: what the last pass still changed
        d = np.array([pitch - prev[0], (yaw - prev[1] + 180.0) % 360.0 - 180.0])
        C_other = C_other + np.diag(d ** 2)
    # height above ground, the same parts: the jackknife's replicates (FOE, residual rotation and tracks without one
    # image block; without it the FOE's formal covariance and the median's standard error), the formal one, and the
    # GNSS speed (the baseline), the pseudo-roll and what the last pass still changed
    var_agl_other = (med * sigma_v_mps / max(speed, 1e-9)) ** 2 + (0.0 if prev is None else (med - prev[2]) ** 2)
    d1i, d2i = d1[inl], d2_pre[inl]
    d2f = d2i @ foe.R_derotated_to_cam1.T
    # the pseudo-roll's error tilts the ground plane under the tracks (not symmetric about the camera in a turn)
    a_r = _agl_of(d1i, d2f, foe.e, v_ned_mid, rph1[0] + 1e-3, R_cam_to_body, speed * dt)
    a_r = a_r[np.isfinite(a_r) & (a_r > 0)]
    if len(a_r):
        var_agl_other += ((float(np.median(a_r)) - med) / 1e-3 * sigma_roll) ** 2
    var_agl_formal = _agl_formal_var(d1i, d2f, foe, v_ned_mid, rph1[0], R_cam_to_body, speed * dt, med)
    if foe.n_blocks:
        lab = labels[inl]
        reps = []
        for b, e_b, w_b in zip(foe.jack_blocks, foe.jack_e, foe.jack_rotation_rad):
            sel = lab != b
            a = _agl_of(d1i[sel], d2i[sel] @ so3_exp(w_b).T, e_b, v_ned_mid, rph1[0], R_cam_to_body, speed * dt)
            a = a[np.isfinite(a) & (a > 0)]
            reps.append(np.median(a) if len(a) else np.nan)
        reps = np.array(reps)
        reps = reps[np.isfinite(reps)]
        var_agl_jack = (len(reps) - 1) / len(reps) * float(np.sum((reps - reps.mean()) ** 2))
    else:
        var_agl_jack = inflate * var_agl_formal
    variance = {"jackknife": np.r_[v_jack, var_agl_jack], "formal": np.r_[v_formal, var_agl_formal],
                "other": np.r_[np.diag(C_other), var_agl_other], "n_blocks": int(foe.n_blocks)}
    # the jackknife's variance has n_blocks - 1 = nu degrees of freedom: error / sigma is Student-t, whose variance
    # is nu / (nu - 2) (a run of pairs does better: `pool_sigmas`)
    nu = foe.n_blocks - 1.0
    sig = np.sqrt(variance["jackknife"] * (nu / (nu - 2.0) if foe.n_blocks else 1.0) + variance["other"])
    f_px = float(K[0, 0])
    flow_px = foe.flow_rad * f_px
    quality = {"rms_px": foe.rms_rad * f_px, "parallax_px": float(np.median(flow_px)) if len(flow_px) else 0.0,
               "rotation_deg": np.degrees(foe.rotation_rad).tolist(),
               "roll_rate_error_dps": float(np.degrees(rate_err)), "n_blocks": int(foe.n_blocks),
               "vif": foe.vif.tolist(),
               "last_change": [] if prev is None else [float(pitch - prev[0]),
                                                       float((yaw - prev[1] + 180.0) % 360.0 - 180.0),
                                                       float(med - prev[2])]}
    pp = np.degrees(np.arctan2(-v_ned_mid[2], np.hypot(v_ned_mid[0], v_ned_mid[1])))
    pyaw = np.degrees(np.arctan2(v_ned_mid[1], v_ned_mid[0]))
    return FlowAttitude(roll=float(rph1[0]), pitch=pitch, yaw=yaw, sigma_pitch=float(sig[0]),
                        sigma_yaw=float(sig[1]), pitch_offset=float(pitch - pp),
                        yaw_offset=float((yaw - pyaw + 180.0) % 360.0 - 180.0), agl_m=med,
                        sigma_agl_m=float(sig[2]), n_tracks=int(len(uv1)), n_inliers=int(inl.sum()),
                        sigma_roll=sigma_roll,
                        foe=np.array(foe.e, float), foe_cov=np.array(foe.cov, float), pseudo_pitch=float(pp),
                        pseudo_yaw=float(pyaw % 360.0), n_blocks=int(foe.n_blocks), quality=quality,
                        variance=variance)
