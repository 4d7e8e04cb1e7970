"""SPP position covariances from an error model with structure: the ionosphere's error measured on the file itself.

Why: the errors SPP leaves on a geodetic receiver are not independent per satellite. Klobuchar's ionosphere is wrong
by a share of its delay that is common to the whole sky (at night its 5 ns constant overstates a quiet ionosphere:
every range too short by a mapped amount, the height 1-2 m low) and by a gradient (on an afternoon it misses the
north-south gradient: every receiver 1-2 m north). A common error goes into the height and the clock, a gradient into
one horizontal axis; an independent per-satellite budget of the same size spreads it over all axes and averages it
down (east sigmas twice the errors, north and height sigmas half of them on the real files).

A receiver with a second code measures its own ionosphere: the geometry-free code difference (P2 - P1)/(g - 1), less
the satellite's broadcast group delay, is the first frequency's slant delay plus a receiver bias per system. Against
the Klobuchar delay I of each satellite it is fitted over the whole file as

    I_meas - I = b_sys + I (a + g_N dN + g_E dE)

(a: the model's common relative error; g_N, g_E: its relative gradient per degree of the ionospheric pierce point's
offset dN, dE from the receiver, Klobuchar's own geometry). The satellites' hardware biases (C1C against C1W,
~0.3 m) stay in the residuals constant per satellite, so the parameters' uncertainty is the cluster-robust one
(satellites are the independent units, not epochs: their residuals are correlated over the whole file). A file is
one draw of these slow errors: each component's variance is its expected square given the estimate, its
uncertainty and a prior (`PRIOR_SIGMA`: a one-sample variance component that a poorly measured file does not move
far from the prior), and the position covariance of every epoch is the least-squares sandwich

    C_p = K (D + sum_k theta_k u_k u_k') K',   K = (H' W H)^-1 H' W

with the weights W the solution used, u_a = I, u_gN = I dN, u_gE = I dE, the troposphere's zenith error mapped to
every satellite (`ZTD_SIGMA_M`, common too), and D per satellite: the receiver noise told by the residuals, the
broadcast orbit and clock (`corrections.orbit_clock_sigma_m`) and the ionosphere's small-scale part
(`IONO_LOCAL_SHARE`). Files without a second code (or too few satellites with one) keep the independent budget
(D the front end's sigmas, nothing common). In both, the per-satellite slow part of D (orbit, clock, local
ionosphere; or the whole budget) is scaled by what the file's residuals say (`slow_scale`: variance-component
estimation with the fit's own weights, E[v'Wv] = sum w (1 - h) d + the common errors' leftovers, the satellites
counted as the independent samples and the budget as `PRIOR_DOF` more). The weights, and so the positions, are
unchanged: only the covariances are the model's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.fields.constants import C_LIGHT
from dgcal.pos.gnss.corrections import KLOBUCHAR_SHARE, ZTD_SIGMA_M, tropo_mapping
from dgcal.pos.gnss.ephemeris import group_delay_s
from dgcal.pos.gnss.spp_batch import NG, NP, groups, normal_inverse, segment_sum

IONO_LOCAL_SHARE = 0.1    # the ionosphere's error not in a common share or a gradient: 10 % of the delay per satellite
# Before the file speaks: Klobuchar removes about half of the delay's RMS (Klobuchar 1987), so its common relative
# error is ~0.5; its gradient error a few per cent of the delay per degree (a tenth of the delay's change across the
# ~10 degrees between pierce points). The file's estimate, uncertain by its satellites' hardware biases, is combined
# with these (the posterior of a zero-mean normal prior): a poorly measured component stays near its prior.
PRIOR_SIGMA = np.array([0.5, 0.03, 0.03])
MIN_CLUSTERS = 8          # satellites with two codes below which the file does not measure its ionosphere
_FIELD = ("common", "gradient_north_per_deg", "gradient_east_per_deg")


@dataclass
class IonoErrorField:
    """Klobuchar's error on one file: `x` (3,) the common relative error and the relative gradients per degree
    north and east, `cov` (3,3) their cluster-robust covariance, `theta` (3,) the variance components (the expected
square under `PRIOR_SIGMA`),
    the receiver's code bias per system (m), the satellites and rows it rests on and the fit's residual RMS (m)."""

    x: np.ndarray
    cov: np.ndarray
    theta: np.ndarray
    receiver_bias_m: dict
    satellites: int
    rows: int
    residual_rms_m: float

    def as_dict(self) -> dict:
        """JSON-ready summary."""
        sd = np.sqrt(np.diag(self.cov))
        return {**{k: float(v) for k, v in zip(_FIELD, self.x)}, **{k + "_sigma": float(s) for k, s in zip(_FIELD, sd)},
                "receiver_bias_m": {k: float(v) for k, v in self.receiver_bias_m.items()},
                "satellites": self.satellites, "rows": self.rows, "residual_rms_m": self.residual_rms_m}


def pierce_offsets_deg(elev: np.ndarray, azim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offset (deg, north and east) of the ionospheric pierce point from the receiver, Klobuchar's geometry
    (earth-centred angle 0.0137/(el + 0.11) - 0.022 semicircles; elevation and azimuth in rad)."""
    psi = (0.0137 / (np.asarray(elev) / np.pi + 0.11) - 0.022) * 180.0
    return psi * np.cos(azim), psi * np.sin(azim)


def iono_error_field(tab, fits, nav) -> IonoErrorField | None:
    """Klobuchar's common error and gradients measured by the file's geometry-free code differences (see the
    module doc); None when fewer than `MIN_CLUSTERS` satellites have a second code next to a Klobuchar delay."""
    m = fits.m
    i = m.idx
    have = (np.isfinite(tab.pr2[i]) & np.isfinite(tab.wl2[i]) & (m.iono > 0)) & fits.ok[m.ep]
    if not have.any():
        return None
    r = np.flatnonzero(have)
    i = i[r]
    sats = tab.sat[i].astype(str)
    uniq, cl = np.unique(sats, return_inverse=True)
    if len(uniq) < MIN_CLUSTERS:
        return None
    # a group delay is a hardware constant: once per satellite
    tgd = group_delay_s(nav, uniq.tolist(), np.full(len(uniq), np.median(tab.t)))[cl]
    g = (tab.wl2[i] / tab.raw["wavelength_m"][i]) ** 2
    meas = (tab.pr2[i] - tab.raw["pr_m"][i]) / (g - 1.0) - C_LIGHT * tgd
    klob = m.iono[r]
    dn, de = pierce_offsets_deg(np.radians(m.elev_deg[r]), np.radians(m.azim_deg[r]))
    systems = np.unique(tab.system[i].astype(str))
    A = np.column_stack([klob, klob * dn, klob * de] + [(tab.system[i] == s).astype(float) for s in systems])
    y = meas - klob
    keep = np.isfinite(y)
    for _ in range(2):          # a tracking glitch of one code is no ionosphere: 5 robust sigmas
        Ak = A[keep]
        try:
            x = np.linalg.solve(Ak.T @ Ak, Ak.T @ y[keep])     # normal equations: a thin problem
        except np.linalg.LinAlgError:                           # a sky that does not separate the parts
            return None
        v = y - A @ x
        mad = 1.4826 * np.median(np.abs(v[keep] - np.median(v[keep])))
        keep = np.isfinite(y) & (np.abs(v) <= 5.0 * max(mad, 0.05))
    n_cl = len(np.unique(cl[keep]))
    p = A.shape[1]
    if n_cl < max(MIN_CLUSTERS, p + 3):
        return None
    Ak, vk, ck = A[keep], v[keep], cl[keep]
    try:
        Q = np.linalg.inv(Ak.T @ Ak)
    except np.linalg.LinAlgError:
        return None
    score = np.zeros((len(uniq), p))
    np.add.at(score, ck, Ak * vk[:, None])
    cov = Q @ (score.T @ score) @ Q * n_cl / (n_cl - p)
    cov3 = cov[:3, :3]
    var, tau2 = np.diag(cov3), PRIOR_SIGMA ** 2
    mean = x[:3] * tau2 / (tau2 + var)
    theta = mean ** 2 + tau2 * var / (tau2 + var)
    return IonoErrorField(x[:3], cov3, theta, dict(zip(systems.tolist(), x[3:].tolist())),
                          n_cl, int(keep.sum()), float(np.sqrt(np.mean(vk ** 2))))


PRIOR_DOF = 4   # the budget's weight against the file's own residuals, in redundant satellites' worth


@dataclass
class _Weights:
    """An epoch-stacked least-squares problem: rows H (M,NP), weights w (M,) 1/m^2, N^-1 (E,NP,NP), leverages h
    (M,)."""

    H: np.ndarray
    w: np.ndarray
    Ninv: np.ndarray
    h: np.ndarray

    @classmethod
    def of(cls, tab, fits) -> "_Weights":
        m, b = fits.m, fits.bounds
        E = len(fits.ok)
        grp = groups(tab, m)
        X = np.where(fits.ok[:, None], fits.p, 0.0)
        d = m.sat_pos - X[m.ep]
        H = np.zeros((len(m.ep), NP))
        H[:, :3] = -d / np.linalg.norm(d, axis=1, keepdims=True)
        H[np.arange(len(m.ep)), 3 + grp] = 1.0
        w = 1.0 / m.sigma_pr ** 2
        absent = ~np.stack([np.bincount(m.ep[grp == j], minlength=E) > 0 for j in range(NG)], axis=1)
        Ninv = normal_inverse(H * np.sqrt(w)[:, None], b, absent)
        return cls(H, w, Ninv, w * np.einsum("ni,nij,nj->n", H, Ninv[m.ep], H))

    def gain(self, ep: np.ndarray) -> np.ndarray:
        """Column of K = N^-1 H' W (position rows) of every satellite (M,3)."""
        return np.einsum("nij,nj->ni", self.Ninv[ep][:, :3, :], self.H) * self.w[:, None]

    def residual_energy(self, u: np.ndarray, ep: np.ndarray, b: np.ndarray) -> float:
        """(R u)' W (R u) summed over epochs, R = I - H K: what a common error u (M,) leaves in the residuals."""
        s = segment_sum(self.H * (self.w * u)[:, None], b)
        r = u - np.einsum("ni,ni->n", self.H, np.einsum("nij,nj->ni", self.Ninv[ep], s[ep]))
        return float(np.sum(self.w * r ** 2))


def covariance(tab, fits, nav, field: IonoErrorField | None) -> tuple[np.ndarray, dict]:
    """Position covariance (E,3,3) ECEF m^2 of every epoch of `fits` (NaN where it failed) under the error model of
    the module doc, and what it rests on: with `field` (a file with two codes) the structured model, else the front
    end's independent budget; in both the slow per-satellite part's scale told by the residuals (`slow_scale`)."""
    m, b = fits.m, fits.bounds
    W = _Weights.of(tab, fits)
    K = W.gain(m.ep)
    el = np.radians(m.elev_deg)
    noise2 = np.maximum(m.sigma_pr ** 2 - m.sigma_bias ** 2, 0.0)
    common: list = []
    if field is None:
        slow2 = m.sigma_bias ** 2
    else:
        share = 1.0 if getattr(nav, "ion_source", "") == "default" else KLOBUCHAR_SHARE
        tropo = ZTD_SIGMA_M * tropo_mapping(el)
        # the per-satellite part: the budget less the shares now modelled as common, and the local ionosphere
        slow2 = (np.maximum(m.sigma_bias ** 2 - (share * m.iono) ** 2 - tropo ** 2, 0.0)
                 + (IONO_LOCAL_SHARE * m.iono) ** 2)
        dn, de = pierce_offsets_deg(el, np.radians(m.azim_deg))
        common = [(1.0, tropo), (field.theta[0], m.iono), (field.theta[1], m.iono * dn), (field.theta[2], m.iono * de)]
    scale, info = slow_scale(fits, W, noise2, slow2, common, tab)
    cov = segment_sum(K[:, :, None] * K[:, None, :] * (noise2 + scale * slow2)[:, None, None], b)
    for theta, u in common:
        s = segment_sum(K * u[:, None], b)
        cov += theta * s[:, :, None] * s[:, None, :]
    info = {"model": "independent" if field is None else "structured", **info}
    if field is not None:
        info["ionosphere"] = field.as_dict()
    return np.where(fits.ok[:, None, None], cov, np.nan), info


def slow_scale(fits, W: _Weights, noise2: np.ndarray, slow2: np.ndarray, common: list, tab) -> tuple[float, dict]:
    """Scale of the slow per-satellite variances `slow2` (M,) m^2 told by the file's residuals: their weighted sum of
    squares against its expectation, sum w (1 - h) (noise2 + theta slow2) plus what the common errors leave
    (variance-component estimation, the fit's own weights). The slow errors of a satellite are one draw per file,
    so the estimate rests on the satellites, not the epochs: it is combined with the budget's 1 as
    (nu theta_hat + PRIOR_DOF) / (nu + PRIOR_DOF), nu the satellites beyond four."""
    m, b = fits.m, fits.bounds
    use = fits.ok[m.ep]
    q = float(np.sum((W.w * fits.res ** 2)[use]))
    a = float(np.sum((W.w * (1.0 - W.h) * noise2)[use]))
    a += sum(theta * W.residual_energy(np.where(use, u, 0.0), m.ep, b) for theta, u in common)
    d = float(np.sum((W.w * (1.0 - W.h) * slow2)[use]))
    nu = max(len(np.unique(tab.sat[m.idx[use]].astype(str))) - 4, 0)
    if d <= 0.0 or nu < 1:
        return 1.0, {"slow_scale": 1.0, "slow_scale_file": None, "slow_dof": nu}
    hat = max((q - a) / d, 0.0)
    scale = (nu * hat + PRIOR_DOF) / (nu + PRIOR_DOF)
    return float(scale), {"slow_scale": float(scale), "slow_scale_file": float(hat), "slow_dof": int(nu)}
