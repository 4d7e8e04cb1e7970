"""Simulated GNSS code pseudoranges and Doppler of a moving antenna, from broadcast orbits.

``simulate_gnss`` is the plain function (used by the POS simulator and the smoother tests);
``dgcal simulate gnss`` writes a static or circling receiver's RINEX 3 observations together with
the navigation file used and ``truth.json``.

Model (consistent with ``dgcal.pos.gnss.spp.prepare_epoch``, so SPP on the output is unbiased)::

    pr = c*tau + c*(dt_rx + isb[sys]) - c*dt_sat(t_tx) + I_klobuchar + T_saastamoinen + b_sat + n_pr
    rr = d(rho)/dt + c*ddt_rx - c*ddt_sat + n_rr,     doppler_hz = -rr / wavelength

where ``tau`` solves the light-time equation exactly (Earth rotation during travel included)
and ``d(rho)/dt`` is the numerical derivative of that exact range. The receiver time tag is
``t_tag = t_true + dt_rx``: the antenna position at the tag is ``p(t_tag) - v * dt_rx``.
Noise sigmas depend on elevation (``dgcal.pos.gnss.corrections.code_sigma_m``). ``b_sat`` is zero unless a
``CodeErrorModel`` is given: then every satellite's pseudoranges carry the slow error that real broadcast orbits,
clocks and atmosphere models leave (a Gauss-Markov sequence scaled by the front end's own budget).
"""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from cssrlib.gnss import Eph, char2sys, gpst2time, prn2sat

from dgcal.fields.constants import C_LIGHT, GM_GPS, OMEGA_EARTH, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.fields.crs import LocalENU, ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.pos.gnss.carrier import CarrierObs
from dgcal.pos.gnss.corrections import (KLOBUCHAR_SHARE, code_sigma_m, klobuchar_delay_m, model_sigma_m,
                                        saastamoinen_delay_m)
from dgcal.pos.gnss.ephemeris import satellite_states
from dgcal.pos.gnss.glonass import MU_GLO, OMGE_GLO, GlonassEphemerides, glonass_frequency_hz, integrate_orbits
from dgcal.pos.gnss.observations import GnssEpoch, GnssObservations
from dgcal.pos.gnss.rinex import BroadcastNav, read_rinex_nav, signal_frequency_hz, write_rinex_obs
from dgcal.pos.gnss.rinex_nav import glonass_rinex3_lines
from dgcal.pos.gnss.spp import SppOptions, prepare_epoch


DEFAULT_NAV = Path(__file__).resolve().parents[2] / "shared" / "data" / "rinex-sept" / "SEPT078M.21P"
# 2021-03-19 12:00:00 GPS time, inside the validity of DEFAULT_NAV
DEFAULT_T0_GPS = 2149 * SECONDS_PER_WEEK + 5 * SECONDS_PER_DAY + 12 * 3600.0
SIGNAL = {"G": "C1C", "J": "C1C", "E": "C1C", "C": "C2I", "R": "C1C"}


@dataclass
class RxClock:
    """Receiver clock: bias (s) and drift (s/s) random walks plus constant inter-system biases (m).

    ``q_bias`` (s^2/s) and ``q_drift`` (s^2/s^3) are the white-noise intensities of the bias and
    drift random walks (defaults: a TCXO, h0 = 2e-19, h-2 = 2e-20).
    """

    bias_s: float = 2.0e-5
    drift: float = 5.0e-8
    q_bias: float = 1.0e-19
    q_drift: float = 4.0e-19
    isb_m: dict[str, float] = field(default_factory=lambda: {"G": 0.0, "J": 0.0, "E": 2.5, "C": -4.0, "R": -7.0})


@dataclass
class CodeErrorModel:
    """Slow pseudorange errors of each satellite, as the broadcast models leave them on real data.

    Per satellite: `scale` times the front end's budget (`dgcal.pos.gnss.corrections.model_sigma_m`: a share of the
    Klobuchar delay, the troposphere, the ephemeris's URA; elevation dependent) times a unit-variance first-order
    Gauss-Markov sequence of correlation time `tau_s`. `scale` 1 draws exactly what the smoother's code-bias states
    (`dgcal.pos.smoother.code_bias`) assume; real receivers in multipath see more.
    """

    scale: float = 1.0
    tau_s: float = 1800.0

    def as_dict(self) -> dict:
        """The model as a JSON-ready dict."""
        return dict(self.__dict__)


def _load_nav(nav, t_span: tuple[float, float] | None = None, systems=("G", "E", "C"),
              seed: int = 0) -> BroadcastNav:
    if isinstance(nav, BroadcastNav):
        return _with_glonass(nav, t_span, systems, seed)
    if nav is None:
        nav = DEFAULT_NAV
    if isinstance(nav, str) and nav == "synthetic":
        if t_span is None:
            raise ValueError("a synthetic constellation needs the time span")
        return synthetic_nav(t_span[0], t_span[1], systems, seed)
    return _with_glonass(read_rinex_nav(nav), t_span, systems, seed)


def _with_glonass(nav: BroadcastNav, t_span, systems, seed: int) -> BroadcastNav:
    """`nav`, or a copy with `synthetic_glonass` records when GLONASS is asked for and `nav` has none."""
    if "R" not in systems or getattr(nav, "glonass", None) is not None:
        return nav
    if t_span is None:
        raise ValueError("a synthetic GLONASS constellation needs the time span")
    return replace(nav, glonass=synthetic_glonass(t_span[0], t_span[1], seed), _toe={})


def load_nav(nav=None, t_span: tuple[float, float] | None = None, systems=("G", "E", "C"),
             seed: int = 0) -> BroadcastNav:
    """Broadcast orbits for simulation: a path, a ``BroadcastNav``, "synthetic" (needs ``t_span``)
    or None for the bundled real file (2021-03-19)."""
    return _load_nav(nav, t_span, systems, seed)


def synthetic_nav(t0_gps: float, t1_gps: float, systems=("G", "E", "C"), seed: int = 0) -> BroadcastNav:
    """A built-in Walker-like constellation as broadcast ephemerides valid over [t0, t1] (GPS s).

    GPS 24 satellites in 6 planes (i = 55 deg), Galileo 24 in 3 planes (56 deg), BeiDou MEO 24
    in 3 planes (55 deg); near-circular orbits, small random clock offsets and drifts, no TGD.
    Ephemerides are issued every 2 hours; the same orbit is continuous across issues.
    """

    rng = np.random.default_rng(seed)
    spec = {"G": (26559.7e3, 55.0, 6, 4), "E": (29600.0e3, 56.0, 3, 8), "C": (27906.1e3, 55.0, 3, 8)}
    toes = np.arange(np.floor(t0_gps / 7200.0) * 7200.0 - 7200.0, t1_gps + 7200.0 + 1.0, 7200.0)
    eph_all, by_sat = [], {}
    for s in (s for s in systems if s != "R"):
        a, inc, n_planes, per_plane = spec[s]
        n_mot = np.sqrt(GM_GPS / a ** 3)
        prn = 0
        for pl in range(n_planes):
            for k in range(per_plane):
                prn += 1
                raan = 2 * np.pi * pl / n_planes + (0.3 if s == "E" else 0.0)
                m_ref = 2 * np.pi * k / per_plane + np.pi * pl / (n_planes * per_plane) * 2
                ecc, omg = 0.002 + 0.008 * rng.random(), 2 * np.pi * rng.random()
                af0, af1 = rng.normal(0, 2e-4), rng.normal(0, 3e-12)
                sid = f"{s}{prn:02d}"
                for toe in toes:
                    week = int(np.floor(toe / SECONDS_PER_WEEK))
                    eph = Eph(prn2sat(char2sys(s), prn))
                    eph.toes = toe - week * SECONDS_PER_WEEK
                    eph.week = week
                    eph.toe = gpst2time(week, eph.toes)
                    eph.toc = eph.toe
                    eph.tot = eph.toe
                    eph.A, eph.e, eph.i0, eph.omg = a, ecc, np.radians(inc), omg
                    eph.M0 = np.mod(m_ref + n_mot * toe, 2 * np.pi)
                    eph.OMG0 = np.mod(raan - OMEGA_EARTH * week * SECONDS_PER_WEEK, 2 * np.pi)
                    eph.deln = eph.OMGd = eph.idot = 0.0
                    eph.crs = eph.crc = eph.cus = eph.cuc = eph.cis = eph.cic = 0.0
                    eph.af0, eph.af1, eph.af2 = af0 + af1 * (toe - toes[0]), af1, 0.0
                    eph.tgd, eph.svh, eph.sva, eph.mode = 0.0, 0, 0, 0
                    eph.code = 516 if s == "E" else 0
                    eph_all.append(eph)
                    by_sat.setdefault(sid, []).append(eph)
    ion = np.array([[1.118e-08, 7.451e-09, -5.960e-08, -5.960e-08],
                    [9.011e+04, 0.0, -1.966e+05, -6.554e+04]])
    return BroadcastNav(eph=eph_all, by_sat=by_sat, ion_gps=ion, ion_bds=None, leap_seconds=18,
                        source="synthetic",
                        glonass=synthetic_glonass(t0_gps, t1_gps, seed) if "R" in systems else None)


def synthetic_glonass(t0_gps: float, t1_gps: float, seed: int = 0) -> GlonassEphemerides:
    """A GLONASS-like constellation as broadcast records every 30 min covering [t0, t1] (GPS s): 24 satellites in 3
    planes (i = 64.8 deg, a = 25510 km, circular), each record's state integrated from the one before (the orbit is
    continuous across records), frequency channels -7..6 (antipodal satellites share one), small clock offsets."""
    rng = np.random.default_rng(seed + 1000)
    a, inc = 25510e3, np.radians(64.8)
    toes = np.arange(np.floor(t0_gps / 1800.0) * 1800.0 - 1800.0, t1_gps + 1800.0 + 1.0, 1800.0)
    rows = []
    for plane in range(3):
        raan = np.radians(120.0 * plane + 10.0)
        P = np.array([np.cos(raan), np.sin(raan), 0.0])
        Q = np.array([-np.sin(raan) * np.cos(inc), np.cos(raan) * np.cos(inc), np.sin(inc)])
        for slot in range(8):
            u = np.radians(45.0 * slot + 15.0 * plane)
            r = a * (np.cos(u) * P + np.sin(u) * Q)
            v = np.sqrt(MU_GLO / a) * (-np.sin(u) * P + np.cos(u) * Q) - np.cross([0.0, 0.0, OMGE_GLO], r)
            taun, gamn = rng.normal(0.0, 1e-5), rng.normal(0.0, 1e-12)
            for j, toe in enumerate(toes):
                if j:
                    pr, vr = integrate_orbits(r[None], v[None], np.zeros((1, 3)), np.array([1800.0]))
                    r, v = pr[0], vr[0]
                rows.append({"sat": f"R{8 * plane + slot + 1:02d}", "toe": toe, "pos": r, "vel": v,
                             "acc": np.zeros(3), "taun": taun - gamn * (toe - toes[0]), "gamn": gamn,
                             "frq": (4 * plane + slot % 4) % 14 - 7, "svh": 0, "age": 0, "line": 0})
    return GlonassEphemerides.from_rows(rows)


def _clock_series(t: np.ndarray, clk: RxClock, rng) -> tuple[np.ndarray, np.ndarray]:
    """Receiver clock bias (s) and drift (s/s) at times t: integrated random walks."""
    n = len(t)
    b, d = np.empty(n), np.empty(n)
    b[0], d[0] = clk.bias_s, clk.drift
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        d[k] = d[k - 1] + np.sqrt(clk.q_drift * dt) * rng.standard_normal()
        b[k] = b[k - 1] + 0.5 * (d[k - 1] + d[k]) * dt + np.sqrt(clk.q_bias * dt) * rng.standard_normal()
    return b, d


def _ecef_acceleration(p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Satellite acceleration in the rotating ECEF frame: gravity, Coriolis and centrifugal."""
    w = np.array([0.0, 0.0, OMEGA_EARTH])
    grav = -GM_GPS * p / np.linalg.norm(p, axis=1, keepdims=True) ** 3
    return grav - 2.0 * np.cross(w, v) - np.cross(w, np.cross(w, p))


def _range_at(p_s0, v_s0, a_s0, t_s0, p_rx, t_rx):
    """Exact light-time range (m) and travel time (s) to a receiver at (p_rx, t_rx).

    Satellite motion near ``t_s0`` is a second-order Taylor series (the span is < 0.1 s).
    """
    tau = np.full(len(p_s0), 0.075)
    for _ in range(4):
        dt = (t_rx - tau - t_s0)[:, None]
        ps = p_s0 + v_s0 * dt + 0.5 * a_s0 * dt ** 2
        th = OMEGA_EARTH * tau
        c, s = np.cos(th), np.sin(th)
        prot = np.stack([c * ps[:, 0] + s * ps[:, 1], -s * ps[:, 0] + c * ps[:, 1], ps[:, 2]], axis=1)
        rho = np.linalg.norm(prot - p_rx, axis=1)
        tau = rho / C_LIGHT
    return rho, tau, prot


def simulate_gnss(traj_t_gps: np.ndarray, p_ecef_antenna: np.ndarray, v_ecef: np.ndarray,
                  nav=None, rx_clock: RxClock | None = None, seed: int = 0,
                  sigma_pr: float = 0.5, sigma_doppler: float = 0.05,
                  outages: list[tuple[float, float, int]] = (), systems=("G", "E"),
                  elev_mask_deg: float = 10.0, prepare: bool = True,
                  code_errors: CodeErrorModel | None = None) -> GnssObservations:
    """Pseudoranges (m) and Doppler (Hz) of an antenna moving along an ECEF trajectory.

    ``traj_t_gps`` (N,) continuous GPS seconds (the receiver epochs), ``p_ecef_antenna`` (N,3) m,
    ``v_ecef`` (N,3) m/s; ``nav``: a RINEX navigation path, a ``BroadcastNav``, ``"synthetic"``
    (``synthetic_nav`` over the trajectory's span: any date, G/E/C/R) or None for the bundled real
    file (then the flight must lie within about 2021-03-19 10:00-15:30 GPS time, e.g. from
    ``DEFAULT_T0_GPS``; G, E and J are available). GLONASS ('R' in ``systems``): the navigation's GLONASS records,
    or `synthetic_glonass`'s when it has none (FDMA wavelengths per satellite). ``outages``:
    (t0, t1, max_sats) -- between t0 and t1 only the ``max_sats`` highest satellites are kept.
    ``sigma_pr``/``sigma_doppler``: zenith noise (m, m/s). With ``prepare`` the epochs are run
    through ``dgcal.pos.gnss.spp.prepare_epoch`` at the true positions (sigmas = the simulated noise, no
    model-error budget), else they are raw. ``code_errors``: add each satellite's slow error
    (`CodeErrorModel`; truth["code_bias_m"] {sat: (t_gps, bias m)}). ``truth`` holds the true states per epoch:
    ``p_ecef``, ``v_ecef``, ``clk_m`` {sys: c*(dt_rx)+isb} (m), ``drift_mps``, ``t_gps``, and
    ``nav`` (the ``BroadcastNav`` used, e.g. to run ``dgcal.pos.gnss.spp.spp`` on raw output).
    """
    rng = np.random.default_rng(seed)
    t = np.asarray(traj_t_gps, float)
    nav = _load_nav(nav, (t[0], t[-1]), tuple(s for s in systems if s in "GECR"), seed)
    clk = rx_clock or RxClock()
    P = np.asarray(p_ecef_antenna, float).reshape(-1, 3)
    V = np.asarray(v_ecef, float).reshape(-1, 3)
    bias, drift = _clock_series(t, clk, rng)
    code_bias: dict = {}
    raw_epochs = _simulate_raw(t, P, V, bias, drift, nav, clk, rng, sigma_pr, sigma_doppler,
                               outages, systems, elev_mask_deg, code_errors, code_bias)
    truth = {"t_gps": t, "p_ecef": P, "v_ecef": V, "drift_mps": C_LIGHT * drift,
             "clk_m": {s: C_LIGHT * bias + clk.isb_m.get(s, 0.0) for s in systems}, "nav": nav,
             "code_bias_m": code_bias}
    obs = GnssObservations(epochs=raw_epochs, receiver="DGCAL SIM", p_approx_ecef=P[0].copy(),
                           signals={s: SIGNAL[s] for s in systems}, source="simulation", truth=truth)
    if prepare:
        obs.epochs = prepare_simulated(obs, nav, sigma_pr, sigma_doppler, elev_mask_deg)
    return obs


def _simulate_raw(t, P, V, bias, drift, nav, clk: RxClock, rng, sigma_pr, sigma_doppler, outages,
                  systems, elev_mask_deg, code_errors: CodeErrorModel | None = None,
                  code_bias_out: dict | None = None) -> list[GnssEpoch]:
    """Raw epochs, vectorised over all (epoch, satellite) pairs; the satellites' slow errors (m) go into
    `code_bias_out` {sat: (t_gps, bias)}."""

    n_ep = len(t)
    t_true = t - bias                        # receiver tags run ahead of true time by dt_rx
    p_rx = P - V * bias[:, None]
    llh = ecef_to_geodetic(p_rx).reshape(n_ep, 3)
    R_ecef_to_local_enu = R_ecef_to_enu(llh[:, 0], llh[:, 1]).reshape(n_ep, 3, 3)
    sats = sorted(s for s in nav.by_sat if s[0] in systems)
    if "R" in systems and getattr(nav, "glonass", None) is not None:
        sats += sorted(set(str(x) for x in nav.glonass.sat))
    k_glo = nav.glonass.frequency_numbers() if "R" in systems and nav.glonass is not None else {}

    def elev_azim(k_idx, p_sat):
        d = p_sat - p_rx[k_idx]
        e = np.einsum("nij,nj->ni", R_ecef_to_local_enu[k_idx], d / np.linalg.norm(d, axis=1, keepdims=True))
        return np.arcsin(np.clip(e[:, 2], -1, 1)), np.mod(np.arctan2(e[:, 0], e[:, 1]), 2 * np.pi)

    # candidate satellites per 30-s block (elevation above mask - 5 deg at the block start)
    block = np.floor((t - t[0]) / 30.0).astype(int)
    starts = np.nonzero(np.r_[True, np.diff(block) != 0])[0]
    kk = np.repeat(starts, len(sats))
    ss = sats * len(starts)
    ps, *_, ok = satellite_states(nav, ss, t_true[kk])
    el = np.full(len(ss), -1.0)
    el[ok], _ = elev_azim(kk[ok], ps[ok])
    vis_ok = (el > np.radians(elev_mask_deg - 5.0)).reshape(len(starts), len(sats))
    visible = {int(block[k]): [s for s, v in zip(sats, row) if v] for k, row in zip(starts, vis_ok)}
    K = np.concatenate([np.full(len(visible[int(block[k])]), k) for k in range(n_ep)]).astype(int)
    S = [s for k in range(n_ep) for s in visible[int(block[k])]]
    if len(K) == 0:
        return []
    t_s0 = t_true[K] - 0.075
    ps, vs, clk_s, clk_d, ura, ok = satellite_states(nav, S, t_s0)
    acc = _ecef_acceleration(ps, vs)
    rho, tau, prot = _range_at(ps, vs, acc, t_s0, p_rx[K], t_true[K])
    el, az = elev_azim(K, prot)
    m = ok & (el >= np.radians(elev_mask_deg))
    for (a, b, nmax) in outages:
        for k in np.nonzero((t >= a) & (t <= b))[0]:
            idx = np.nonzero((K == k) & m)[0]
            if len(idx) > nmax:
                m[idx[np.argsort(-el[idx])[nmax:]]] = False
    sel = np.nonzero(m)[0]
    K, S = K[sel], [S[i] for i in sel]
    ps, vs, acc, clk_s, clk_d, ura = ps[sel], vs[sel], acc[sel], clk_s[sel], clk_d[sel], ura[sel]
    rho, tau, el, az, t_s0 = rho[sel], tau[sel], el[sel], az[sel], t_s0[sel]
    h_d = 0.01
    rho_p, _, _ = _range_at(ps, vs, acc, t_s0, p_rx[K] + V[K] * h_d, t_true[K] + h_d)
    rho_m, _, _ = _range_at(ps, vs, acc, t_s0, p_rx[K] - V[K] * h_d, t_true[K] - h_d)
    rr = (rho_p - rho_m) / (2 * h_d)
    dts = clk_s + clk_d * ((t_true[K] - tau) - t_s0)
    sysv = np.array([s[0] for s in S])
    lam = {s: C_LIGHT / signal_frequency_hz(s, SIGNAL[s]) for s in systems if s != "R"}
    lam.update({sid: C_LIGHT / float(glonass_frequency_hz(k)) for sid, k in k_glo.items()})   # FDMA
    lam_v = np.array([lam[sid if sid[0] == "R" else sid[0]] for sid in S])
    iono = klobuchar_delay_m(t_true[K], llh[K, 0], llh[K, 1], el, az, nav.ion_gps, C_LIGHT / lam_v)
    tropo = saastamoinen_delay_m(llh[K, 0], llh[K, 2], el)
    isb = np.array([clk.isb_m.get(s, 0.0) for s in sysv])
    s_pr = code_sigma_m(el, sigma_pr)
    s_rr = code_sigma_m(el, sigma_doppler)
    pr = (rho + C_LIGHT * bias[K] + isb - C_LIGHT * dts + iono + tropo
          + s_pr * rng.standard_normal(len(K)))
    if code_errors is not None:
        b = _satellite_code_errors(code_errors, t, K, S, el, iono, ura, nav, rng)
        pr = pr + b
        if code_bias_out is not None:
            sat_of = np.array(S)
            for s in sorted(set(S)):
                i = np.flatnonzero(sat_of == s)
                code_bias_out[s] = (t[K[i]], b[i])
    rr_meas = rr + C_LIGHT * drift[K] - C_LIGHT * clk_d + s_rr * rng.standard_normal(len(K))
    cn0 = np.round(30.0 + 20.0 * np.sin(el), 3)
    out = []
    bounds = np.nonzero(np.r_[True, np.diff(K) != 0, True])[0]
    for a, b in zip(bounds[:-1], bounds[1:]):
        n = b - a
        nan = np.full(n, np.nan)
        out.append(GnssEpoch(
            t_gps=float(t[K[a]]), sat=S[a:b], system=sysv[a:b], pr_m=pr[a:b],
            doppler_hz=-rr_meas[a:b] / lam_v[a:b], range_rate_mps=rr_meas[a:b],
            wavelength_m=lam_v[a:b], cn0_dbhz=cn0[a:b],
            sat_pos_ecef=np.full((n, 3), np.nan), sat_vel_ecef=np.full((n, 3), np.nan),
            sat_clk_s=nan.copy(), sat_clk_drift=nan.copy(), iono_m=nan.copy(), tropo_m=nan.copy(),
            elev_deg=nan.copy(), azim_deg=nan.copy(), sigma_pr_m=s_pr[a:b], sigma_rr_mps=s_rr[a:b]))
    return out


def _satellite_code_errors(model: CodeErrorModel, t: np.ndarray, K: np.ndarray, S: list, el: np.ndarray,
                           iono: np.ndarray, ura: np.ndarray, nav, rng) -> np.ndarray:
    """Slow error (m) of every (epoch K, satellite S) pair: `model.scale` x the front end's budget x a unit
    Gauss-Markov sequence per satellite over all epochs (drawn in sorted satellite order, so a seed gives the
    same errors in every process)."""
    sats = sorted(set(S))
    col = {s: j for j, s in enumerate(sats)}
    dt = np.r_[0.0, np.diff(t)]
    u = _gauss_markov(len(t), (len(sats),), dt, model.tau_s, rng)
    share = 1.0 if getattr(nav, "ion_source", "") == "default" else KLOBUCHAR_SHARE
    sigma = model_sigma_m(el, iono, np.where(np.isfinite(ura), ura, 2.0), iono_share=share,
                          system=np.array([s[0] for s in S]))
    return model.scale * sigma * u[K, [col[s] for s in S]]


def prepare_simulated(obs: GnssObservations, nav: BroadcastNav, sigma_pr: float,
                      sigma_doppler: float, elev_mask_deg: float) -> list[GnssEpoch]:
    """Run the front end on simulated raw epochs at the true antenna positions."""
    opts = SppOptions(elev_mask_deg=elev_mask_deg - 1e-6, code_sigma_zenith_m=sigma_pr,
                      doppler_sigma_zenith_mps=sigma_doppler, model_errors=False,
                      systems=tuple(obs.signals))
    t_true = obs.truth["t_gps"]
    out = []
    for ep in obs.epochs:
        k = int(np.searchsorted(t_true, ep.t_gps - 1e-9))
        out.append(prepare_epoch(ep, nav, obs.truth["p_ecef"][k], opts))
    return out


def circle_trajectory(t_gps: np.ndarray, lat: float, lon: float, h: float, radius: float,
                      speed: float) -> tuple[np.ndarray, np.ndarray]:
    """ECEF positions (m) and velocities (m/s) of a horizontal circle (or a static point)."""
    enu = LocalENU(lat, lon, h)
    tt = t_gps - t_gps[0]
    if radius > 0:
        w = speed / radius
        p = np.stack([radius * np.cos(w * tt), radius * np.sin(w * tt), np.zeros_like(tt)], 1)
        v = np.stack([-radius * w * np.sin(w * tt), radius * w * np.cos(w * tt), np.zeros_like(tt)], 1)
    else:
        p, v = np.zeros((len(tt), 3)), np.zeros((len(tt), 3))
    return enu.to_ecef(p), v @ enu.R_ecef_to_enu


def write_nav_file(path: Path, source: str | Path, used: BroadcastNav) -> None:
    """A simulation's navigation file: `source` copied, with the GLONASS records of `used` (the synthetic ones the
    observations came from) after its header when it has none of its own."""
    shutil.copyfile(source, path)
    if getattr(used, "glonass", None) is not None and read_rinex_nav(path).glonass is None:
        lines = Path(path).read_text().splitlines()
        end = next(i for i, x in enumerate(lines) if x[60:].startswith("END OF HEADER"))
        Path(path).write_text("\n".join(lines[:end + 1] + glonass_rinex3_lines(used.glonass) + lines[end + 1:]) + "\n")


def simulate_gnss_dataset(out: str | Path, seed: int = 0, nav: str | Path | None = None,
                          t0_gps: float | None = None, duration_s: float = 300.0, rate_hz: float = 1.0,
                          lat: float = 35.3, lon: float = 139.5, height: float = 100.0, radius_m: float = 0.0,
                          speed_mps: float = 10.0, sigma_pr: float = 0.5, sigma_doppler: float = 0.05,
                          systems: tuple[str, ...] = ("G", "E")) -> Path:
    """Simulate RINEX 3 observations of a receiver static at (lat, lon deg, height m ellipsoidal) or on a
    horizontal circle (`radius_m`, `speed_mps`) from `duration_s` at `rate_hz` (t0: continuous GPS s, default
    DEFAULT_T0_GPS) into out/sim.obs, with the navigation file (default DEFAULT_NAV) as out/nav.rnx and the
    truth (positions, clocks) in out/truth.json; returns the observation file's path. With 'R' in `systems` and no
    GLONASS records in the navigation file, `synthetic_glonass`'s records are simulated and written into nav.rnx."""
    t0 = t0_gps if t0_gps is not None else DEFAULT_T0_GPS
    t = t0 + np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    p, v = circle_trajectory(t, lat, lon, height, radius_m, speed_mps)
    obs = simulate_gnss(t, p, v, _load_nav(nav), seed=seed, sigma_pr=sigma_pr, sigma_doppler=sigma_doppler,
                        systems=tuple(systems), prepare=False)
    with staged_dir(out) as d:
        write_rinex_obs(Path(d) / "sim.obs", obs)
        write_nav_file(Path(d) / "nav.rnx", nav or DEFAULT_NAV, obs.truth["nav"])
        truth = {"kind": "gnss", "seed": seed, "systems": list(systems),
                 "sigma_pr_m": sigma_pr, "sigma_doppler_mps": sigma_doppler,
                 "t_gps": t.tolist(), "p_ecef": p.tolist(), "v_ecef": v.tolist(),
                 "clk_m": {s: c.tolist() for s, c in obs.truth["clk_m"].items()},
                 "drift_mps": obs.truth["drift_mps"].tolist()}
        with atomic_write(Path(d) / "truth.json") as fh:
            json.dump(truth, fh)
    return Path(out) / "sim.obs"


# ------------------------------------------------------------------------------- carrier phase (PPK tests)
CARRIER_BANDS_HZ = {"G": (1575.42e6, 1227.60e6, 1176.45e6), "E": (1575.42e6, 1176.45e6, 1207.14e6),
                    "J": (1575.42e6, 1227.60e6, 1176.45e6)}


def simulate_carrier_pair(t_gps: np.ndarray, p_rover_ecef: np.ndarray, p_base_ecef: np.ndarray, nav=None,
                          seed: int = 0, sigma_code: float = 0.3, sigma_phase: float = 0.003,
                          systems=("G", "E"), n_freq: int = 2, elev_mask_deg: float = 10.0,
                          slips: list[tuple[float, str, int, int, bool]] = ()):
    """Minimal simulated code + carrier phase of a rover and a static base (for PPK tests), as two
    ``dgcal.pos.gnss.carrier.CarrierObs``; returns (rover, base, nav).

    Per receiver, satellite and frequency slot ``f`` (GPS/QZSS L1 L2 L5, Galileo E1 E5a E5b)::

        P = rho + c*(dt_rx - dt_sat) + T + I_f + n_P,    L = (rho + c*(dt_rx - dt_sat) + T - I_f)/lam + N + n_L/lam

    with the exact light-time range of ``_range_at``, the Saastamoinen (standard atmosphere, 70 % humidity) and
    Klobuchar models at each receiver (so that the PPK front end removes them; no differential atmosphere error), a
    constant
    receiver clock offset, random integer ambiguities and white noise ``sigma * sqrt(1/2 + 1/(2 sin^2 el))``
    (zenith sigmas ``sigma_code`` m, ``sigma_phase`` m). ``slips``: (t_gps, sat, slot, cycles, flagged)
    add ``cycles`` to that phase from ``t_gps`` on, with LLI=1 at that epoch if ``flagged``. ``rover.truth``
    holds the true rover positions. Code-only products (SPP) are unchanged by this function.
    """
    rng = np.random.default_rng(seed)
    t = np.asarray(t_gps, float)
    nav = _load_nav(nav, (t[0], t[-1]), tuple(s for s in systems if s in "GEC"), seed)
    n_ep = len(t)
    P_r = np.asarray(p_rover_ecef, float).reshape(-1, 3)
    if len(P_r) == 1:
        P_r = np.repeat(P_r, n_ep, axis=0)
    p_b = np.asarray(p_base_ecef, float).reshape(3)
    sats = sorted(s for s in nav.by_sat if s[0] in systems and s[0] in CARRIER_BANDS_HZ)
    m = len(sats)
    freq = np.array([[CARRIER_BANDS_HZ[s[0]][f] for f in range(n_freq)] for s in sats])
    out = {}
    for name, pos, clk_m in (("rover", P_r, 3.0e3), ("base", np.repeat(p_b[None], n_ep, axis=0), -1.2e3)):
        K = np.repeat(np.arange(n_ep), m)
        S = sats * n_ep
        t_true = t[K] - clk_m / C_LIGHT              # the time tag runs ahead of true time by the clock offset
        t_s0 = t_true - 0.075
        ps, vs, clk_s, clk_d, _, ok = satellite_states(nav, S, t_s0)
        ps = np.where(ok[:, None], ps, 2.6e7)
        vs = np.where(ok[:, None], vs, 0.0)
        acc = _ecef_acceleration(ps, vs)
        rho, tau, prot = _range_at(ps, vs, acc, t_s0, pos[K], t_true)
        llh = ecef_to_geodetic(pos[K]).reshape(-1, 3)
        R_ecef_to_local_enu = R_ecef_to_enu(llh[:, 0], llh[:, 1]).reshape(-1, 3, 3)
        d = prot - pos[K]
        e = np.einsum("nij,nj->ni", R_ecef_to_local_enu, d / np.linalg.norm(d, axis=1, keepdims=True))
        el = np.arcsin(np.clip(e[:, 2], -1, 1))
        az = np.mod(np.arctan2(e[:, 0], e[:, 1]), 2 * np.pi)
        vis = ok & (el >= np.radians(elev_mask_deg - 2.0))
        dts = clk_s + clk_d * ((t_true - tau) - t_s0)
        tropo = saastamoinen_delay_m(llh[:, 0], llh[:, 2], el, humidity=0.7)
        geo = rho + clk_m - C_LIGHT * dts + tropo
        Pm = np.full((n_ep * m, n_freq), np.nan)
        Lm = np.full((n_ep * m, n_freq), np.nan)
        N = rng.integers(-10 ** 6, 10 ** 6, size=(m, n_freq)).astype(float)
        for f in range(n_freq):
            fr = freq[np.tile(np.arange(m), n_ep), f]
            iono = klobuchar_delay_m(t[K], llh[:, 0], llh[:, 1], el, az, nav.ion_gps, fr)
            sc = code_sigma_m(el, sigma_code)
            sp = code_sigma_m(el, sigma_phase)
            Pm[:, f] = geo + iono + sc * rng.standard_normal(len(K))
            Lm[:, f] = (geo - iono + sp * rng.standard_normal(len(K))) / (C_LIGHT / fr) + N[np.tile(np.arange(m),
                                                                                                       n_ep), f]
        Pm[~vis] = np.nan
        Lm[~vis] = np.nan
        out[name] = (Pm.reshape(n_ep, m, n_freq), Lm.reshape(n_ep, m, n_freq))
    lli = {k: np.zeros((n_ep, m, n_freq), dtype=np.uint8) for k in out}
    for (ts, sat, f, cycles, flagged) in slips:
        i = sats.index(sat)
        k = t >= ts - 1e-9
        out["rover"][1][k, i, f] += cycles
        if flagged and k.any():
            lli["rover"][np.argmax(k), i, f] = 1
    signals = {(s, f): (f"C{b}X", f"L{b}X") for s in systems if s in CARRIER_BANDS_HZ
               for f, b in enumerate({"G": "125", "E": "157", "J": "125"}[s][:n_freq])}
    res = []
    for name, pos0 in (("rover", P_r[0]), ("base", p_b)):
        Pm, Lm = out[name]
        res.append(CarrierObs(source=f"simulation ({name})", t_gps=t.copy(), sats=list(sats), freq_hz=freq.copy(),
                              P=Pm, L=Lm, D=np.full_like(Pm, np.nan), snr=np.full_like(Pm, np.nan), lli=lli[name],
                              signals=dict(signals), p_approx_ecef=pos0 + rng.normal(0, 2.0, 3),
                              power_failure=np.zeros(n_ep, dtype=bool),
                              truth={"p_ecef": P_r.copy()} if name == "rover" else {"p_ecef": p_b.copy()}))
    return res[0], res[1], nav


# ------------------------------------------------------------ rover + base carrier phase (TC, campaign, tests)
# RINEX 3 (code, phase) per system and frequency slot (the slots of dgcal.pos.gnss.carrier.BANDS)
CARRIER_SIGNALS = {"G": (("C1C", "L1C"), ("C2W", "L2W"), ("C5Q", "L5Q")),
                   "E": (("C1C", "L1C"), ("C5Q", "L5Q"), ("C7Q", "L7Q")),
                   "J": (("C1C", "L1C"), ("C2L", "L2L"), ("C5Q", "L5Q"))}


@dataclass
class CarrierErrorModel:
    """Errors of the rover + base carrier simulator: zenith sigmas (m, m/s) with the elevation law of
    `code_sigma_m`, correlation times (s).

    Per receiver, satellite and frequency: white noise plus a first-order Gauss-Markov multipath error (code and
    phase independently; the base's multipath is `base_multipath_scale` times the rover's, a static site with
    a better antenna). Atmosphere left after the models of the PPK/TC front end: a slant ionosphere gradient
    per satellite (`iono_gradient_ppm` mm per km of horizontal distance from the base at L1, times the
    elevation mapping 1/sin el) and a rover zenith troposphere residual (`tropo_zenith_residual_m`, drawn once,
    mapped 1/sin el). Doppler: white, `doppler_mps`.
    """

    code_white_m: float = 0.15
    code_mp_m: float = 0.26
    code_mp_tau_s: float = 30.0
    phase_white_m: float = 0.0018
    phase_mp_m: float = 0.0024
    phase_mp_tau_s: float = 10.0
    doppler_mps: float = 0.05
    base_multipath_scale: float = 1.0
    iono_gradient_ppm: float = 0.5
    tropo_zenith_residual_m: float = 0.0015

    def as_dict(self) -> dict:
        """The model as a JSON-ready dict."""
        return dict(self.__dict__)


@dataclass
class CarrierSimulation:
    """Simulated rover and base observations (`CarrierObs`, code m, phase cycles, Doppler Hz) and their truth.

    `truth`: rover antenna ECEF per epoch (m), base ECEF (m), receiver clocks (s), the slips applied
    [(t_gps, sat, slot, cycles, flagged)], the loss-of-lock restarts [(t_gps, sat)], the error model.
    """

    rover: CarrierObs
    base: CarrierObs
    nav: BroadcastNav
    base_ecef: np.ndarray
    truth: dict


def _gauss_markov(n_ep: int, shape: tuple, dt: np.ndarray, tau_s: float, rng) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov sequences (n_ep, *shape) with correlation time tau_s (s)."""
    out = np.empty((n_ep, *shape))
    out[0] = rng.standard_normal(shape)
    if tau_s <= 0:
        out[1:] = rng.standard_normal((n_ep - 1, *shape))
        return out
    for k in range(1, n_ep):
        rho = np.exp(-dt[k] / tau_s)
        out[k] = rho * out[k - 1] + np.sqrt(1.0 - rho * rho) * rng.standard_normal(shape)
    return out


def _receiver_geometry(nav, sats, t, pos, vel, bias, elev_mask_deg):
    """Exact ranges, range rates, elevations/azimuths, satellite clocks of every (epoch, satellite) of a receiver.

    pos/vel (n_ep,3) antenna ECEF at the time tags t (receiver time: true time = t - bias). Returns arrays
    (n_ep, m): rho (m), rr (m/s), el, az (rad), dts (s), ddts (s/s), visible; and the receiver llh (n_ep,3).
    """
    n_ep, m = len(t), len(sats)
    t_true = t - bias
    p_rx = pos - vel * bias[:, None]
    K = np.repeat(np.arange(n_ep), m)
    S = list(sats) * n_ep
    t_s0 = t_true[K] - 0.075
    ps, vs, clk_s, clk_d, ura, ok = satellite_states(nav, S, t_s0)
    ps = np.where(ok[:, None], ps, 2.6e7)
    vs = np.where(ok[:, None], vs, 0.0)
    acc = _ecef_acceleration(ps, vs)
    rho, tau, prot = _range_at(ps, vs, acc, t_s0, p_rx[K], t_true[K])
    h_d = 0.01
    rho_p, _, _ = _range_at(ps, vs, acc, t_s0, p_rx[K] + vel[K] * h_d, t_true[K] + h_d)
    rho_m, _, _ = _range_at(ps, vs, acc, t_s0, p_rx[K] - vel[K] * h_d, t_true[K] - h_d)
    rr = (rho_p - rho_m) / (2 * h_d)
    llh = ecef_to_geodetic(p_rx).reshape(n_ep, 3)
    R_ecef_to_local_enu = R_ecef_to_enu(llh[:, 0], llh[:, 1]).reshape(n_ep, 3, 3)
    d = prot - p_rx[K]
    e = np.einsum("nij,nj->ni", R_ecef_to_local_enu[K], d / np.linalg.norm(d, axis=1, keepdims=True))
    el = np.arcsin(np.clip(e[:, 2], -1, 1))
    az = np.mod(np.arctan2(e[:, 0], e[:, 1]), 2 * np.pi)
    dts = clk_s + clk_d * ((t_true[K] - tau) - t_s0)
    vis = ok & (el >= np.radians(elev_mask_deg))
    shp = (n_ep, m)
    return (rho.reshape(shp), rr.reshape(shp), el.reshape(shp), az.reshape(shp), dts.reshape(shp),
            clk_d.reshape(shp), vis.reshape(shp), llh, p_rx)


def simulate_rover_base(t_gps: np.ndarray, p_rover_ecef: np.ndarray, v_rover_ecef: np.ndarray,
                        base_ecef: np.ndarray, nav=None, seed: int = 0, errors: CarrierErrorModel | None = None,
                        systems=("G", "E"), n_freq: int = 2, elev_mask_deg: float = 10.0,
                        outages: list[tuple[float, float, int]] = (),
                        slips: list[tuple[float, str, int, int, bool]] = (), n_random_slips: int = 0,
                        rover_clock: RxClock | None = None, base_clock: RxClock | None = None,
                        rover_mask=None, doppler: bool = True, half_cycle_share: float = 0.0,
                        half_cycle_s: float = 6.0) -> CarrierSimulation:
    """Code, carrier phase, Doppler and C/N0 of a moving rover antenna and a static base (GPS s, ECEF m, m/s).

    Per receiver r, satellite and frequency slot f (GPS L1 L2 L5, Galileo E1 E5a E5b, QZSS L1 L2 L5)::

        P = rho + c (dt_r - dt_sat) + isb + T + I_f + e_P
        L = (rho + c (dt_r - dt_sat) + T - I_f + e_L) / lam_f + N + phi_r

    with the exact light-time range (`_range_at`, Earth rotation), receiver clocks as `RxClock` random walks
    (the antenna is where it was at the true time t_tag - dt_r), Saastamoinen with the standard atmosphere
    (70 % humidity) and Klobuchar at each receiver plus the residuals and errors of `CarrierErrorModel`, one
    integer N per phase arc (a new one after every loss of lock) and a fractional receiver phase offset phi_r
    per system and slot. `outages` (t0, t1, max_sats): inside [t0, t1] the rover keeps only the `max_sats`
    satellites that were highest at t0 (0 = nothing); a satellite it loses starts a new arc with the
    loss-of-lock indicator when it comes back. `slips` (t_gps, sat, slot, cycles, flagged) add cycles to the
    rover phase from t_gps on (LLI 1 at that epoch if flagged); `n_random_slips` more are drawn (half flagged).
    `rover_mask(el, az)` (rad, (n_ep, m) arrays of the rover) returns what the rover's antenna can see beside the
    elevation mask (an airframe in a bank, buildings); `doppler` False: a receiver that outputs no Doppler;
    `half_cycle_share`: that share of the rover's arcs after the first epoch start with the half-cycle ambiguity
    unresolved for `half_cycle_s` (phase 0.5 cycle off, LLI bit 1), then corrected (bit 1 cleared).
    """
    err = errors or CarrierErrorModel()
    rng = np.random.default_rng(seed)
    t = np.asarray(t_gps, float)
    n_ep = len(t)
    nav = _load_nav(nav, (t[0], t[-1]), tuple(s for s in systems if s in "GEC"), seed)
    P_r = np.asarray(p_rover_ecef, float).reshape(-1, 3)
    V_r = np.asarray(v_rover_ecef, float).reshape(-1, 3)
    p_b = np.asarray(base_ecef, float).reshape(3)
    sats = sorted(s for s in nav.by_sat if s[0] in systems and s[0] in CARRIER_SIGNALS)
    m, F = len(sats), int(n_freq)
    sysv = np.array([s[0] for s in sats])
    freq = np.array([[signal_frequency_hz(s[0], CARRIER_SIGNALS[s[0]][f][0]) for f in range(F)] for s in sats])
    lam = C_LIGHT / freq
    dt = np.r_[1.0, np.diff(t)]
    clocks = {"rover": rover_clock or RxClock(), "base": base_clock or RxClock(bias_s=-1.2e-5, drift=-3e-8)}
    enu_b = LocalENU(*ecef_to_geodetic(p_b).reshape(3))
    g_iono = rng.normal(0.0, err.iono_gradient_ppm * 1e-6, (m, 2))          # m of slant delay per m, L1
    tropo_res = rng.normal(0.0, err.tropo_zenith_residual_m)
    out, vis_r = {}, None
    truth_clk = {}
    for name, pos, vel in (("rover", P_r, V_r), ("base", np.repeat(p_b[None], n_ep, 0), np.zeros((n_ep, 3)))):
        clk = clocks[name]
        bias, drift = _clock_series(t, clk, rng)
        truth_clk[name] = {"bias_s": bias, "drift": drift}
        rho, rr, el, az, dts, ddts, vis, llh, p_rx = _receiver_geometry(nav, sats, t, pos, vel, bias,
                                                                          elev_mask_deg)
        tropo = saastamoinen_delay_m(llh[:, 0:1], llh[:, 2:3], el, humidity=0.7)
        mapping = 1.0 / np.sin(np.maximum(el, np.radians(3.0)))
        iono1 = np.stack([klobuchar_delay_m(t[k], llh[k, 0], llh[k, 1], el[k], az[k], nav.ion_gps)
                          for k in range(n_ep)])
        if name == "rover":
            tropo = tropo + tropo_res * mapping
            d_en = enu_b.from_ecef(p_rx)[:, :2]                                 # horizontal offset from the base
            iono1 = iono1 + mapping * (d_en @ g_iono.T)
        isb = np.array([clk.isb_m.get(s, 0.0) for s in sysv])
        geo = rho + C_LIGHT * (bias[:, None] - dts) + tropo                     # (n_ep, m)
        mp = 1.0 if name == "rover" else err.base_multipath_scale
        sig_el = code_sigma_m(el, 1.0)[:, :, None]                              # elevation factor
        n_code = sig_el * (err.code_white_m * rng.standard_normal((n_ep, m, F))
                           + mp * err.code_mp_m * _gauss_markov(n_ep, (m, F), dt, err.code_mp_tau_s, rng))
        n_phase = sig_el * (err.phase_white_m * rng.standard_normal((n_ep, m, F))
                            + mp * err.phase_mp_m * _gauss_markov(n_ep, (m, F), dt, err.phase_mp_tau_s, rng))
        iono = iono1[:, :, None] * (1575.42e6 / freq[None]) ** 2
        P = geo[:, :, None] + isb[None, :, None] + iono + n_code
        Lm = geo[:, :, None] - iono + n_phase                                    # metres, before N
        rr_meas = rr + C_LIGHT * (drift[:, None] - ddts)
        D = -(rr_meas[:, :, None] + err.doppler_mps * sig_el * rng.standard_normal((n_ep, m, F))) / lam[None]
        snr = np.repeat((30.0 + 20.0 * np.sin(el))[:, :, None], F, axis=2)
        out[name] = dict(P=P, L=Lm / lam[None], D=D, snr=np.round(snr, 3), vis=vis, el=el)
        if name == "rover":
            vis_r = vis.copy() if rover_mask is None else vis & rover_mask(el, az)
            if not doppler:
                out[name]["D"] = np.full_like(D, np.nan)
    out["rover"]["vis"] = _rover_outages(vis_r, out["rover"]["el"], t, outages)
    restarts = _phase_arcs(out, t, sats, sysv, F, rng)
    half = _half_cycles(out["rover"], t, half_cycle_share, half_cycle_s, rng)
    truth_slips = _cycle_slips(out["rover"], t, sats, F, slips, n_random_slips, rng)
    signals = {(s, f): CARRIER_SIGNALS[s][f] for s in systems if s in CARRIER_SIGNALS for f in range(F)}
    res = {name: _carrier_obs(name, out[name], t, sats, freq, signals, pos0, P_r if name == "rover" else p_b, rng)
           for name, pos0 in (("rover", P_r[0]), ("base", p_b))}
    truth = {"t_gps": t, "p_ecef": P_r, "v_ecef": V_r, "base_ecef": p_b, "clock": truth_clk,
             "slips": truth_slips, "restarts": restarts, "half_cycles": half, "errors": err.as_dict(),
             "tropo_zenith_residual_m": float(tropo_res), "outages": [list(o) for o in outages]}
    return CarrierSimulation(res["rover"], res["base"], nav, p_b, truth)


def _rover_outages(vis: np.ndarray, el: np.ndarray, t: np.ndarray, outages) -> np.ndarray:
    """Visibility (n_ep, m) with the rover keeping, inside each outage (t0, t1, max_sats), only the `max_sats`
    satellites that were highest at t0."""
    vis = vis.copy()
    m = vis.shape[1]
    for (a, b, nmax) in outages:
        kk = np.nonzero((t >= a - 1e-9) & (t <= b + 1e-9))[0]
        if len(kk) == 0:
            continue
        el0 = np.where(vis[kk[0]], el[kk[0]], -np.inf)
        keep = np.argsort(-el0)[:int(nmax)] if nmax > 0 else np.array([], int)
        mask = np.zeros(m, bool)
        mask[keep] = True
        vis[kk] &= mask[None]
    return vis


def _phase_arcs(out: dict, t: np.ndarray, sats: list, sysv: np.ndarray, F: int, rng) -> list:
    """Integer ambiguities per phase arc and a receiver phase offset per system and slot added to each receiver's
    phase (cycles), loss-of-lock indicators at every restart; returns the rover's restarts (t, sat)."""
    restarts = []
    m = len(sats)
    phase_offset = {name: {s: rng.uniform(0, 1, F) for s in sorted(set(sysv))} for name in out}
    for name, o in out.items():
        vis = o["vis"]
        n_ep = vis.shape[0]
        start = vis & ~np.vstack([np.zeros((1, m), bool), vis[:-1]])           # first epoch of every arc
        arc = np.cumsum(start, axis=0)                                          # arc number per (epoch, sat)
        N = rng.integers(-10 ** 6, 10 ** 6, size=(int(arc.max()) + 1, m, F)).astype(float)
        L = o["L"] + N[arc, np.arange(m)[None, :], :]
        L = L + np.stack([phase_offset[name][s] for s in sysv])[None]
        lli = np.zeros((n_ep, m, F), dtype=np.uint8)
        restart = start.copy()
        restart[0] = False
        lli[restart] = 1
        if name == "rover":
            restarts = [(float(t[k]), sats[i]) for k, i in zip(*np.nonzero(restart))]
        o.update(L=L, lli=lli)
    return restarts


def _half_cycles(rover: dict, t: np.ndarray, share: float, duration_s: float, rng) -> int:
    """Half-cycle ambiguities: `share` of the arcs that start after the first epoch get +0.5 cycle and LLI bit 1 for
    their first `duration_s` (every slot), as a receiver's phase before it resolves the navigation-bit sign; the
    number of such arcs."""
    if share <= 0:
        return 0
    vis = rover["vis"]
    start = vis & ~np.vstack([np.ones((1, vis.shape[1]), bool), vis[:-1]])
    n = 0
    for k, i in zip(*np.nonzero(start)):
        if rng.uniform() >= share:
            continue
        kk = k + np.nonzero(vis[k:, i].cumprod() & (t[k:] < t[k] + duration_s))[0]
        rover["L"][kk, i, :] += 0.5
        rover["lli"][kk, i, :] |= 2
        n += 1
    return n


def _cycle_slips(rover: dict, t: np.ndarray, sats: list, F: int, slips, n_random: int, rng) -> list:
    """Add the cycle slips `slips` (t_gps, sat, slot, cycles, flagged) and `n_random` drawn ones (half flagged) to
    the rover's phase from their epoch on, LLI 1 at the flagged ones; returns them all."""
    slip_list = list(slips)
    if n_random:
        cand = np.argwhere(rover["vis"][5:-5]) + [5, 0]
        pick = cand[rng.choice(len(cand), size=min(n_random, len(cand)), replace=False)]
        for q, (k, i) in enumerate(pick):
            cyc = int(rng.integers(1, 20)) * int(rng.choice([-1, 1]))
            slip_list.append((float(t[k]), sats[i], int(rng.integers(0, F)), cyc, bool(q % 2 == 0)))
    truth = []
    for (ts, sat, f, cycles, flagged) in slip_list:
        i = sats.index(sat)
        k = t >= ts - 1e-9
        rover["L"][k, i, f] += cycles
        if flagged and k.any():
            rover["lli"][np.argmax(k), i, f] |= 1
        truth.append((float(ts), sat, int(f), int(cycles), bool(flagged)))
    return truth


def _carrier_obs(name: str, o: dict, t: np.ndarray, sats: list, freq: np.ndarray, signals: dict,
                 pos0: np.ndarray, p_true: np.ndarray, rng) -> CarrierObs:
    """The CarrierObs of one receiver: observations hidden where the satellite is not tracked, an approximate
    header position 2 m off the true one."""
    F = freq.shape[1]
    hide = ~o["vis"][:, :, None].repeat(F, axis=2)
    arrs = {}
    for key in ("P", "L", "D", "snr"):
        a = o[key].copy()
        a[hide] = np.nan
        arrs[key] = a
    lli = o["lli"].copy()
    lli[hide] = 0
    n_ep = len(t)
    return CarrierObs(source=f"simulation ({name})", t_gps=t.copy(), sats=list(sats), freq_hz=freq.copy(),
                      P=arrs["P"], L=arrs["L"], D=arrs["D"], snr=arrs["snr"], lli=lli,
                      signals=dict(signals), p_approx_ecef=pos0 + rng.normal(0, 2.0, 3),
                      receiver="DGCAL SIM", antenna="SIM", power_failure=np.zeros(n_ep, dtype=bool),
                      epoch_line=np.arange(n_ep), truth={"p_ecef": p_true.copy()})
