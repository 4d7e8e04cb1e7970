"""Time-correlated errors of the LC fixes: a Gauss-Markov error state per nav axis beside the IMU states.

A GNSS solution's position error is not white. RTK and PPK fixes carry multipath and the differential atmosphere
(centimetres over seconds to minutes), a float or code solution the orbit, clock and atmosphere models' residuals
(metres over minutes), and a receiver's own filter correlates consecutive epochs further. Weighted as white noise at
1-50 Hz, the smoother averages every fix the IMU bridges as independent and reports sigmas several to tens of
times too small (error/sigma 2-4 on simulated PPK fixes, 25-75 on a simulated low-cost flight). The TC smoother's
answer for the pseudoranges (`dgcal.pos.smoother.code_bias`) serves here too: the stated covariance C of every fix
is split into a white part w C and, per nav axis, a first-order Gauss-Markov error of variance (1 - w) C_ii and
correlation time tau,

    e_k = sigma_k u_k,   u_{k+1} = phi u_k + n_k,   phi = exp(-dt/tau),   var(n) = 1 - phi^2,   u_first ~ N(0, 1),

held as one 3-vector per keyframe (`FE(k)`, metres, holding the correction d = -e) from the first fix to the last,
through the gaps between fixes, where only the process ties it (sigma_k is interpolated there).

The fix factor, the antenna position p + R L against the fix z corrected by d, with the white part as its noise,

    r_k = p_k + R_k L - z_k - d_k ~ N(0, w C_k),

is held linearised (a `LinearContainerFactor`: a whitened Jacobian on the pose and the error state), as the double
differences are (`dgcal.pos.smoother.carrier.linear_dd_factor`); what that leaves out is |L| |dtheta|^2 / 2 and the
chart's |dtheta| |dp| / 2, so the smoother re-linearises it where a pose moved by more than 1 m or 0.03 deg
(`dgcal.pos.smoother.batch.relinearise_lc`). It is not robust (Huber): the fixes are screened before the graph
is built and after the first solution (`dgcal.pos.smoother.integrity`).

The white share w is what the data say: the first pass takes the fixes as white (w = 1), then the white part's
variance factor, the whitened residuals' sum of squares over their redundancy (Helmert's variance-component
estimate, `dgcal.pos.smoother.covariance.variance_factors`), scales w until it is one
(`dgcal.pos.smoother.batch.smooth`). The IMU bridges a fix interval to millimetres or centimetres, so what the
fixes scatter about the smoothed track from epoch to epoch is their white part; the rest of the stated variance is
taken as correlated. White fixes keep w = 1 (error/sigma 0.8-1.1 on simulated SPP fixes of exact models); a
low-cost receiver's come out at w = 0.03 (simulated: 0.2 m white of 1.1 m), RTKLIB's RTK fixes of the real car
drive at 0.37, simulated PPK fixes at 0.15-0.25.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from dgcal.pos.smoother.factors import FE, X

MIN_CORR_SHARE = 0.01    # the Gauss-Markov part is kept (small) when the white part takes the whole stated variance
MAX_WHITE_SHARE = 100.0  # the white part may exceed the stated variance (fixes noisier than they say), up to this


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@dataclass
class LcFixModel:
    """The LC fixes of a problem with their error model: keyframe `k` (M,) sorted, antenna position `z` (M,3) nav m,
    stated covariance `C` (M,3,3) nav m^2, the white share of C, the Gauss-Markov correlation time `tau_s`, the
    keyframe times `t_key` and the lever arm (body, m); `lin`: the poses (R_body_to_nav (K,3,3), p (K,3)) the
    factors are linearised at."""

    k: np.ndarray
    z: np.ndarray
    C: np.ndarray
    white_share: float
    tau_s: float
    t_key: np.ndarray
    lever_arm_b: np.ndarray
    lin: tuple | None = None

    @property
    def span(self) -> tuple[int, int]:
        """The first and last keyframe with an error state."""
        return int(self.k[0]), int(self.k[-1])

    def corr_sigma(self) -> np.ndarray:
        """(M,3) sigma (m) of each fix's Gauss-Markov error per nav axis."""
        share = max(1.0 - self.white_share, MIN_CORR_SHARE)
        return np.sqrt(share * np.einsum("mii->mi", self.C))

    def sigma_at_keyframes(self) -> np.ndarray:
        """(n,3) the Gauss-Markov sigma (m) at the keyframes of the span (interpolated between fixes)."""
        k0, k1 = self.span
        s = self.corr_sigma()
        ks = np.arange(k0, k1 + 1)
        return np.stack([np.interp(ks, self.k, s[:, j]) for j in range(3)], axis=1)

    def white_cov(self) -> np.ndarray:
        """(M,3,3) covariance (m^2) of the fixes' white part."""
        return self.white_share * self.C

    def whitener(self) -> np.ndarray:
        """(M,3,3) W with W'W the inverse of the white part's covariance."""
        return np.linalg.inv(np.linalg.cholesky(self.white_cov()))


def lc_fix_model(t_key: np.ndarray, k: np.ndarray, z_nav: np.ndarray, C_nav: np.ndarray, white_share: float,
                 tau_s: float, lever_arm_b) -> LcFixModel:
    """The fixes at keyframes `k` (sorted, unique) with positions `z_nav` (M,3) and covariances `C_nav` (M,3,3)."""
    return LcFixModel(np.asarray(k, int), np.asarray(z_nav, float), np.asarray(C_nav, float),
                      float(np.clip(white_share, 1e-4, MAX_WHITE_SHARE)), float(tau_s), np.asarray(t_key, float),
                      np.asarray(lever_arm_b, float))


def set_white_share(model: LcFixModel, white_share: float) -> None:
    """A new white share (the Gauss-Markov sigmas follow: the rest of the stated variance), in place."""
    model.white_share = float(np.clip(white_share, 1e-4, MAX_WHITE_SHARE))


def insert_initial(model: LcFixModel, values) -> None:
    """Initial values of the error states: zero."""
    k0, k1 = model.span
    for k in range(k0, k1 + 1):
        values.insert(FE(k), np.zeros(3))


def _linear(keys: list, mats: list, lin_values):
    """The linear factor sum(mats_i x_i) ~ N(0, I) about `lin_values` (error exactly A x; mats already whitened)."""
    x0 = sum(M @ lin_values.atVector(key) for key, M in zip(keys, mats))
    args = []
    for key, M in zip(keys, mats):
        args += [key, M]
    jf = gtsam.JacobianFactor(*args, -x0, gtsam.noiseModel.Unit.Create(3))
    lin = gtsam.Values()
    for key in keys:
        lin.insert(key, lin_values.atVector(key))
    return gtsam.LinearContainerFactor(jf, lin)


def process_factors(model: LcFixModel, lin_values) -> list[tuple[int, object]]:
    """(keyframe, factor) of the error states' prior u ~ N(0, I) at the first fix and their Gauss-Markov steps
    u_{k+1} - phi u_k ~ N(0, (1 - phi^2) I), u = d / sigma per axis.

    phi = exp(-dt/tau) times the ratio of the smaller to the larger sigma of the step: where the stated sigma steps
    (a float solution fixing, a code solution becoming RTK) the error is a different one, not the old one scaled.
    With u carried unchanged through such a step the smoother would read the fixed epochs' error off the float
    ones (their ratio fixed by the model), far more precisely than either is known."""
    k0, k1 = model.span
    sig = model.sigma_at_keyframes()
    out = [(k0, _linear([FE(k0)], [np.diag(1.0 / sig[0])], lin_values))]
    dt = np.diff(model.t_key[k0:k1 + 1])
    phi = np.exp(-dt / model.tau_s)[:, None] * np.minimum(sig[1:], sig[:-1]) / np.maximum(sig[1:], sig[:-1])
    w = 1.0 / np.sqrt(np.maximum(1.0 - phi * phi, 1e-12))
    for k in range(k0, k1):
        i = k - k0
        out.append((k + 1, _linear([FE(k + 1), FE(k)], [np.diag(w[i] / sig[i + 1]), np.diag(-w[i] * phi[i] / sig[i])],
                                   lin_values)))
    return out


def _corrections(values, k: np.ndarray) -> np.ndarray:
    return np.array([values.atVector(FE(int(kk))) for kk in k]).reshape(len(k), 3)


def fix_errors(model: LcFixModel, R_body_to_nav: np.ndarray, p: np.ndarray, d: np.ndarray,
               rows: np.ndarray | None = None) -> np.ndarray:
    """(M,3) unwhitened errors p + R L - z - d (m) of the fixes `rows` (all if None) at keyframe poses (K,...) and
    error-state corrections d (M,3)."""
    i = np.arange(len(model.k)) if rows is None else rows
    k = model.k[i]
    return p[k] + R_body_to_nav[k] @ model.lever_arm_b - model.z[i] - d


def _pose_jacobian(model: LcFixModel, R: np.ndarray) -> np.ndarray:
    """(M,3,6) Jacobian of the antenna position on gtsam's Pose3 local coordinates (rotation, translation)."""
    return np.concatenate([-R @ _skew(model.lever_arm_b), R], axis=2)


def fix_factors(model: LcFixModel, values, R_body_to_nav: np.ndarray, p: np.ndarray,
                rows: np.ndarray | None = None) -> dict:
    """keyframe -> the linearised fix factor (module docstring) of the fixes `rows` (all if None) at `values`,
    whose keyframe poses are R_body_to_nav (K,3,3), p (K,3)."""
    i = np.arange(len(model.k)) if rows is None else np.asarray(rows, int)
    if not len(i):
        return {}
    k = model.k[i]
    d = _corrections(values, k)
    e = fix_errors(model, R_body_to_nav, p, d, i)
    W = model.whitener()[i]
    A = W @ _pose_jacobian(model, R_body_to_nav[k])
    b = -np.einsum("mij,mj->mi", W, e)
    unit = gtsam.noiseModel.Unit.Create(3)
    out = {}
    for j, kk in enumerate(k.tolist()):
        jf = gtsam.JacobianFactor(X(kk), A[j], FE(kk), -W[j], b[j], unit)
        lin = gtsam.Values()
        lin.insert(X(kk), values.atPose3(X(kk)))
        lin.insert(FE(kk), d[j])
        out[kk] = gtsam.LinearContainerFactor(jf, lin)
    return out


def fix_residuals(model: LcFixModel, values, R_body_to_nav: np.ndarray, p: np.ndarray,
                  rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Post-fit residuals of the fixes `rows` (all if None): keyframe (M,), residual (M,3) m (nav axes, the error
    states' correction applied) and the white part's sigma (M,3) m."""
    i = np.arange(len(model.k)) if rows is None else np.asarray(rows, int)
    k = model.k[i]
    e = fix_errors(model, R_body_to_nav, p, _corrections(values, k), i)
    return k, e, np.sqrt(np.einsum("mii->mi", model.white_cov()[i]))


def fix_row(model: LcFixModel, k: int) -> int | None:
    """The model's row of the fix at keyframe k, or None."""
    i = int(np.searchsorted(model.k, k))
    return i if i < len(model.k) and model.k[i] == k else None


def fix_error_at(model: LcFixModel, k: int, values) -> tuple[np.ndarray, np.ndarray]:
    """The unwhitened error (3,) m of the fix at keyframe k at `values` (which hold X(k) and FE(k)) and its white
    sigmas (3,) m."""
    pose = values.atPose3(X(k))
    e = pose.translation() + pose.rotation().matrix() @ model.lever_arm_b - model.z[fix_row(model, k)] \
        - values.atVector(FE(k))
    return e, fix_white_sigma(model, k)


def fix_white_sigma(model: LcFixModel, k: int) -> np.ndarray:
    """The white sigmas (3,) m of the fix at keyframe k."""
    return np.sqrt(np.diag(model.white_cov()[fix_row(model, k)]))


def error_estimates(model: LcFixModel, values) -> tuple[np.ndarray, np.ndarray]:
    """The fixes' estimated time-correlated errors: keyframes of the span (n,) and errors (n,3) nav m."""
    k0, k1 = model.span
    ks = np.arange(k0, k1 + 1)
    return ks, -gtsam.utilities.extractVectors(values, "f").reshape(-1, 3)
