"""Single-point positioning: front-end preparation of epochs and per-epoch weighted least squares.

``prepare_epoch`` turns a raw epoch (pseudoranges, Doppler) into a fully modelled one
(satellite states rotated for Sagnac, Klobuchar/Saastamoinen delays, elevation mask, sigmas;
see ``dgcal.pos.gnss.observations`` for the exact meaning). ``spp`` solves position + one receiver clock
bias per constellation by Gauss-Newton WLS with elevation weights and RAIM-style rejection
(global chi-square test, then the largest standardised residual is removed), and velocity +
clock drift from Doppler. Clock biases are reported in metres (c * dt).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.special import chdtri  # scipy.stats would cost seconds of import time
from tqdm import tqdm

from dgcal.fields.constants import C_LIGHT
from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.fields.io.csv_tables import write_table
from dgcal.pos.gnss.ephemeris import group_delay_s, states_at_transmission
from dgcal.pos.gnss.corrections import (code_sigma_m, elevation_azimuth, klobuchar_delay_m, model_sigma_m,
                                  sagnac_rotate, saastamoinen_delay_m)
from dgcal.pos.gnss.observations import CLOCK_GROUP, SYSTEMS, GnssEpoch, GnssObservations, split_gps_time
from dgcal.pos.gnss.rinex import BroadcastNav, read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file


@dataclass
class SppOptions:
    """Settings of the front end and SPP.

    ``code_sigma_zenith_m``/``doppler_sigma_zenith_mps``: measurement noise at the zenith
    (elevation scaled by ``code_sigma_m``); ``model_errors``: add the broadcast-model error
    budget (iono, tropo, URA) to the code sigma (True for real data; False for simulated data
    built with the same models); ``raim_alpha``: false-alarm probability of the chi-square test. ``iono``: ``auto``
    uses the dual-frequency ionosphere-free code combination for every GPS, QZSS and Galileo satellite with a
    second code (``GnssEpoch.pr2_m``) and Klobuchar for the others, ``klobuchar`` the first code only,
    ``iono-free`` only satellites with two codes.
    """

    elev_mask_deg: float = 10.0
    code_sigma_zenith_m: float = 0.3
    doppler_sigma_zenith_mps: float = 0.1
    model_errors: bool = True
    systems: tuple[str, ...] = SYSTEMS
    raim: bool = True
    raim_alpha: float = 1e-3
    max_reject: int = 3
    max_gdop: float = 30.0
    humidity: float = 0.7
    iono: str = "klobuchar"  # klobuchar (first code); auto (ionosphere-free where there is a second code); iono-free


IF_CODE_BIAS_M = 1.0   # sigma (m) of the uncorrected code biases in the ionosphere-free combination


def _has_position(p) -> bool:
    return p is not None and np.all(np.isfinite(p)) and np.linalg.norm(p) > 6.0e6


def prepare_epoch(raw: GnssEpoch, nav: BroadcastNav, p_rx_ecef: np.ndarray | None,
                  opts: SppOptions | None = None) -> GnssEpoch:
    """Model one raw epoch at the approximate receiver position ``p_rx_ecef`` (m, ECEF; None: unknown).

    Drops satellites without valid healthy ephemeris, of unwanted systems, or (when the position
    is known) below the elevation mask. Without a position the travel time is taken from the
    pseudorange and no atmosphere is modelled (a first pass for SPP).
    """
    if opts is None:
        opts = SppOptions()
    keep = np.isin(raw.system, list(opts.systems)) & np.isfinite(raw.pr_m)
    dual = _dual_frequency(raw, opts.iono)
    if opts.iono == "iono-free":
        keep &= dual
    ep = raw.subset(keep)
    dual = dual[keep]
    p, v, clk, drift, ura, ok = states_at_transmission(nav, ep.sat, ep.t_gps, ep.pr_m)
    ep = ep.subset(ok)
    p, v, clk, drift, ura, dual = p[ok], v[ok], clk[ok], drift[ok], ura[ok], dual[ok]
    known = _has_position(p_rx_ecef)
    if known:
        tau = np.linalg.norm(p - p_rx_ecef, axis=1) / C_LIGHT
        for _ in range(2):
            pr_, _ = sagnac_rotate(p, v, tau)
            tau = np.linalg.norm(pr_ - p_rx_ecef, axis=1) / C_LIGHT
        los = (p - p_rx_ecef) / np.linalg.norm(p - p_rx_ecef, axis=1, keepdims=True)
    else:
        tau = np.clip(ep.pr_m / C_LIGHT, 0.06, 0.15)
        los = p / np.linalg.norm(p, axis=1, keepdims=True)
    tau_dot = np.sum(los * v, axis=1) / C_LIGHT
    p_rot, v_rot = sagnac_rotate(p, v, tau, tau_dot)
    n = ep.n
    if known:
        lat, lon, h = ecef_to_geodetic(p_rx_ecef)
        elev, azim = elevation_azimuth(p_rx_ecef, p_rot, (lat, lon))
        freq = C_LIGHT / ep.wavelength_m
        ion = nav.ion_gps
        iono = klobuchar_delay_m(ep.t_gps, lat, lon, elev, azim, ion, freq)
        tropo = saastamoinen_delay_m(lat, h, elev, opts.humidity)
    else:
        elev, azim = np.full(n, np.pi / 2), np.zeros(n)
        iono, tropo = np.zeros(n), np.zeros(n)
    sig = code_sigma_m(elev, opts.code_sigma_zenith_m)
    if dual.any():
        # P_IF = (g P1 - P2) / (g - 1), g = (f1/f2)^2: no first-order ionosphere; the broadcast clock refers to the
        # combination (no group delay); the receiver noise of both codes grows by sqrt(g^2 + 1) / (g - 1)
        g = np.ones(n)
        g[dual] = (ep.wavelength2_m[dual] / ep.wavelength_m[dual]) ** 2
        ep.pr_m = np.where(dual, (g * ep.pr_m - np.nan_to_num(ep.pr2_m)) / np.where(dual, g - 1.0, 1.0), ep.pr_m)
        clk = clk + np.where(dual, group_delay_s(nav, ep.sat, ep.t_gps), 0.0)
        iono = np.where(dual, 0.0, iono)
        sig = np.where(dual, sig * np.sqrt(g ** 2 + 1.0) / np.where(dual, g - 1.0, 1.0), sig)
    bias = np.zeros(n)
    if opts.model_errors:
        # default Klobuchar coefficients are not the day's ionosphere: their error is the whole delay, not half
        share = 1.0 if getattr(nav, "ion_source", "") == "default" else 0.5
        bias = model_sigma_m(elev, iono, ura, iono_share=share)
        # the ionosphere-free combination amplifies the receiver's and the satellite's code biases that no
        # broadcast message corrects (C1C against C1W, L2C inter-signal, ~1 ns): 2.55 x ~0.4 m
        bias = np.where(dual, np.hypot(bias, IF_CODE_BIAS_M), bias)
        sig = np.hypot(sig, bias)
    ep.sigma_pr_bias_m = bias
    ep.pr2_m = ep.wavelength2_m = None
    ep.sat_pos_ecef, ep.sat_vel_ecef = p_rot, v_rot
    ep.sat_clk_s, ep.sat_clk_drift = clk, drift
    ep.iono_m, ep.tropo_m = iono, tropo
    ep.elev_deg, ep.azim_deg = np.degrees(elev), np.degrees(azim)
    ep.sigma_pr_m = sig
    ep.sigma_rr_mps = code_sigma_m(elev, opts.doppler_sigma_zenith_mps)
    ep.p_approx_ecef = np.asarray(p_rx_ecef, float) if known else np.full(3, np.nan)
    if known:
        ep = ep.subset(ep.elev_deg >= opts.elev_mask_deg)
    return ep


def _dual_frequency(ep: GnssEpoch, mode: str) -> np.ndarray:
    """Satellites of a raw epoch whose ionosphere-free combination the front end uses (GPS, QZSS, Galileo with
    a second code), under the `SppOptions.iono` mode."""
    if mode not in ("auto", "klobuchar", "iono-free"):
        raise ValueError(f"iono must be auto, klobuchar or iono-free, not {mode!r}")
    if mode == "klobuchar" or ep.pr2_m is None:
        return np.zeros(ep.n, bool)
    return np.isfinite(ep.pr2_m) & np.isfinite(ep.wavelength2_m) & np.isin(ep.system, ["G", "J", "E"])


@dataclass
class EpochSolution:
    """SPP result of one epoch: position/velocity (ECEF), clocks (m, m/s), covariances, DOP."""

    t_gps: float
    ok: bool
    p_ecef: np.ndarray
    cov_p: np.ndarray
    clk_m: dict[str, float]
    clk_sigma_m: dict[str, float]
    v_ecef: np.ndarray
    cov_v: np.ndarray
    drift_mps: float
    drift_sigma_mps: float
    n_sat: int
    used: list[str]
    rejected: list[str]
    dop: dict[str, float]
    chi2_dof: float
    residuals_m: dict[str, float] = field(default_factory=dict)
    epoch: GnssEpoch | None = None


def _wls(H: np.ndarray, y: np.ndarray, sigma: np.ndarray):
    """Weighted LS step: returns (dx, N^-1)."""
    Hw = H / sigma[:, None]
    yw = y / sigma
    N = Hw.T @ Hw
    Ninv = np.linalg.inv(N)
    return Ninv @ (Hw.T @ yw), Ninv


def _solve_position(ep: GnssEpoch, x0: np.ndarray, systems: list[str], iters: int = 10):
    """Gauss-Newton for [x, y, z, clk per clock group] (m) on the corrected pseudoranges."""
    x = x0.copy()
    y_obs = ep.pr_corr_m
    sys_col = np.array([systems.index(s) for s in ep.clock_group])
    Ninv = None
    for _ in range(iters):
        d = ep.sat_pos_ecef - x[:3]
        rho = np.linalg.norm(d, axis=1)
        e = d / rho[:, None]
        H = np.zeros((ep.n, 3 + len(systems)))
        H[:, :3] = -e
        H[np.arange(ep.n), 3 + sys_col] = 1.0
        v = y_obs - (rho + x[3 + sys_col])
        dx, Ninv = _wls(H, v, ep.sigma_pr_m)
        x += dx
        if np.linalg.norm(dx) < 1e-4:
            break
    d = ep.sat_pos_ecef - x[:3]
    rho = np.linalg.norm(d, axis=1)
    H = np.zeros((ep.n, 3 + len(systems)))
    H[:, :3] = -d / rho[:, None]
    H[np.arange(ep.n), 3 + sys_col] = 1.0
    res = y_obs - (rho + x[3 + sys_col])
    return x, Ninv, H, res


def _dops(H_geom: np.ndarray, p_ecef: np.ndarray) -> dict[str, float]:
    """GDOP/PDOP/HDOP/VDOP of the line-of-sight geometry (one clock column per system)."""
    try:
        Q = np.linalg.inv(H_geom.T @ H_geom)
    except np.linalg.LinAlgError:
        return {k: np.inf for k in ("gdop", "pdop", "hdop", "vdop")}
    lat, lon, _ = ecef_to_geodetic(p_ecef)
    R = R_ecef_to_enu(lat, lon)
    Qenu = R @ Q[:3, :3] @ R.T
    return {"gdop": float(np.sqrt(np.trace(Q))), "pdop": float(np.sqrt(np.trace(Q[:3, :3]))),
            "hdop": float(np.sqrt(Qenu[0, 0] + Qenu[1, 1])), "vdop": float(np.sqrt(Qenu[2, 2]))}


def _chi2_limit(dof: int, alpha: float) -> float:
    return float(chdtri(dof, alpha))


def solve_epoch(raw: GnssEpoch, nav: BroadcastNav, p_guess: np.ndarray | None,
                opts: SppOptions | None = None) -> EpochSolution:
    """SPP of one raw epoch: position, per-system clocks, velocity, drift, covariances, DOP."""
    if opts is None:
        opts = SppOptions()
    x_prep = np.asarray(p_guess, float) if _has_position(p_guess) else None
    rejected: list[str] = []
    fail = EpochSolution(raw.t_gps, False, np.full(3, np.nan), np.full((3, 3), np.nan), {}, {},
                         np.full(3, np.nan), np.full((3, 3), np.nan), np.nan, np.nan, 0, [], [],
                         {}, np.nan)
    for _outer in range(6):
        ep = prepare_epoch(raw, nav, x_prep, opts)
        if rejected:
            ep = ep.subset(~np.isin(ep.sat, rejected))
        while True:
            systems = [s for s in SYSTEMS if s in set(ep.clock_group)]
            n_par = 3 + len(systems)
            if ep.n < n_par:
                fail.rejected = rejected
                fail.n_sat = ep.n
                return fail
            x0 = np.zeros(n_par)
            x0[:3] = x_prep if x_prep is not None else 0.0
            x, Ninv, H, res = _solve_position(ep, x0, systems)
            dof = ep.n - n_par
            chi2 = float(np.sum((res / ep.sigma_pr_m) ** 2))
            if not (opts.raim and x_prep is not None and dof >= 1 and len(rejected) < opts.max_reject
                    and chi2 > _chi2_limit(dof, opts.raim_alpha)):
                break
            # Baarda-style: remove the observation with the largest standardised residual
            W = 1.0 / ep.sigma_pr_m ** 2
            Qv = 1.0 / W - np.einsum("ij,jk,ik->i", H, Ninv, H)
            w = np.abs(res) / np.sqrt(np.maximum(Qv, 1e-12))
            worst = int(np.argmax(w))
            rejected.append(ep.sat[worst])
            ep = ep.subset(np.arange(ep.n) != worst)
        moved = np.inf if x_prep is None else np.linalg.norm(x[:3] - x_prep)
        x_prep = x[:3].copy()
        if moved < 20.0:
            break
    systems = [s for s in SYSTEMS if s in set(ep.clock_group)]
    H_geom = H.copy()
    dop = _dops(H_geom, x[:3])
    if not np.isfinite(dop["gdop"]) or dop["gdop"] > opts.max_gdop:
        fail.rejected, fail.n_sat = rejected, ep.n
        return fail
    dof = ep.n - (3 + len(systems))
    v, cov_v, drift, drift_sig = _solve_velocity(ep, x[:3])
    return EpochSolution(
        t_gps=raw.t_gps, ok=True, p_ecef=x[:3], cov_p=Ninv[:3, :3],
        clk_m={s: float(x[3 + k]) for k, s in enumerate(systems)},
        clk_sigma_m={s: float(np.sqrt(Ninv[3 + k, 3 + k])) for k, s in enumerate(systems)},
        v_ecef=v, cov_v=cov_v, drift_mps=drift, drift_sigma_mps=drift_sig, n_sat=ep.n,
        used=list(ep.sat), rejected=rejected, dop=dop,
        chi2_dof=float(np.sum((res / ep.sigma_pr_m) ** 2) / dof) if dof > 0 else np.nan,
        residuals_m=dict(zip(ep.sat, res.tolist())), epoch=ep)


def _solve_velocity(ep: GnssEpoch, p_ecef: np.ndarray):
    """Velocity (m/s, ECEF) and clock drift (m/s) from corrected range rates; NaN if too few."""
    m = ep.has_doppler
    nan3 = np.full(3, np.nan)
    if m.sum() < 5:
        return nan3, np.full((3, 3), np.nan), np.nan, np.nan
    d = ep.sat_pos_ecef[m] - p_ecef
    e = d / np.linalg.norm(d, axis=1, keepdims=True)
    # rr_corr = e.(v_sat - v_rx) + drift  ->  rr_corr - e.v_sat = -e.v_rx + drift
    y = ep.rr_corr_mps[m] - np.sum(e * ep.sat_vel_ecef[m], axis=1)
    H = np.hstack([-e, np.ones((len(y), 1))])
    sig = ep.sigma_rr_mps[m]
    keep = np.ones(len(y), dtype=bool)
    for _ in range(3):
        x, Ninv = _wls(H[keep], y[keep], sig[keep])
        r = y - H @ x
        # drop gross Doppler errors (5 sigma scaled by the fit's own scatter)
        s = np.sqrt(max(np.sum((r[keep] / sig[keep]) ** 2) / max(keep.sum() - 4, 1), 1.0))
        bad = np.abs(r / sig) > 5.0 * s
        if not np.any(bad & keep) or (keep & ~bad).sum() < 5:
            break
        keep &= ~bad
    return x[:3], Ninv[:3, :3], float(x[3]), float(np.sqrt(Ninv[3, 3]))


@dataclass
class SppSolution:
    """Per-epoch SPP results (arrays of length N) plus the modelled epochs for later use."""

    t_gps: np.ndarray
    ok: np.ndarray
    p_ecef: np.ndarray
    cov_p: np.ndarray
    v_ecef: np.ndarray
    cov_v: np.ndarray
    clk_m: dict[str, np.ndarray]
    clk_sigma_m: dict[str, np.ndarray]
    drift_mps: np.ndarray
    drift_sigma_mps: np.ndarray
    n_sat: np.ndarray
    dop: dict[str, np.ndarray]
    chi2_dof: np.ndarray
    used: list[list[str]]
    rejected: list[list[str]]
    epochs: list[GnssEpoch | None]
    residuals_m: list[dict[str, float]] = field(default_factory=list)


def spp(obs: GnssObservations, nav: BroadcastNav, opts: SppOptions | None = None,
        progress: bool = False) -> SppSolution:
    """SPP of every epoch; each epoch starts from the previous solution (or the header position)."""
    if opts is None:
        opts = SppOptions()
    sols = []
    guess = obs.p_approx_ecef if _has_position(obs.p_approx_ecef) else None
    it = obs.epochs
    if progress:
        it = tqdm(it, desc="SPP", unit="epoch", leave=False)
    for raw in it:
        s = solve_epoch(raw, nav, guess, opts)
        if s.ok:
            guess = s.p_ecef
        sols.append(s)
    return collect(sols, sorted({CLOCK_GROUP[s] for s in obs.systems}, key=SYSTEMS.index))


def collect(sols: list[EpochSolution], systems: list[str]) -> SppSolution:
    """Stack per-epoch solutions into arrays (NaN where an epoch failed or lacks a system)."""
    n = len(sols)
    arr = lambda f: np.array([f(s) for s in sols], dtype=float)  # noqa: E731
    return SppSolution(
        t_gps=arr(lambda s: s.t_gps), ok=np.array([s.ok for s in sols], dtype=bool),
        p_ecef=arr(lambda s: s.p_ecef).reshape(n, 3), cov_p=arr(lambda s: s.cov_p).reshape(n, 3, 3),
        v_ecef=arr(lambda s: s.v_ecef).reshape(n, 3), cov_v=arr(lambda s: s.cov_v).reshape(n, 3, 3),
        clk_m={k: arr(lambda s, k=k: s.clk_m.get(k, np.nan)) for k in systems},
        clk_sigma_m={k: arr(lambda s, k=k: s.clk_sigma_m.get(k, np.nan)) for k in systems},
        drift_mps=arr(lambda s: s.drift_mps), drift_sigma_mps=arr(lambda s: s.drift_sigma_mps),
        n_sat=np.array([s.n_sat for s in sols], dtype=int),
        dop={k: arr(lambda s, k=k: s.dop.get(k, np.nan)) for k in ("gdop", "pdop", "hdop", "vdop")},
        chi2_dof=arr(lambda s: s.chi2_dof), used=[s.used for s in sols],
        rejected=[s.rejected for s in sols], epochs=[s.epoch for s in sols],
        residuals_m=[s.residuals_m for s in sols])


@dataclass
class SppRun:
    """`dgcal pos --mode spp`: the SPP solution of every epoch, its summary and the reference position (m)."""

    solution: SppSolution
    summary: dict
    reference_ecef: np.ndarray | None = None


def spp_files(obs_path: str | Path | None, nav_paths: Sequence[str | Path], opts: SppOptions,
              t_start: float | None = None, t_end: float | None = None,
              reference_ecef: Sequence[float] | None = None, progress: bool = False) -> SppRun:
    """`dgcal pos --mode spp` on files: read the RINEX observations (epochs in [t_start, t_end], continuous GPS s)
    and navigation files, position every epoch and summarise (RINEX record problems in the summary's
    `integrity.rinex` and `warnings`; the 3D RMS against `reference_ecef` (ECEF m) when given).

    Only the GNSS modules are imported: this is what the command runs, in well under a second for an hour of
    1 Hz data (the GNSS/INS pipeline's imports alone take longer)."""
    for name, val in (("rinex-obs", obs_path), ("rinex-nav", nav_paths)):
        if not val:
            raise InputError("required for --mode spp", field="--" + name)
    nav = read_rinex_nav(nav_paths[0], list(nav_paths[1:]))
    rx = read_obs_file(obs_path, t_start=t_start, t_end=t_end)
    obs = read_rinex_obs(obs_path, systems=opts.systems, rinex=rx)
    sol = spp(obs, nav, opts, progress=progress)
    if not sol.ok.any():
        raise InputError("no epoch could be positioned (too few satellites with ephemeris?)", obs_path)
    summary = spp_summary(sol, obs, nav, opts)
    if rx.warnings:
        summary.setdefault("integrity", {}).setdefault("rinex", []).extend(rx.warnings)
        summary.setdefault("warnings", []).extend(rx.warnings)
    ref = None
    if reference_ecef is not None:
        ref = np.asarray(reference_ecef, float)
        err = sol.p_ecef[sol.ok] - ref
        summary["rms_3d_vs_reference_m"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    return SppRun(sol, summary, ref)


def load_gnss(obs_path, nav_path, opts: SppOptions | None = None, progress: bool = False
              ) -> tuple[GnssObservations, SppSolution]:
    """Read RINEX obs + nav, run SPP, and return the epochs modelled at the SPP positions.

    The returned ``GnssObservations`` holds, for every epoch with an SPP fix, the satellites
    used by SPP (mask applied, RAIM rejections removed) with all front-end fields filled.
    This is the input a tightly coupled smoother needs.
    """
    if opts is None:
        opts = SppOptions()
    nav = read_rinex_nav(nav_path)
    raw = read_rinex_obs(obs_path, systems=opts.systems)
    sol = spp(raw, nav, opts, progress=progress)
    epochs = [e for e, ok in zip(sol.epochs, sol.ok) if ok and e is not None]
    good = sol.p_ecef[sol.ok]
    p0 = np.median(good, axis=0) if len(good) else raw.p_approx_ecef
    return GnssObservations(epochs=epochs, receiver=raw.receiver, p_approx_ecef=p0,
                            signals=raw.signals, source=raw.source), sol


GNSS_CSV_COLUMNS = ["gps_week", "gps_sow", "x", "y", "z", "vx", "vy", "vz", "sx", "sy", "sz",
                    "svx", "svy", "svz", "lat", "lon", "h", "s_e", "s_n", "s_u",
                    "clk_G_m", "clk_E_m", "clk_C_m", "drift_mps", "n_sat",
                    "gdop", "pdop", "hdop", "vdop", "chi2_dof", "rejected"]


def enu_sigmas(p_ecef: np.ndarray, cov_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geodetic (lat, lon deg, h m) of ECEF points (N,3) and their E/N/U sigmas (N,3) in metres."""
    llh = ecef_to_geodetic(p_ecef)
    R = R_ecef_to_enu(llh[:, 0], llh[:, 1]).reshape(-1, 3, 3)
    cov_enu = R @ cov_p @ np.swapaxes(R, 1, 2)
    return llh, np.sqrt(np.maximum(np.diagonal(cov_enu, axis1=1, axis2=2), 0.0))


def write_gnss_csv(path, sol: SppSolution) -> None:
    """Write the epochs with a fix as gnss.csv (columns ``GNSS_CSV_COLUMNS``, see docs/gnss.md)."""
    k = np.nonzero(sol.ok)[0]
    week, sow = split_gps_time(sol.t_gps[k])
    sp = np.sqrt(np.diagonal(sol.cov_p[k], axis1=1, axis2=2))
    sv = np.sqrt(np.diagonal(sol.cov_v[k], axis1=1, axis2=2))
    llh, senu = enu_sigmas(sol.p_ecef[k], sol.cov_p[k])
    nan = np.full(len(k), np.nan)
    clk = {g: sol.clk_m.get(g, nan)[k] if g in sol.clk_m else nan for g in ("G", "E", "C")}
    rows = []
    for j, i in enumerate(k):
        rows.append([int(week[j]), float(sow[j]), *sol.p_ecef[i].tolist(), *sol.v_ecef[i].tolist(),
                     *sp[j].tolist(), *sv[j].tolist(), *llh[j].tolist(), *senu[j].tolist(),
                     float(clk["G"][j]), float(clk["E"][j]), float(clk["C"][j]),
                     float(sol.drift_mps[i]), int(sol.n_sat[i]),
                     *(float(sol.dop[d][i]) for d in ("gdop", "pdop", "hdop", "vdop")),
                     float(sol.chi2_dof[i]), ";".join(sol.rejected[i])])
    write_table(path, GNSS_CSV_COLUMNS, rows, fmt="%.12g")


def spp_summary(sol: SppSolution, obs: GnssObservations, nav: BroadcastNav,
                opts: SppOptions) -> dict:
    """Numbers for gnss_summary.json: counts, median position, sigmas, DOP, rejections."""
    ok = sol.ok
    p = sol.p_ecef[ok]
    s3 = np.sqrt(np.trace(sol.cov_p[ok], axis1=1, axis2=2))
    llh, senu = enu_sigmas(p, sol.cov_p[ok])
    return {
        "rinex_obs": obs.source, "rinex_nav": nav.source, "signals": obs.signals,
        "n_epochs": int(len(sol.ok)), "n_fixed": int(ok.sum()),
        "median_ecef_m": np.median(p, axis=0).tolist(),
        "scatter_enu_m": (np.std(llh[:, :2] - np.median(llh[:, :2], axis=0), axis=0) *
                          np.array([111320.0, 111320.0 * np.cos(np.radians(np.median(llh[:, 0])))])
                          ).tolist()[::-1] + [float(np.std(llh[:, 2]))],
        "median_sigma_enu_m": np.median(senu, axis=0).tolist(),
        "median_sigma_3d_m": float(np.median(s3)),
        "mean_n_sat": float(sol.n_sat[ok].mean()), "median_pdop": float(np.median(sol.dop["pdop"][ok])),
        "n_rejected": int(sum(len(r) for r in sol.rejected)),
        "ionosphere_model": getattr(nav, "ion_source", "GPSA/GPSB"),
        "ionosphere": opts.iono,
        "warnings": list(getattr(nav, "warnings", [])),
        "options": {"elev_mask_deg": opts.elev_mask_deg, "code_sigma_zenith_m": opts.code_sigma_zenith_m,
                    "doppler_sigma_zenith_mps": opts.doppler_sigma_zenith_mps,
                    "systems": list(opts.systems), "raim": opts.raim},
    }
