"""Single-point positioning of many epochs at once: the front end's models and the weighted least squares of
`dgcal.pos.gnss.spp` vectorised over epochs and satellites.

An hour of 1 Hz data is 3600 small problems of ~10 satellites; solved one by one, NumPy's per-call overhead is
almost all of the time (2.9 ms per epoch). Here every step runs on all epochs at once: the satellites of all epochs
are one flat table (sorted by epoch), normal matrices are summed per epoch (`np.add.reduceat`) and inverted as a
stack. Each epoch's parameters are [x, y, z, one clock per clock group G, E, C, R] (m); a clock group without a
satellite in the epoch gets unit information, coupled to nothing, which leaves the other parameters exactly as
the reduced problem gives them. Every decision (RAIM rejections, the outer iterations at the moved position, the
DOP and Doppler tests) is taken per epoch exactly as `spp.solve_epoch` describes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.fields.constants import C_LIGHT
from dgcal.fields.crs import R_ecef_to_enu_at, ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.pos.gnss.chi2_points import chi2_limit
from dgcal.pos.gnss.corrections import (KLOBUCHAR_SHARE, code_sigma_m, klobuchar_delay_m, model_sigma_m,
                                        sagnac_rotate, saastamoinen_delay_m)
from dgcal.pos.gnss.ephemeris import group_delay_s, states_at_transmission
from dgcal.pos.gnss.observations import GnssEpoch

GROUPS = ("G", "E", "C", "R")            # receiver clock parameters, in `ALL_SYSTEMS` order
NG = len(GROUPS)
NP = 3 + NG                              # parameters of an epoch
_GROUP_OF = {"G": 0, "J": 0, "E": 1, "C": 2, "R": 3}
IF_CODE_BIAS_M = 1.0   # sigma (m) of the uncorrected code biases in the ionosphere-free combination
_RAW = ("pr_m", "doppler_hz", "range_rate_mps", "wavelength_m", "cn0_dbhz")


@dataclass
class ObsTable:
    """The satellites of E raw epochs as flat arrays in epoch order: `ep` (N,) the epoch of each, `sat` and
    `system` (N,) strings, the raw measurements of `_RAW`, the second code and its wavelength (NaN where absent),
    and the epoch times `t` (E,) s."""

    ep: np.ndarray
    sat: np.ndarray
    system: np.ndarray
    raw: dict
    pr2: np.ndarray
    wl2: np.ndarray
    t: np.ndarray

    @property
    def group(self) -> np.ndarray:
        """Clock group index (0 G/J, 1 E, 2 C, 3 R; -1 other) of every row."""
        if getattr(self, "_group", None) is None:
            self._group = np.select([self.system == s for s in _GROUP_OF], list(_GROUP_OF.values()), -1)
        return self._group

    def satellite_states(self, nav) -> tuple:
        """Every row's satellite at transmission (`dgcal.pos.gnss.ephemeris.states_at_transmission`: position,
        velocity, clock, drift, URA, ok), computed once: they depend on the time and the pseudorange only, not on
        where the receiver is assumed, so every round of the positioning reuses them."""
        hit = getattr(self, "_states", None)
        if hit is None or hit[0] is not nav:
            ok_pr = np.isfinite(self.raw["pr_m"]) & (self.group >= 0)   # the systems SPP knows
            n = len(self.ep)
            out = [np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.full(n, np.nan), np.full(n, np.nan),
                   np.full(n, np.nan), np.zeros(n, bool)]
            i = np.flatnonzero(ok_pr)
            for a, b in zip(out, states_at_transmission(nav, self.sat[i].tolist(), self.t[self.ep[i]],
                                                        self.raw["pr_m"][i])):
                a[i] = b
            hit = (nav, tuple(out))
            self._states = hit
        return hit[1]

    def subset(self, epochs: np.ndarray) -> "ObsTable":
        """The table of some epochs (indices, ascending), renumbered 0.. in that order."""
        where = np.full(len(self.t), -1)
        where[epochs] = np.arange(len(epochs))
        r = np.flatnonzero(where[self.ep] >= 0)
        return ObsTable(where[self.ep[r]], self.sat[r], self.system[r], {k: v[r] for k, v in self.raw.items()},
                        self.pr2[r], self.wl2[r], self.t[epochs])

    @classmethod
    def from_epochs(cls, epochs: list) -> "ObsTable":
        """Flatten raw `GnssEpoch`s."""
        n = np.array([e.n for e in epochs], int)
        ep = np.repeat(np.arange(len(epochs)), n)
        sat = np.array([s for e in epochs for s in e.sat], dtype=object)
        system = np.concatenate([np.asarray(e.system, str) for e in epochs]) if len(epochs) else np.zeros(0, str)
        raw = {f: np.concatenate([np.asarray(getattr(e, f), float) for e in epochs]) if len(epochs) else np.zeros(0)
               for f in _RAW}

        def second(f):
            return np.concatenate([np.full(e.n, np.nan) if getattr(e, f) is None else np.asarray(getattr(e, f), float)
                                   for e in epochs]) if len(epochs) else np.zeros(0)
        return cls(ep, sat, system, raw, second("pr2_m"), second("wavelength2_m"),
                   np.array([e.t_gps for e in epochs], float))


@dataclass
class Modelled:
    """Modelled satellites (the front end's products, `GnssEpoch` fields) of some epochs, flat and in epoch order:
    `idx` (M,) rows of the `ObsTable`, `ep` (M,) their epochs; `p_approx` (E,3) the position each epoch was
    modelled at (NaN: unknown)."""

    idx: np.ndarray
    ep: np.ndarray
    pr_m: np.ndarray
    sat_pos: np.ndarray
    sat_vel: np.ndarray
    clk: np.ndarray
    drift: np.ndarray
    iono: np.ndarray
    tropo: np.ndarray
    elev_deg: np.ndarray
    azim_deg: np.ndarray
    sigma_pr: np.ndarray
    sigma_rr: np.ndarray
    sigma_bias: np.ndarray
    p_approx: np.ndarray

    def take(self, m: np.ndarray) -> "Modelled":
        """The satellites of boolean mask or index array m."""
        kw = {k: (v if k == "p_approx" else v[m]) for k, v in self.__dict__.items()}
        return Modelled(**kw)

    def pr_corr(self, tab: ObsTable) -> np.ndarray:
        """Corrected pseudoranges (m), as `GnssEpoch.pr_corr_m`."""
        return self.pr_m + C_LIGHT * self.clk - self.iono - self.tropo

    def rr_corr(self, tab: ObsTable) -> np.ndarray:
        """Corrected range rates (m/s), as `GnssEpoch.rr_corr_mps`."""
        return tab.raw["range_rate_mps"][self.idx] + C_LIGHT * self.drift


def dual_frequency(tab: ObsTable, mode: str) -> np.ndarray:
    """Satellites whose ionosphere-free combination the front end uses (GPS, QZSS, Galileo, GLONASS with a second
    code), under the `SppOptions.iono` mode."""
    if mode not in ("auto", "klobuchar", "iono-free"):
        raise ValueError(f"iono must be auto, klobuchar or iono-free, not {mode!r}")
    if mode == "klobuchar":
        return np.zeros(len(tab.ep), bool)
    return np.isfinite(tab.pr2) & np.isfinite(tab.wl2) & np.isin(tab.system, ["G", "J", "E", "R"])


def _known(p: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(p), axis=-1) & (np.linalg.norm(np.nan_to_num(p), axis=-1) > 6.0e6)


def model(tab: ObsTable, nav, p_rx: np.ndarray, opts, epochs: np.ndarray) -> Modelled:
    """The front end (`spp.prepare_epoch`) for the epochs `epochs` (indices, ascending) at receiver positions p_rx
    (len(epochs),3) ECEF m (NaN rows: unknown, no atmosphere, no elevation mask)."""
    E = len(tab.t)
    pos = np.full((E, 3), np.nan)
    pos[epochs] = p_rx
    want = np.zeros(E, bool)
    want[epochs] = True
    dual = dual_frequency(tab, opts.iono)
    keep = want[tab.ep] & np.isin(tab.system, list(opts.systems)) & np.isfinite(tab.raw["pr_m"])
    if opts.iono == "iono-free":
        keep &= dual
    idx = np.flatnonzero(keep)
    p, v, clk, drift, ura, ok = (a[idx] for a in tab.satellite_states(nav))
    idx, p, v, clk, drift, ura = idx[ok], p[ok], v[ok], clk[ok], drift[ok], ura[ok]
    ep = tab.ep[idx]
    pr = tab.raw["pr_m"][idx]
    dual = dual[idx]
    known_ep = _known(pos)
    known = known_ep[ep]
    r = pos[ep]
    tau = np.where(known, 0.0, np.clip(pr / C_LIGHT, 0.06, 0.15))
    if known.any():
        k = known
        t = np.linalg.norm(p[k] - r[k], axis=1) / C_LIGHT
        for _ in range(2):
            pr_, _ = sagnac_rotate(p[k], v[k], t)
            t = np.linalg.norm(pr_ - r[k], axis=1) / C_LIGHT
        tau[k] = t
    d = np.where(known[:, None], p - np.nan_to_num(r), p)
    los = d / np.linalg.norm(d, axis=1, keepdims=True)
    tau_dot = np.sum(los * v, axis=1) / C_LIGHT
    p_rot, v_rot = sagnac_rotate(p, v, tau, tau_dot)
    n = len(idx)
    elev, azim = np.full(n, np.pi / 2), np.zeros(n)
    iono, tropo = np.zeros(n), np.zeros(n)
    if known.any():
        geo = np.full((E, 3), np.nan)
        geo[known_ep] = ecef_to_geodetic(pos[known_ep]).reshape(-1, 3)
        k = known
        lat, lon, h = geo[ep[k], 0], geo[ep[k], 1], geo[ep[k], 2]
        u = p_rot[k] - r[k]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        e_enu = np.einsum("nij,nj->ni", R_ecef_to_enu(lat, lon).reshape(-1, 3, 3), u)
        elev[k] = np.arcsin(np.clip(e_enu[:, 2], -1.0, 1.0))
        azim[k] = np.mod(np.arctan2(e_enu[:, 0], e_enu[:, 1]), 2 * np.pi)
        freq = C_LIGHT / tab.raw["wavelength_m"][idx[k]]
        iono[k] = klobuchar_delay_m(tab.t[ep[k]], lat, lon, elev[k], azim[k], nav.ion_gps, freq)
        tropo[k] = saastamoinen_delay_m(lat, h, elev[k], opts.humidity)
    sig = code_sigma_m(elev, opts.code_sigma_zenith_m)
    if dual.any():
        # P_IF = (g P1 - P2) / (g - 1), g = (f1/f2)^2: no first-order ionosphere; the broadcast clock refers to the
        # combination (no group delay); the receiver noise of both codes grows by sqrt(g^2 + 1) / (g - 1)
        wl, wl2, pr2 = tab.raw["wavelength_m"][idx], tab.wl2[idx], tab.pr2[idx]
        g = np.ones(n)
        g[dual] = (wl2[dual] / wl[dual]) ** 2
        pr = np.where(dual, (g * pr - np.nan_to_num(pr2)) / np.where(dual, g - 1.0, 1.0), pr)
        clk = clk + np.where(dual, group_delay_s(nav, sats_of(tab, idx), tab.t[ep]), 0.0)
        iono = np.where(dual, 0.0, iono)
        sig = np.where(dual, sig * np.sqrt(g ** 2 + 1.0) / np.where(dual, g - 1.0, 1.0), sig)
    bias = np.zeros(n)
    if opts.model_errors:
        # default Klobuchar coefficients are not the day's ionosphere: their error is the whole delay
        share = 1.0 if getattr(nav, "ion_source", "") == "default" else KLOBUCHAR_SHARE
        # precise products: `ura` is their accuracy, not a broadcast message's URA
        precise = getattr(nav, "precise", None) is not None
        bias = model_sigma_m(elev, iono, ura, iono_share=share, system=tab.system[idx],
                             orbit_clock_m=ura if precise else None)
        # the ionosphere-free combination amplifies the receiver's and the satellite's code biases that no
        # broadcast message corrects (C1C against C1W, L2C inter-signal, ~1 ns): 2.55 x ~0.4 m
        bias = np.where(dual, np.hypot(bias, IF_CODE_BIAS_M), bias)
        sig = np.hypot(sig, bias)
    out = Modelled(idx, ep, pr, p_rot, v_rot, clk, drift, iono, tropo, np.degrees(elev), np.degrees(azim), sig,
                   code_sigma_m(elev, opts.doppler_sigma_zenith_mps), bias, pos)
    return out.take(~known | (out.elev_deg >= opts.elev_mask_deg))


def sats_of(tab: ObsTable, idx: np.ndarray) -> list:
    """Satellite names of table rows."""
    return tab.sat[idx].tolist()


def to_epoch(tab: ObsTable, m: Modelled, raw: GnssEpoch, e: int, lo: int, hi: int, known: bool | None = None
             ) -> GnssEpoch:
    """The modelled `GnssEpoch` of epoch e from its satellites lo:hi of `m` (the raw epoch gives the time; `known`:
    whether it was modelled at a known position, found out if not given)."""
    i = m.idx[lo:hi]
    if known is None:
        known = bool(_known(m.p_approx[e]))
    return GnssEpoch(
        t_gps=raw.t_gps, sat=tab.sat[i].tolist(), system=tab.system[i], pr_m=m.pr_m[lo:hi],
        doppler_hz=tab.raw["doppler_hz"][i], range_rate_mps=tab.raw["range_rate_mps"][i],
        wavelength_m=tab.raw["wavelength_m"][i], cn0_dbhz=tab.raw["cn0_dbhz"][i], sat_pos_ecef=m.sat_pos[lo:hi],
        sat_vel_ecef=m.sat_vel[lo:hi], sat_clk_s=m.clk[lo:hi], sat_clk_drift=m.drift[lo:hi], iono_m=m.iono[lo:hi],
        tropo_m=m.tropo[lo:hi], elev_deg=m.elev_deg[lo:hi], azim_deg=m.azim_deg[lo:hi], sigma_pr_m=m.sigma_pr[lo:hi],
        sigma_rr_mps=m.sigma_rr[lo:hi],
        p_approx_ecef=m.p_approx[e].copy() if known else np.full(3, np.nan),
        sigma_pr_bias_m=m.sigma_bias[lo:hi], pr2_m=None, wavelength2_m=None)


def _bounds(ep: np.ndarray, E: int) -> np.ndarray:
    """Start of each epoch's rows in an epoch-sorted array (E+1,)."""
    return np.searchsorted(ep, np.arange(E + 1))


def segment_sum(x: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sums of x over the row segments b[e]:b[e+1] (empty segments give 0)."""
    out = np.zeros((len(b) - 1,) + x.shape[1:])
    ne = b[1:] > b[:-1]
    if ne.any() and len(x):
        out[ne] = np.add.reduceat(x, b[:-1][ne], axis=0)
    return out


def _design(m: Modelled, x: np.ndarray, grp: np.ndarray):
    """Geometry rows H (M,NP) and ranges rho (M,) at the epochs' parameters x (E,NP)."""
    d = m.sat_pos - x[m.ep, :3]
    rho = np.linalg.norm(d, axis=1)
    H = np.zeros((len(rho), NP))
    H[:, :3] = -d / rho[:, None]
    H[np.arange(len(rho)), 3 + grp] = 1.0
    return H, rho


def _padding(absent: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Parameters (E,NP) given unit information: the absent clock groups, and all of an epoch without rows."""
    pad = np.concatenate([np.zeros((len(absent), 3), bool), absent], axis=1)
    pad[b[1:] == b[:-1]] = True
    return pad


def normal_inverse(Hw: np.ndarray, b: np.ndarray, absent: np.ndarray) -> np.ndarray:
    """Inverse (E,NP,NP) of each epoch's normal matrix sum(Hw Hw'), unit information on its absent parameters."""
    N = segment_sum(Hw[:, :, None] * Hw[:, None, :], b)
    i = np.arange(NP)
    N[:, i, i] += _padding(absent, b)
    return np.linalg.inv(N)


@dataclass
class PositionFit:
    """Per epoch: parameters x (E,NP), N^-1 of the last iteration (E,NP,NP); per satellite: final rows H (M,NP) and
    residuals (M,) m."""

    x: np.ndarray
    Ninv: np.ndarray
    H: np.ndarray
    res: np.ndarray


def fit_positions(m: Modelled, grp: np.ndarray, y: np.ndarray, x0: np.ndarray, absent: np.ndarray, E: int,
                  iters: int = 10) -> PositionFit:
    """Gauss-Newton of every epoch (spp's `_solve_position`) on corrected pseudoranges y (M,) m of satellites of clock
    groups `grp` (M,): x0 (E,NP) start, each epoch iterated until its step is below 0.1 mm (at most `iters`); the
    returned N^-1 is that of the last step, H and residuals at the end."""
    x = x0.copy()
    Ninv = np.zeros((E, NP, NP))
    active = np.bincount(m.ep, minlength=E) > 0
    rows = np.arange(len(m.ep))
    for _ in range(iters):
        ep_a = np.flatnonzero(active)
        sub = m.take(rows)
        H, rho = _design(sub, x, grp[rows])
        v = y[rows] - (rho + x[sub.ep, 3 + grp[rows]])
        Hw = H / sub.sigma_pr[:, None]
        b = np.searchsorted(sub.ep, ep_a)
        b = np.r_[b, len(rows)]
        Ni = normal_inverse(Hw, b, absent[ep_a])
        dx = np.einsum("eij,ej->ei", Ni, segment_sum(Hw * (v / sub.sigma_pr)[:, None], b))
        x[ep_a] += dx
        Ninv[ep_a] = Ni
        active[ep_a[np.linalg.norm(dx, axis=1) < 1e-4]] = False
        if not active.any():
            break
        rows = rows[active[m.ep[rows]]]
    H, rho = _design(m, x, grp)
    return PositionFit(x, Ninv, H, y - (rho + x[m.ep, 3 + grp]))


def groups(tab: ObsTable, m: Modelled) -> np.ndarray:
    """Clock group index (0 G/J, 1 E, 2 C, 3 R) of each modelled satellite."""
    return tab.group[m.idx]


def dops(H: np.ndarray, b: np.ndarray, absent: np.ndarray, p_ecef: np.ndarray) -> dict:
    """GDOP/PDOP/HDOP/VDOP (E,) of each epoch's line-of-sight rows H (one clock column per present group); inf
    where the geometry is singular."""
    E = len(b) - 1
    N = segment_sum(H[:, :, None] * H[:, None, :], b)
    i = np.arange(NP)
    pad = _padding(absent, b)
    N[:, i, i] += pad
    out = {k: np.full(E, np.inf) for k in ("gdop", "pdop", "hdop", "vdop")}
    Q = np.full((E, NP, NP), np.nan)
    good = np.ones(E, bool)
    try:
        Q = np.linalg.inv(N)
    except np.linalg.LinAlgError:
        for e in range(E):
            try:
                Q[e] = np.linalg.inv(N[e])
            except np.linalg.LinAlgError:
                good[e] = False
    if not good.any():
        return out
    R_ecef_to_enu_ep = R_ecef_to_enu_at(p_ecef[good].reshape(-1, 3))
    Qg = Q[good]
    Qenu = R_ecef_to_enu_ep @ Qg[:, :3, :3] @ np.swapaxes(R_ecef_to_enu_ep, 1, 2)
    tr = np.trace(Qg, axis1=1, axis2=2) - pad[good].sum(axis=1)
    out["gdop"][good] = np.sqrt(tr)
    out["pdop"][good] = np.sqrt(np.trace(Qg[:, :3, :3], axis1=1, axis2=2))
    out["hdop"][good] = np.sqrt(Qenu[:, 0, 0] + Qenu[:, 1, 1])
    out["vdop"][good] = np.sqrt(Qenu[:, 2, 2])
    return out


def fit_velocities(tab: ObsTable, m: Modelled, p: np.ndarray, E: int):
    """Velocity (E,3) m/s ECEF, its covariance (E,3,3), clock drift and its sigma (E,) m/s from the corrected range
    rates of each epoch at positions p (E,3) (spp's `_solve_velocity`: at least 5 Dopplers, up to 3 rounds of 5-sigma
    rejection scaled by the fit's scatter); NaN where too few."""
    has = np.isfinite(tab.raw["range_rate_mps"][m.idx])
    mm = m.take(has)
    b = _bounds(mm.ep, E)
    cnt = np.diff(b)
    ok = cnt >= 5
    vel = np.full((E, 3), np.nan)
    cov = np.full((E, 3, 3), np.nan)
    drift = np.full(E, np.nan)
    dsig = np.full(E, np.nan)
    if not ok.any():
        return vel, cov, drift, dsig
    d = mm.sat_pos - p[mm.ep]
    e = d / np.linalg.norm(d, axis=1, keepdims=True)
    y = mm.rr_corr(tab) - np.sum(e * mm.sat_vel, axis=1)
    H = np.hstack([-e, np.ones((len(y), 1))])
    sig = mm.sigma_rr
    keep = ok[mm.ep].copy()
    going = ok.copy()
    x = np.zeros((E, 4))
    Ninv = np.zeros((E, 4, 4))
    for _ in range(3):
        w = keep & going[mm.ep]
        Hw = H / sig[:, None] * w[:, None]
        N = segment_sum(Hw[:, :, None] * Hw[:, None, :], b)
        N[~going] = np.eye(4)
        Ni = np.linalg.inv(N)
        xx = np.einsum("eij,ej->ei", Ni, segment_sum(Hw * (y / sig)[:, None], b))
        x[going] = xx[going]
        Ninv[going] = Ni[going]
        r = y - np.einsum("ni,ni->n", H, x[mm.ep])
        z2 = segment_sum(np.where(keep, (r / sig) ** 2, 0.0), b)
        nk = segment_sum(keep.astype(float), b)
        s = np.sqrt(np.maximum(z2 / np.maximum(nk - 4, 1), 1.0))
        bad = np.abs(r / sig) > 5.0 * s[mm.ep]
        any_bad = segment_sum((bad & keep).astype(float), b) > 0
        left = segment_sum((keep & ~bad).astype(float), b)
        stop = ~any_bad | (left < 5)
        upd = going & ~stop
        keep &= ~(bad & upd[mm.ep])
        going = upd
        if not going.any():
            break
    vel[ok] = x[ok, :3]
    cov[ok] = Ninv[ok, :3, :3]
    drift[ok] = x[ok, 3]
    dsig[ok] = np.sqrt(Ninv[ok, 3, 3])
    return vel, cov, drift, dsig


@dataclass
class EpochFits:
    """SPP of E epochs: `ok` (E,); position (E,3) and covariance (E,3,3) m, clocks (E,NG) m and sigmas per clock group
    (NaN where absent), velocity, its covariance, drift and sigma (m/s), satellites used, rejected names, DOPs,
    chi-square per degree of freedom; `m` the modelled satellites used (epoch order) with their residuals `res` (m)."""

    ok: np.ndarray
    p: np.ndarray
    cov_p: np.ndarray
    clk: np.ndarray
    clk_sigma: np.ndarray
    v: np.ndarray
    cov_v: np.ndarray
    drift: np.ndarray
    drift_sigma: np.ndarray
    n_sat: np.ndarray
    rejected: list
    dop: dict
    chi2_dof: np.ndarray
    m: Modelled
    res: np.ndarray
    bounds: np.ndarray


def _empty(E: int) -> Modelled:
    z, z3 = np.zeros(0), np.zeros((0, 3))
    return Modelled(np.zeros(0, int), np.zeros(0, int), z, z3, z3, z, z, z, z, z, z, z, z, z, np.full((E, 3), np.nan))


def _concat(parts: list) -> Modelled:
    kw = {k: np.concatenate([getattr(q, k) for q in parts]) for k in parts[0].__dict__ if k != "p_approx"}
    p = parts[0].p_approx.copy()
    for q in parts[1:]:
        have = np.all(np.isfinite(q.p_approx), axis=1)
        p[have] = q.p_approx[have]
    return Modelled(**kw, p_approx=p)


def solve_epochs(tab: ObsTable, nav, guesses: np.ndarray, opts, which: np.ndarray | None = None) -> EpochFits:
    """`spp.solve_epoch` for every epoch of `tab` at once (or the epochs `which`, indices ascending; the others are
    left failed and empty), epoch e starting from guesses[e] (ECEF m; NaN or a point inside the Earth: unknown)."""
    E = len(tab.t)
    has_prep = _known(guesses)
    x_prep = np.where(has_prep[:, None], guesses, 0.0)
    rejected: list = [[] for _ in range(E)]
    fail = np.zeros(E, bool)
    n_sat = np.zeros(E, int)
    X = np.zeros((E, NP))
    NI = np.zeros((E, NP, NP))
    absent_f = np.zeros((E, NG), bool)
    parts: list = []
    res_parts: list = []
    todo = np.arange(E) if which is None else np.asarray(which, int)
    fail[np.setdiff1d(np.arange(E), todo)] = True
    for _outer in range(6):
        if not len(todo):
            break
        m = model(tab, nav, np.where(has_prep[todo, None], x_prep[todo], np.nan), opts, todo)
        p_approx = m.p_approx
        if any(rejected[e] for e in todo):
            m = m.take(np.array([tab.sat[i] not in rejected[e] for i, e in zip(m.idx, m.ep)], bool))
        grp = groups(tab, m)
        alive = np.ones(len(m.idx), bool)
        Hm = np.zeros((len(m.idx), NP))
        resm = np.zeros(len(m.idx))
        absent_r = np.zeros((E, NG), bool)
        in_loop = np.zeros(E, bool)
        in_loop[todo] = True
        while in_loop.any():
            rows = np.flatnonzero(alive & in_loop[m.ep])
            sub, g = m.take(rows), grp[rows]
            cnt = np.bincount(sub.ep, minlength=E)
            present = np.stack([np.bincount(sub.ep[g == j], minlength=E) > 0 for j in range(NG)], axis=1)
            n_par = 3 + present.sum(axis=1)
            few = in_loop & (cnt < n_par)
            fail |= few
            n_sat[few] = cnt[few]
            in_loop &= ~few
            if few.any():
                k = in_loop[sub.ep]
                rows, sub, g = rows[k], sub.take(k), g[k]
            if not in_loop.any():
                break
            x0 = np.zeros((E, NP))
            x0[:, :3] = x_prep
            fit = fit_positions(sub, g, sub.pr_corr(tab), x0, ~present, E)
            b = _bounds(sub.ep, E)
            dof = cnt - n_par
            chi2 = segment_sum((fit.res / sub.sigma_pr) ** 2, b)
            n_rej = np.array([len(r) for r in rejected])
            need = in_loop & opts.raim & has_prep & (dof >= 1) & (n_rej < opts.max_reject) & \
                (chi2 > np.nan_to_num(chi2_limit(dof, opts.raim_alpha), nan=np.inf))
            fin = in_loop & ~need
            X[fin], NI[fin], absent_r[fin] = fit.x[fin], fit.Ninv[fin], ~present[fin]
            k = fin[sub.ep]
            Hm[rows[k]], resm[rows[k]] = fit.H[k], fit.res[k]
            in_loop &= ~fin
            if need.any():
                # Baarda-style: remove the observation with the largest standardised residual
                Qv = sub.sigma_pr ** 2 - np.einsum("ni,nij,nj->n", fit.H, fit.Ninv[sub.ep], fit.H)
                w = np.abs(fit.res) / np.sqrt(np.maximum(Qv, 1e-12))
                for e in np.flatnonzero(need):
                    j = b[e] + int(np.argmax(w[b[e]:b[e + 1]]))
                    rejected[e].append(tab.sat[sub.idx[j]])
                    alive[rows[j]] = False
        ok_r = np.zeros(E, bool)
        ok_r[todo] = True
        ok_r &= ~fail
        moved = np.where(has_prep, np.linalg.norm(X[:, :3] - x_prep, axis=1), np.inf)
        x_prep[ok_r] = X[ok_r, :3]
        has_prep |= ok_r
        absent_f[ok_r] = absent_r[ok_r]
        fin = ok_r & (moved < 20.0)
        last = _outer == 5
        take = (fin | ok_r) if last else fin
        k = alive & take[m.ep]
        if k.any():
            q = m.take(k)
            q.p_approx = p_approx
            parts.append(q)
            res_parts.append(resm[k])
        todo = np.flatnonzero(ok_r & ~fin)
    m = _concat(parts) if parts else _empty(E)
    res = np.concatenate(res_parts) if res_parts else np.zeros(0)
    order = np.argsort(m.ep, kind="stable")
    m, res = m.take(order), res[order]
    b = _bounds(m.ep, E)
    cnt = np.diff(b)
    grp = groups(tab, m)
    H = np.zeros((len(m.idx), NP))
    H[:, :3] = -(m.sat_pos - X[m.ep, :3]) / np.linalg.norm(m.sat_pos - X[m.ep, :3], axis=1, keepdims=True)
    H[np.arange(len(m.idx)), 3 + grp] = 1.0
    ok = ~fail & (cnt > 0)
    dop = dops(H, b, absent_f, np.where(ok[:, None], X[:, :3], 1e7))
    bad_dop = ok & (~np.isfinite(dop["gdop"]) | (dop["gdop"] > opts.max_gdop))
    n_sat[ok] = cnt[ok]
    ok &= ~bad_dop
    for k in dop:
        dop[k][~ok] = np.nan
    v, cov_v, drift, dsig = fit_velocities(tab, m, np.where(ok[:, None], X[:, :3], 1e7), E)
    nsys = (~absent_f).sum(axis=1)
    dof = cnt - 3 - nsys
    chi2 = segment_sum((res / m.sigma_pr) ** 2, b)
    nan = np.full(E, np.nan)
    i3 = np.arange(NG)
    clk = np.where(~absent_f & ok[:, None], X[:, 3:], np.nan)
    clk_sigma = np.where(~absent_f & ok[:, None], np.sqrt(np.abs(NI[:, 3 + i3, 3 + i3])), np.nan)
    return EpochFits(
        ok=ok, p=np.where(ok[:, None], X[:, :3], np.nan), cov_p=np.where(ok[:, None, None], NI[:, :3, :3], np.nan),
        clk=clk, clk_sigma=clk_sigma, v=np.where(ok[:, None], v, np.nan),
        cov_v=np.where(ok[:, None, None], cov_v, np.nan), drift=np.where(ok, drift, nan),
        drift_sigma=np.where(ok, dsig, nan), n_sat=n_sat, rejected=rejected, dop=dop,
        chi2_dof=np.where(ok & (dof > 0), chi2 / np.where(dof > 0, dof, 1), nan), m=m, res=res, bounds=b)


MIN_NOISE_PAIRS = 30   # residual differences below which the data do not tell the receiver's code noise
NOISE_LAG_S = 30.0     # residuals differenced this far apart: past the code's own correlation, within the slow errors'


def code_noise_from_residuals(tab: ObsTable, fits: EpochFits, sigma_zenith_m: float, lag_s: float = NOISE_LAG_S,
                              max_lag_s: float = 120.0) -> tuple[float, int] | None:
    """The receiver's code noise at the zenith (m) told by its own post-fit residuals, and the number of residual
    differences it rests on (None: fewer than `MIN_NOISE_PAIRS`).

    A satellite's residuals `lag_s` apart (the first of its epochs at least that much later, at most `max_lag_s`)
    share its slow errors (broadcast orbit, clock, ionosphere and troposphere change by centimetres in that time):
    their difference is the receiver's noise of the two epochs. Not of consecutive epochs: receivers smooth their
    code (a geodetic Septentrio's 1 s differences show a third of its 30 s ones) and a moving antenna's multipath
    changes over seconds. Each difference is divided by the noise's elevation law of the fit (`code_sigma_m`
    relative to `sigma_zenith_m`, the ionosphere-free combination's factor included); the scale is their RMS within
    five robust sigmas (median absolute deviation) of their median (a multipath jump or a cycle of a tracking loop
    does not count, a heavy tail does), and a residual keeps on average 1 - p/n of its noise's variance (p
    parameters, n satellites), which is given back."""
    m, res = fits.m, fits.res
    n = np.diff(fits.bounds).astype(float)
    p = 3.0 + np.isfinite(fits.clk).sum(axis=1)
    use = (fits.ok & (n - p >= 2))[m.ep]           # residuals of epochs with two or more redundant satellites
    if use.sum() < 2:
        return None
    ep, r = m.ep[use], res[use]
    law = np.sqrt(np.maximum(m.sigma_pr[use] ** 2 - m.sigma_bias[use] ** 2, 0.0)) / sigma_zenith_m
    sat = np.unique(tab.sat[m.idx[use]].astype(str), return_inverse=True)[1]
    t = tab.t[ep] - tab.t[ep].min()
    order = np.lexsort((t, sat))                                   # by satellite, then time
    key = sat[order] * (t.max() + 2.0 * max_lag_s) + t[order]      # one increasing line, satellites apart
    later = np.searchsorted(key, key + lag_s - 1e-3)
    ok = later < len(order)
    a, b = order[ok], order[later[ok]]
    pair = (sat[a] == sat[b]) & (t[b] - t[a] <= max_lag_s)
    a, b = a[pair], b[pair]
    if len(a) < MIN_NOISE_PAIRS:
        return None
    u = (r[b] - r[a]) / np.hypot(law[a], law[b])
    u = np.abs(u - np.median(u))
    rms = np.sqrt(np.mean(u[u <= 5.0 * 1.4826 * np.median(u)] ** 2))
    kept = 1.0 - p / np.maximum(n, p + 2.0)
    return float(rms / np.sqrt(np.mean(0.5 * (kept[ep[a]] + kept[ep[b]])))), int(len(a))


def merge_fits(full: EpochFits, part: EpochFits, which: np.ndarray) -> EpochFits:
    """`full` with the epochs `which` replaced by those of `part` (a `solve_epochs(..., which)` of the same table)."""
    w = np.zeros(len(full.ok), bool)
    w[which] = True
    out = EpochFits(**{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in full.__dict__.items()})
    for k in ("ok", "p", "cov_p", "clk", "clk_sigma", "v", "cov_v", "drift", "drift_sigma", "n_sat", "chi2_dof"):
        getattr(out, k)[w] = getattr(part, k)[w]
    out.dop = {k: np.where(w, part.dop[k], full.dop[k]) for k in full.dop}
    out.rejected = [part.rejected[e] if w[e] else full.rejected[e] for e in range(len(w))]
    keep = ~w[full.m.ep]
    add = w[part.m.ep]
    m = _concat([full.m.take(keep), part.m.take(add)])
    m.p_approx = np.where(w[:, None], part.m.p_approx, full.m.p_approx)
    res = np.concatenate([full.res[keep], part.res[add]])
    order = np.argsort(m.ep, kind="stable")
    out.m, out.res = m.take(order), res[order]
    out.bounds = _bounds(out.m.ep, len(w))
    return out
