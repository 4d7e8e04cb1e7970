"""Single-point positioning: front-end preparation of epochs and per-epoch weighted least squares.

``prepare_epoch`` turns a raw epoch (pseudoranges, Doppler) into a fully modelled one
(satellite states rotated for Sagnac, Klobuchar/Saastamoinen delays, elevation mask, sigmas;
see ``dgcal.pos.gnss.observations`` for the exact meaning). ``solve_epoch`` solves position + one receiver clock
bias per constellation by Gauss-Newton WLS with elevation weights and RAIM-style rejection
(global chi-square test, then the largest standardised residual is removed), and velocity +
clock drift from Doppler. Clock biases are reported in metres (c * dt). ``spp`` does it for every epoch, each
starting from the previous epoch's solution; the work runs on all epochs at once (`dgcal.pos.gnss.spp_batch`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from dgcal.fields.crs import ecef_to_geodetic
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.fields.io.csv_tables import write_table
from dgcal.pos.gnss.observations import CLOCK_GROUP, SYSTEMS, GnssEpoch, GnssObservations, split_gps_time
from dgcal.pos.gnss.spp_batch import (GROUPS, NG, ObsTable, code_noise_from_residuals, merge_fits, model, solve_epochs,
                                      to_epoch)
from dgcal.pos.gnss.rinex import BroadcastNav, read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.spp_error_model import covariance, iono_error_field
from dgcal.pos.gnss.rinex_obs import read_obs_file


@dataclass
class SppOptions:
    """Settings of the front end and SPP.

    ``code_sigma_zenith_m``/``doppler_sigma_zenith_mps``: measurement noise at the zenith
    (elevation scaled by ``code_sigma_m``); ``code_sigma_from_data``: on real data (``model_errors``) `spp`
    estimates the receiver's code noise at the zenith from the file's own post-fit residuals
    (`dgcal.pos.gnss.spp_batch.code_noise_from_residuals`: a first round with ``code_sigma_zenith_m``, then every
    epoch again with the estimate); the given value stays when the data are too few, for simulated data (their
    noise is what was given) and for a single epoch (`solve_epoch`); ``model_errors``: add the broadcast-model error
    budget (`dgcal.pos.gnss.corrections.model_sigma_m`: Klobuchar, troposphere, orbit and clock) to the code sigma
    (True for real data; False for simulated data built with the same models); ``raim_alpha``: false-alarm
    probability of the chi-square test. ``iono``: ``auto``
    uses the dual-frequency ionosphere-free code combination for every GPS, QZSS and Galileo satellite with a
    second code (``GnssEpoch.pr2_m``) and Klobuchar for the others, ``klobuchar`` the first code only,
    ``iono-free`` only satellites with two codes. ``systems``: the constellations used, letters of
    ``ALL_SYSTEMS`` (GLONASS 'R' only when named: its own receiver clock, FDMA frequencies per satellite).
    """

    elev_mask_deg: float = 10.0
    code_sigma_zenith_m: float = 0.3
    code_sigma_from_data: bool = True
    doppler_sigma_zenith_mps: float = 0.1
    model_errors: bool = True
    systems: tuple[str, ...] = SYSTEMS
    raim: bool = True
    raim_alpha: float = 1e-3
    max_reject: int = 3
    max_gdop: float = 30.0
    humidity: float = 0.7
    iono: str = "klobuchar"  # klobuchar (first code); auto (ionosphere-free where there is a second code); iono-free


def _has_position(p) -> bool:
    return p is not None and np.all(np.isfinite(p)) and np.linalg.norm(p) > 6.0e6


def prepare_epoch(raw: GnssEpoch, nav: BroadcastNav, p_rx_ecef: np.ndarray | None,
                  opts: SppOptions | None = None) -> GnssEpoch:
    """Model one raw epoch at the approximate receiver position ``p_rx_ecef`` (m, ECEF; None: unknown).

    Drops satellites without valid healthy ephemeris, of unwanted systems, or (when the position
    is known) below the elevation mask. Without a position the travel time is taken from the
    pseudorange and no atmosphere is modelled (a first pass for SPP).
    """
    return prepare_epochs([raw], nav, None if not _has_position(p_rx_ecef) else np.asarray(p_rx_ecef, float)[None],
                          opts)[0]


def prepare_epochs(raws: list[GnssEpoch], nav: BroadcastNav, p_rx_ecef: np.ndarray | None,
                   opts: SppOptions | None = None) -> list[GnssEpoch]:
    """`prepare_epoch` of many raw epochs at once, epoch e at p_rx_ecef[e] (ECEF m, (E,3); NaN rows or None:
    unknown)."""
    opts = opts or SppOptions()
    tab = ObsTable.from_epochs(raws)
    E = len(raws)
    p = np.full((E, 3), np.nan) if p_rx_ecef is None else np.asarray(p_rx_ecef, float).reshape(E, 3)
    m = model(tab, nav, p, opts, np.arange(E))
    b = np.searchsorted(m.ep, np.arange(E + 1))
    return [to_epoch(tab, m, raws[e], e, b[e], b[e + 1]) for e in range(E)]


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


def solve_epoch(raw: GnssEpoch, nav: BroadcastNav, p_guess: np.ndarray | None,
                opts: SppOptions | None = None) -> EpochSolution:
    """SPP of one raw epoch: position, per-system clocks, velocity, drift, covariances, DOP.

    The front end models the epoch at the guess (unknown: no atmosphere, see `prepare_epoch`); Gauss-Newton
    weighted least squares gives position and clocks; while the chi-square test fails (RAIM, with a position)
    the satellite of the largest standardised residual goes (at most `max_reject`); when the solution moved
    20 m or more from where the epoch was modelled, it is modelled again there (at most 6 times). Fewer
    satellites than parameters, or a GDOP beyond `max_gdop`, fail the epoch."""
    opts = opts or SppOptions()
    tab = ObsTable.from_epochs([raw])
    g = np.asarray(p_guess, float)[None] if _has_position(p_guess) else np.full((1, 3), np.nan)
    fits = solve_epochs(tab, nav, g, opts)
    b = fits.bounds
    if not fits.ok[0]:
        return EpochSolution(raw.t_gps, False, np.full(3, np.nan), np.full((3, 3), np.nan), {}, {},
                             np.full(3, np.nan), np.full((3, 3), np.nan), np.nan, np.nan, int(fits.n_sat[0]), [],
                             list(fits.rejected[0]), {}, np.nan)
    ep = to_epoch(tab, fits.m, raw, 0, b[0], b[1])
    have = [j for j in range(NG) if np.isfinite(fits.clk[0, j])]
    return EpochSolution(
        t_gps=raw.t_gps, ok=True, p_ecef=fits.p[0], cov_p=fits.cov_p[0],
        clk_m={GROUPS[j]: float(fits.clk[0, j]) for j in have},
        clk_sigma_m={GROUPS[j]: float(fits.clk_sigma[0, j]) for j in have},
        v_ecef=fits.v[0], cov_v=fits.cov_v[0], drift_mps=float(fits.drift[0]),
        drift_sigma_mps=float(fits.drift_sigma[0]), n_sat=int(fits.n_sat[0]), used=list(ep.sat),
        rejected=list(fits.rejected[0]), dop={k: float(v[0]) for k, v in fits.dop.items()},
        chi2_dof=float(fits.chi2_dof[0]), residuals_m=dict(zip(ep.sat, fits.res[b[0]:b[1]].tolist())), epoch=ep)


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
    options: SppOptions | None = None                 # the options the epochs were solved with
    code_noise: dict = field(default_factory=dict)    # the code noise at the zenith: given or estimated, and from what
    error_model: dict = field(default_factory=dict)   # which model the covariances come from (`spp_error_model`)


def spp(obs: GnssObservations, nav: BroadcastNav, opts: SppOptions | None = None,
        progress: bool = False) -> SppSolution:
    """SPP of every epoch (`solve_epoch`); each epoch starts from the previous epoch's solution (or the header
    position before the first).

    All epochs are solved at once (`dgcal.pos.gnss.spp_batch.solve_epochs`) from the guesses of the previous
    round, starting with the header position for all: an epoch's solution depends on its start only through
    where the models are evaluated (~5e-4 m per metre), so each round brings the epoch-by-epoch result ~2000
    times closer; an epoch is solved again only while its start moves by 10 um or more (what remains is ~5 nm).
    With `code_sigma_from_data` (and `model_errors`: real data) the receiver's code noise at the zenith is estimated
    from the residuals of the first round, solved without RAIM (`code_noise_from_residuals`), and every epoch solved
    again with it: the result is `solve_epoch`'s chain with `code_sigma_zenith_m` the estimate
    (`SppSolution.options`; `.code_noise` says what was given, estimated, and from how many residual differences).
    `progress` is accepted for the callers (no bar: an hour takes about a second)."""
    if opts is None:
        opts = SppOptions()
    tab = ObsTable.from_epochs(obs.epochs)
    E = len(obs.epochs)
    header = np.asarray(obs.p_approx_ecef, float) if _has_position(obs.p_approx_ecef) else np.full(3, np.nan)
    guesses = np.tile(header, (E, 1))
    estimate = opts.code_sigma_from_data and opts.model_errors
    # the first round's residuals tell the noise (the rounds after it move the fixes by millimetres), all of them:
    # RAIM at a noise still unknown would take the largest away
    fits = solve_epochs(tab, nav, guesses, replace(opts, raim=False) if estimate else opts)
    noise = {"code_sigma_zenith_m": opts.code_sigma_zenith_m, "estimated": False}
    if estimate:
        est = code_noise_from_residuals(tab, fits, opts.code_sigma_zenith_m)
        noise.update(given_m=opts.code_sigma_zenith_m, differences=0 if est is None else est[1])
        opts = replace(opts, code_sigma_from_data=False)
        if est is not None:
            noise.update(code_sigma_zenith_m=est[0], estimated=True)
            opts = replace(opts, code_sigma_zenith_m=est[0])
        guesses = _previous_fix(fits, header)
        fits = solve_epochs(tab, nav, guesses, opts)
    fits = _chain(tab, nav, fits, guesses, header, opts)
    error_model = {"model": "independent"}
    if opts.model_errors:
        fits.cov_p, error_model = covariance(tab, fits, nav, iono_error_field(tab, fits, nav))
    b = fits.bounds
    groups = sorted({CLOCK_GROUP[s] for s in obs.systems}, key=GROUPS.index)
    pa = fits.m.p_approx
    known = np.all(np.isfinite(pa), axis=1) & (np.linalg.norm(np.nan_to_num(pa), axis=1) > 6e6)
    epochs = [to_epoch(tab, fits.m, obs.epochs[e], e, b[e], b[e + 1], bool(known[e])) if fits.ok[e] else None
              for e in range(E)]
    res = fits.res.tolist()
    return SppSolution(
        t_gps=tab.t.copy(), ok=fits.ok, p_ecef=fits.p, cov_p=fits.cov_p, v_ecef=fits.v, cov_v=fits.cov_v,
        clk_m={g: fits.clk[:, GROUPS.index(g)] for g in groups},
        clk_sigma_m={g: fits.clk_sigma[:, GROUPS.index(g)] for g in groups},
        drift_mps=fits.drift, drift_sigma_mps=fits.drift_sigma, n_sat=fits.n_sat, dop=fits.dop,
        chi2_dof=fits.chi2_dof, used=[list(ep.sat) if ep is not None else [] for ep in epochs],
        rejected=[list(r) for r in fits.rejected], epochs=epochs,
        residuals_m=[dict(zip(ep.sat, res[b[e]:b[e + 1]])) if ep is not None else {} for e, ep in enumerate(epochs)],
        options=opts, code_noise=noise, error_model=error_model)


def _chain(tab: ObsTable, nav: BroadcastNav, fits, guesses: np.ndarray, header: np.ndarray, opts: SppOptions):
    """`fits` (every epoch solved from `guesses` (E,3)) solved again from the previous epoch's solution until no
    start moves (see `spp`)."""
    for _ in range(10):
        new = _previous_fix(fits, header)
        # an epoch whose start moved by less than 10 um would move by less than 5 nm: only the others again
        moved = np.flatnonzero(~(np.all(np.abs(new - guesses) < 1e-5, axis=1)
                                 | np.all(np.isnan(new) & np.isnan(guesses), axis=1)))
        if not len(moved):
            break
        fits = merge_fits(fits, solve_epochs(tab, nav, new, opts, moved), moved)
        guesses = new
    return fits


def _previous_fix(fits, header: np.ndarray) -> np.ndarray:
    """Each epoch's start: the last solution before it (the header position before the first)."""
    E = len(fits.ok)
    last = np.where(fits.ok, np.arange(E), -1)
    last = np.maximum.accumulate(last)
    prev = np.r_[-1, last[:-1]]
    out = np.tile(header, (E, 1))
    have = prev >= 0
    out[have] = fits.p[prev[have]]
    return out


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
    for name, val in (("rinex_obs", obs_path), ("rinex_nav", nav_paths)):
        if not val:
            raise InputError("required for --mode spp", field=name)
    nav = read_rinex_nav(nav_paths[0], list(nav_paths[1:]))
    rx = read_obs_file(obs_path, t_start=t_start, t_end=t_end)
    obs = read_rinex_obs(obs_path, systems=opts.systems, rinex=rx, glonass_k=glonass_channels(nav))
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


def glonass_channels(nav: BroadcastNav) -> dict[str, int] | None:
    """Frequency channel of each GLONASS satellite of the navigation records (None without GLONASS records)."""
    glo = getattr(nav, "glonass", None)
    return None if glo is None else glo.frequency_numbers()


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
    raw = read_rinex_obs(obs_path, systems=opts.systems, glonass_k=glonass_channels(nav))
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
        "orbits": getattr(nav, "orbits", "broadcast"),
        "warnings": list(getattr(nav, "warnings", [])),
        "code_noise": dict(sol.code_noise),
        "error_model": dict(sol.error_model),
        "options": {"elev_mask_deg": opts.elev_mask_deg, "code_sigma_zenith_m": opts.code_sigma_zenith_m,
                    "code_sigma_from_data": opts.code_sigma_from_data, "model_errors": opts.model_errors,
                    "doppler_sigma_zenith_mps": opts.doppler_sigma_zenith_mps,
                    "systems": list(opts.systems), "raim": opts.raim},
    }
