"""Multi-frequency code and carrier phase of one receiver, its zero-difference model and cycle-slip flags.

``carrier_observations`` picks, per system and frequency band, the RINEX 3 signal (code + phase of
one attribute) with the most observations and returns them as ``CarrierObs`` arrays
``[epoch, satellite, slot]``. Slots are frequency bands in the order of ``BANDS``: GPS/QZSS L1, L2,
L5; Galileo E1, E5a, E5b; BeiDou B1I, B2I/B2b, B3I. One attribute per receiver, system and band is
used for all satellites, so receiver-side signal biases (and RINEX 3 phase alignment shifts) are the
same for all satellites of a double difference and cancel.

``zero_difference`` models one epoch at a receiver position: satellite states at transmission from
the pseudorange (dgcal.pos.gnss.ephemeris, Sagnac rotation into the ECEF frame at reception),
Saastamoinen troposphere and Klobuchar ionosphere (scaled to each frequency, + on code, - on phase).
Observed-minus-computed values (m)::

    omc_code  = P       - (rho - c*dt_sat + T + I_f)
    omc_phase = lam*L   - (rho - c*dt_sat + T - I_f)

(compiled per satellite in ``dgcal.pos.gnss.carrier_model``; a receiver at one place, the base, is modelled for
all its epochs in one call).
``slip_flags`` marks, per receiver, the observations whose carrier phase may have slipped since the
previous observation of the same satellite and slot: loss-of-lock indicator (bit 0), an epoch flag
1 (power failure), a data gap, a jump of the geometry-free combination or of the Melbourne-Wuebbena
wide-lane (against the running mean of the arc).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from dgcal.fields.constants import C_LIGHT
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.gnss.carrier_model import at_reception, zero_difference_rows
from dgcal.pos.gnss.ephemeris import states_at_transmission
from dgcal.pos.gnss.observations import GnssEpoch, GnssObservations
from dgcal.pos.gnss.rinex import BroadcastNav, calendar_from_gps_seconds
from dgcal.pos.gnss.rinex_obs import RinexObsFile

BANDS = {"G": ("1", "2", "5"), "J": ("1", "2", "5"), "E": ("1", "5", "7"), "C": ("2", "7", "6")}
BAND_FREQ_HZ = {
    ("G", "1"): 1575.42e6, ("G", "2"): 1227.60e6, ("G", "5"): 1176.45e6,
    ("J", "1"): 1575.42e6, ("J", "2"): 1227.60e6, ("J", "5"): 1176.45e6, ("J", "6"): 1278.75e6,
    ("E", "1"): 1575.42e6, ("E", "5"): 1176.45e6, ("E", "7"): 1207.14e6, ("E", "8"): 1191.795e6,
    ("E", "6"): 1278.75e6,
    ("C", "2"): 1561.098e6, ("C", "7"): 1207.14e6, ("C", "6"): 1268.52e6, ("C", "1"): 1575.42e6,
    ("C", "5"): 1176.45e6, ("C", "8"): 1191.795e6,
}
# attribute preference per band when two attributes are equally complete
ATTR_PRIORITY = "CWPYXLSQIDBZMNA"


@dataclass
class CarrierObs:
    """Code (m), phase (cycles), Doppler (Hz), C/N0 and LLI of one receiver as ``[epoch, sat, slot]`` arrays.

    ``freq_hz[sat, slot]`` is NaN where the system has no such slot; ``signals[(system, slot)]`` the
    RINEX 3 code and phase used (e.g. ``('C1C', 'L1C')``). ``power_failure``: epoch flag 1.
    """

    source: str
    t_gps: np.ndarray
    sats: list[str]
    freq_hz: np.ndarray
    P: np.ndarray
    L: np.ndarray
    D: np.ndarray
    snr: np.ndarray
    lli: np.ndarray
    signals: dict[tuple[str, int], tuple[str, str]]
    p_approx_ecef: np.ndarray
    receiver: str = ""
    antenna: str = ""
    power_failure: np.ndarray | None = None
    epoch_line: np.ndarray | None = None
    truth: dict | None = None

    @property
    def n_slots(self) -> int:
        """Number of frequency slots (columns of the last axis)."""
        return self.P.shape[2]

    @property
    def system(self) -> np.ndarray:
        """System letter of every satellite."""
        return np.array([s[0] for s in self.sats])

    @property
    def wavelength_m(self) -> np.ndarray:
        """Carrier wavelength (m) per satellite and slot (NaN where no slot)."""
        return C_LIGHT / self.freq_hz


def _pick_attribute(so, band: str) -> tuple[str, str] | None:
    """(code, phase) of the attribute with the most complete phase + code of a band in one system."""
    best, best_n = None, 0
    for code in so.codes:
        if len(code) != 3 or code[0] != "C" or code[1] != band:
            continue
        ph = "L" + code[1:]
        if ph not in so.codes:
            continue
        v = so.val[:, :, so.column(code)]
        w = so.val[:, :, so.column(ph)]
        n = int(np.sum(np.isfinite(v) & np.isfinite(w)))
        rank = ATTR_PRIORITY.find(code[2]) if code[2] in ATTR_PRIORITY else len(ATTR_PRIORITY)
        key = (n, -rank)
        if n > 0 and (best is None or key > best_n):
            best, best_n = (code, ph), key
    return best


def carrier_observations(rx: RinexObsFile, systems: str = "GECJ", n_freq: int = 3) -> CarrierObs:
    """The code/phase arrays of a RINEX file for PPK: ``n_freq`` slots per system (see ``BANDS``)."""
    sats, freq, cols, signals = [], [], [], {}
    for s in "GECJ":
        if s not in systems or s not in rx.systems:
            continue
        so = rx.systems[s]
        picks = []
        for f, band in enumerate(BANDS[s][:n_freq]):
            pk = _pick_attribute(so, band)
            picks.append(pk)
            if pk is not None:
                signals[(s, f)] = pk
        if all(p is None for p in picks):
            continue
        for j, sid in enumerate(so.sats):
            sats.append(sid)
            freq.append([BAND_FREQ_HZ[(s, BANDS[s][f])] if f < len(picks) and picks[f] is not None else np.nan
                         for f in range(n_freq)])
            cols.append((so, j, picks))
    if not sats:
        raise InputError(f"no carrier-phase observations for systems {systems}", rx.path,
                         field="SYS / # / OBS TYPES" if rx.version >= 3 else "# / TYPES OF OBSERV")
    n_ep, m = len(rx.t_gps), len(sats)
    P = np.full((n_ep, m, n_freq), np.nan)
    L = np.full((n_ep, m, n_freq), np.nan)
    D = np.full((n_ep, m, n_freq), np.nan)
    S = np.full((n_ep, m, n_freq), np.nan)
    LLI = np.zeros((n_ep, m, n_freq), dtype=np.uint8)
    for i, (so, j, picks) in enumerate(cols):
        for f, pk in enumerate(picks):
            if pk is None:
                continue
            code, ph = pk
            P[:, i, f] = so.val[:, j, so.column(code)]
            L[:, i, f] = so.val[:, j, so.column(ph)]
            LLI[:, i, f] = so.lli[:, j, so.column(ph)]
            for arr, typ in ((D, "D"), (S, "S")):
                c = typ + code[1:]
                if c in so.codes:
                    arr[:, i, f] = so.val[:, j, so.column(c)]
    bad = ~(P > 1e6)
    P[bad] = np.nan
    return CarrierObs(source=rx.path, t_gps=rx.t_gps.copy(), sats=sats, freq_hz=np.array(freq, float), P=P, L=L,
                      D=D, snr=S, lli=LLI, signals=signals, p_approx_ecef=rx.p_approx_ecef.copy(),
                      receiver=rx.receiver, antenna=rx.antenna, power_failure=rx.power_failure.copy(),
                      epoch_line=rx.epoch_line.copy())


@dataclass
class ZeroDiff:
    """One receiver epoch modelled at ``p_rx``: per satellite (m,) and slot (m, F) arrays.

    ``ok``: satellite has ephemeris and a code; ``sat_pos`` (ECEF at reception, m), ``los`` (unit
    vectors receiver->satellite), ``rho`` (m), ``elev``/``azim`` (rad), ``tropo`` (m), ``iono`` (m,
    per slot), ``omc_code``/``omc_phase`` (m, per slot; NaN where not observed).
    """

    ok: np.ndarray
    sat_pos: np.ndarray
    sat_vel: np.ndarray
    sat_clk_s: np.ndarray
    rho: np.ndarray
    los: np.ndarray
    elev: np.ndarray
    azim: np.ndarray
    tropo: np.ndarray
    iono: np.ndarray
    omc_code: np.ndarray
    omc_phase: np.ndarray
    extra: dict = field(default_factory=dict)

    def epoch(self, q: int) -> "ZeroDiff":
        """Epoch q of a model of many epochs (views of its rows)."""
        return ZeroDiff(*(getattr(self, name)[q] for name in _ZD_ARRAYS))


_ZD_ARRAYS = ("ok", "sat_pos", "sat_vel", "sat_clk_s", "rho", "los", "elev", "azim", "tropo", "iono", "omc_code",
              "omc_phase")


def first_code(P: np.ndarray) -> np.ndarray:
    """The first finite code (m) of every satellite over the frequency slots (last axis), NaN where none."""
    pr0 = np.full(P.shape[:-1], np.nan)
    for f in range(P.shape[-1]):
        pr0 = np.where(np.isfinite(pr0), pr0, P[..., f])
    return pr0


def transmission_states(nav: BroadcastNav, sats: list[str], t_rx: np.ndarray, pr_m: np.ndarray):
    """Satellite states at transmission of every epoch at once (`states_at_transmission` of all (epoch,
    satellite) pairs with a code, unrotated ECEF): position, velocity (E,m,3) m, m/s, clock (E,m) s and validity
    (E,m); NaN / False where the epoch has no code of the satellite. Row by row as `satellite_geometry` needs."""
    E, m = pr_m.shape
    pos = np.full((E, m, 3), np.nan)
    vel = np.full((E, m, 3), np.nan)
    clk = np.full((E, m), np.nan)
    good = np.zeros((E, m), bool)
    e, i = np.nonzero(np.isfinite(pr_m))
    if len(e):
        p, v, c, _d, _u, ok = states_at_transmission(nav, [sats[j] for j in i], np.asarray(t_rx, float)[e],
                                                     pr_m[e, i])
        pos[e, i], vel[e, i], clk[e, i], good[e, i] = p, v, c, ok
    return pos, vel, clk, good


def satellite_geometry(nav: BroadcastNav, sats: list[str], t_rx, pr_m: np.ndarray, p_rx: np.ndarray,
                       states: tuple | None = None):
    """Satellite position/velocity (ECEF at reception, Sagnac-rotated), clock (s) and validity for one epoch
    (`t_rx` s, `pr_m` (m,)), or for many epochs of a receiver at one place at once (`t_rx` (E,), `pr_m` (E,m));
    `states`: these epochs' rows of `transmission_states` (position, velocity, clock, validity), computed already.
    NaN / False where the epoch has no code of the satellite or no ephemeris."""
    if states is None:
        states = transmission_states(nav, sats, np.atleast_1d(np.asarray(t_rx, float)), np.atleast_2d(pr_m))
        states = tuple(a.reshape(np.shape(pr_m) + a.shape[2:]) for a in states)
    p, v, clk, good = states
    pos, vel = at_reception(np.ascontiguousarray(p).reshape(-1, 3), np.ascontiguousarray(v).reshape(-1, 3),
                            np.asarray(p_rx, float))
    pos, vel = pos.reshape(p.shape), vel.reshape(v.shape)
    return pos, vel, np.array(clk, float), good & np.all(np.isfinite(pos), axis=-1)


def zero_difference(nav: BroadcastNav, sats: list[str], t_rx, P: np.ndarray, L: np.ndarray,
                    freq_hz: np.ndarray, p_rx: np.ndarray, geometry=None, humidity: float = 0.7) -> ZeroDiff:
    """Model one epoch of one receiver at ``p_rx`` (ECEF m): ranges, atmosphere, observed-minus-computed (m).

    ``P`` (m, F) code in metres, ``L`` (m, F) phase in cycles, ``freq_hz`` (m, F). ``geometry``: the
    ``satellite_geometry`` result to reuse (satellite states do not depend on ``p_rx`` beyond the
    Sagnac rotation, which changes < 0.1 mm for 100 m). Many epochs of a receiver at one place at once: `t_rx`
    (E,), ``P``, ``L`` (E, m, F) and the geometry of these epochs give arrays with a leading epoch axis.
    """
    pos, vel, clk, ok = geometry if geometry is not None else satellite_geometry(nav, sats, t_rx, first_code(P), p_rx)
    ion = nav.ion_gps
    has_ion = ion is not None and bool(np.asarray(ion).any())
    shape = ok.shape
    F = freq_hz.shape[-1]
    rows = zero_difference_rows(pos.reshape(-1, 3), clk.reshape(-1), ok.reshape(-1), P.reshape(-1, F),
                                L.reshape(-1, F), np.ascontiguousarray(freq_hz, float), np.asarray(p_rx, float),
                                np.asarray(t_rx, float).reshape(-1),
                                np.asarray(ion, float) if has_ion else np.zeros((2, 4)), has_ion, float(humidity))
    rho, los, elev, azim, tropo, iono, omc_code, omc_phase = (a.reshape(shape + a.shape[1:]) for a in rows)
    return ZeroDiff(ok, pos, vel, clk, rho, los, elev, azim, tropo, iono, omc_code, omc_phase)


def slip_flags(obs: CarrierObs, gf_threshold_m: float = 0.05, mw_threshold_cycles: float = 4.0,
               max_gap_s: float = 30.0) -> np.ndarray:
    """Possible cycle slips ``[epoch, sat, slot]``: the phase may have jumped since the previous observation.

    Flags: LLI bit 0; a change of LLI bit 1 (half cycle resolved, or lost); epoch flag 1 (power failure: all phases);
    a gap > ``max_gap_s`` since the previous
    phase of the same satellite and slot; a geometry-free (``lam1 L1 - lamk Lk``, m) change > the
    threshold (scaled up for gaps over 1 s, to allow for the ionosphere's rate); a Melbourne-Wuebbena
    wide-lane jump > ``mw_threshold_cycles`` times its scatter along the arc (at least 1 cycle + 4 sigma
    of the epoch noise). GF/MW flags mark all slots of the satellite pair concerned.
    """
    n, m, F = obs.L.shape
    t = obs.t_gps
    have = np.isfinite(obs.L)
    slip = (obs.lli & 1).astype(bool) & have
    # LLI bit 1 (half-cycle ambiguity not resolved) set or cleared since the previous observation: a receiver that
    # resolves the half cycle corrects its phase by half a cycle, which neither GF nor MW sees on every frequency
    half = (obs.lli & 2).astype(bool)
    for f in range(F):
        slip[:, :, f] |= _half_cycle_changes(have[:, :, f], half[:, :, f])
    if obs.power_failure is not None and obs.power_failure.any():
        slip |= obs.power_failure[:, None, None] & have
    lam = C_LIGHT / obs.freq_hz                                  # (m, F)
    for i in range(m):
        for f in range(F):
            k = np.nonzero(have[:, i, f])[0]
            if len(k) == 0:
                continue
            slip[k[0], i, f] = True                                # the start of an arc
            gap = np.diff(t[k]) > max_gap_s
            slip[k[1:][gap], i, f] = True
        for f in range(1, F):
            if not (np.isfinite(lam[i, 0]) and np.isfinite(lam[i, f])):
                continue
            k = np.nonzero(have[:, i, 0] & have[:, i, f])[0]
            if len(k) < 2:
                continue
            gf = lam[i, 0] * obs.L[k, i, 0] - lam[i, f] * obs.L[k, i, f]
            dt = np.diff(t[k])
            jump = np.abs(np.diff(gf)) > gf_threshold_m * np.maximum(1.0, np.sqrt(dt))
            f0, f1 = obs.freq_hz[i, 0], obs.freq_hz[i, f]
            lam_wl = C_LIGHT / (f0 - f1)
            p_ok = np.isfinite(obs.P[k, i, 0]) & np.isfinite(obs.P[k, i, f])
            mw = ((obs.L[k, i, 0] - obs.L[k, i, f])
                  - (f0 * obs.P[k, i, 0] + f1 * obs.P[k, i, f]) / (f0 + f1) / lam_wl)
            restart = slip[k, i, 0] | slip[k, i, f]
            restart[0] = True
            restart[1:] |= jump
            bad = np.nonzero(jump | _mw_jumps(mw, p_ok, restart, mw_threshold_cycles))[0] + 1
            slip[k[bad], i, 0] = True
            slip[k[bad], i, f] = True
    return slip


def _half_cycle_changes(have: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(epoch, sat): the half-cycle flag differs from the one of the previous observation of the satellite."""
    idx = np.where(have, np.arange(len(have))[:, None], -1)
    prev = np.maximum.accumulate(np.vstack([np.full((1, have.shape[1]), -1), idx[:-1]]), axis=0)
    before = np.take_along_axis(half, np.maximum(prev, 0), axis=0)
    return have & (prev >= 0) & (before != half)


@njit(cache=True)
def _mw_jumps(mw: np.ndarray, p_ok: np.ndarray, restart: np.ndarray, threshold: float):  # pragma: no cover
    """Melbourne-Wuebbena jumps between consecutive observations j-1, j of an arc (cycles): |mw_j - running mean|
    beyond `threshold` times the running scatter (at least 1 cycle + 4 sigma of the epoch noise) once 5 values
    are averaged; the mean restarts at `restart` and after a jump; epochs without both codes (`p_ok`) skipped."""
    jump = np.zeros(len(mw) - 1, np.bool_)
    mean, m2, cnt = 0.0, 0.0, 0
    for j in range(len(mw)):
        if restart[j]:
            mean, m2, cnt = 0.0, 0.0, 0
        if not p_ok[j]:
            continue
        if cnt >= 5:
            sd = math.sqrt(m2 / (cnt - 1)) if cnt > 1 else 0.0
            if abs(mw[j] - mean) > max(threshold * sd, 1.0 + 4.0 * 0.15):
                jump[j - 1] = True
                mean, m2, cnt = 0.0, 0.0, 0
        cnt += 1
        dlt = mw[j] - mean
        mean += dlt / cnt
        m2 += dlt * (mw[j] - mean)
    return jump


def code_observations(obs: CarrierObs, slot: int = 0) -> GnssObservations:
    """The single-frequency code, Doppler and C/N0 of slot `slot` as raw `GnssObservations` (SPP, code TC):
    what `dgcal.pos.gnss.rinex.read_rinex_obs` would read from the same data (front-end fields NaN)."""
    epochs = []
    lam = C_LIGHT / obs.freq_hz[:, slot]
    sysv = obs.system
    for k in range(len(obs.t_gps)):
        i = np.nonzero(np.isfinite(obs.P[k, :, slot]) & np.isfinite(lam))[0]
        if len(i) == 0:
            continue
        n = len(i)
        nan = np.full(n, np.nan)
        dop = obs.D[k, i, slot]
        epochs.append(GnssEpoch(
            t_gps=float(obs.t_gps[k]), sat=[obs.sats[j] for j in i], system=sysv[i], pr_m=obs.P[k, i, slot].copy(),
            doppler_hz=dop.copy(), range_rate_mps=-lam[i] * dop, wavelength_m=lam[i].copy(),
            cn0_dbhz=obs.snr[k, i, slot].copy(), sat_pos_ecef=np.full((n, 3), np.nan),
            sat_vel_ecef=np.full((n, 3), np.nan), sat_clk_s=nan.copy(), sat_clk_drift=nan.copy(),
            iono_m=nan.copy(), tropo_m=nan.copy(), elev_deg=nan.copy(), azim_deg=nan.copy(),
            sigma_pr_m=nan.copy(), sigma_rr_mps=nan.copy()))
    signals = {s: obs.signals[(s, slot)][0] for s in dict.fromkeys(sysv) if (s, slot) in obs.signals}
    return GnssObservations(epochs=epochs, receiver=obs.receiver, p_approx_ecef=obs.p_approx_ecef.copy(),
                            signals=signals, source=obs.source)


def _glonass_channel(obs: CarrierObs, i: int) -> int:
    """Frequency channel of GLONASS satellite `i` from its G1 (or G2) carrier frequency."""
    for f in range(obs.n_slots):
        band = obs.signals.get(("R", f), ("C1C",))[0][1]
        if np.isfinite(obs.freq_hz[i, f]):
            base, step = (1602.0e6, 0.5625e6) if band == "1" else (1246.0e6, 0.4375e6)
            return int(round((obs.freq_hz[i, f] - base) / step))
    return 0


def write_rinex_carrier(path, obs: CarrierObs, marker: str = "DGCAL", comment: str = "simulated by dgcal") -> None:
    """Write code (m), carrier phase (cycles, with the loss-of-lock indicator), Doppler (Hz) and C/N0 of every
    slot of ``obs`` (its ``signals``) as a RINEX 3.04 observation file (atomic write); NaN is left blank."""
    systems = [s for s in "GRECJSI" if any(sid[0] == s for sid in obs.sats)]
    types, slots = {}, {}
    for s in systems:
        fs = [f for f in range(obs.n_slots) if (s, f) in obs.signals]
        slots[s] = fs
        types[s] = [c for f in fs for c in (obs.signals[(s, f)][0], obs.signals[(s, f)][1],
                                            "D" + obs.signals[(s, f)][0][1:], "S" + obs.signals[(s, f)][0][1:])]
    p0 = obs.p_approx_ecef if np.all(np.isfinite(obs.p_approx_ecef)) else np.zeros(3)

    def hdr(text: str, label: str) -> str:
        return f"{text:<60.60}{label:<20}\n"

    t = obs.t_gps
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    lines = [hdr(f"{3.04:9.2f}{'':11}{'OBSERVATION DATA':<20}{'M':<20}", "RINEX VERSION / TYPE"),
             hdr(f"{'dgcal':<20}{'dgcal':<40}", "PGM / RUN BY / DATE"),
             hdr(comment, "COMMENT"), hdr(marker, "MARKER NAME"),
             hdr(f"{'SIM':<20}{obs.receiver or 'DGCAL SIM':<20}{'':<20}", "REC # / TYPE / VERS"),
             hdr(f"{'SIM':<20}{obs.antenna or 'SIM':<20}", "ANT # / TYPE"),
             hdr(f"{p0[0]:14.4f}{p0[1]:14.4f}{p0[2]:14.4f}", "APPROX POSITION XYZ"),
             hdr(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N")]
    for s in systems:
        ty = types[s]
        for j in range(0, len(ty), 13):
            head = f"{s}{len(ty):5d}" if j == 0 else " " * 6
            lines.append(hdr(head + "".join(f" {c}" for c in ty[j:j + 13]), "SYS / # / OBS TYPES"))
    glo = [(sid, _glonass_channel(obs, i)) for i, sid in enumerate(obs.sats) if sid[0] == "R"]
    for j in range(0, len(glo), 8):      # GLONASS channels (u-blox logs; the simulator writes none)
        part = "".join(f"{sid} {k:2d} " for sid, k in glo[j:j + 8])
        lines.append(hdr((f"{len(glo):3d} " if j == 0 else "    ") + part, "GLONASS SLOT / FRQ #"))
    lines.append(hdr(f"{dt:10.3f}", "INTERVAL"))
    for tt, label in ((t[0], "TIME OF FIRST OBS"), (t[-1], "TIME OF LAST OBS")):
        y, mo, d, h, mi, sec = calendar_from_gps_seconds(tt)
        lines.append(hdr(f"{y:6d}{mo:6d}{d:6d}{h:6d}{mi:6d}{sec:13.7f}     GPS", label))
    lines.append(hdr("DBHZ", "SIGNAL STRENGTH UNIT"))
    lines.append(hdr("", "END OF HEADER"))
    col = {sid: i for i, sid in enumerate(obs.sats)}
    order = sorted(obs.sats, key=lambda sid: ("GRECJSI".index(sid[0]), sid))

    def val(v: float, lli: int = 0) -> str:
        if not math.isfinite(v):
            return " " * 16
        return f"{v:14.3f}{lli if lli else ' '} "

    # Python floats and ints per epoch: formatting numpy scalars one by one costs twice as much
    sat_slots = [(sid, col[sid], slots[sid[0]]) for sid in order]
    with atomic_write(path) as fh:
        fh.writelines(lines)
        for k in range(len(t)):
            P, L, D, S = (a[k].tolist() for a in (obs.P, obs.L, obs.D, obs.snr))
            lli = obs.lli[k].astype(int).tolist()
            rows = []
            for sid, i, fs in sat_slots:
                if not any(math.isfinite(P[i][f]) or math.isfinite(L[i][f]) for f in fs):
                    continue
                rec = "".join(val(P[i][f]) + val(L[i][f], lli[i][f]) + val(D[i][f]) + val(S[i][f]) for f in fs)
                rows.append(sid + rec.rstrip() + "\n")
            y, mo, d, h, mi, sec = calendar_from_gps_seconds(t[k])
            flag = 1 if obs.power_failure is not None and obs.power_failure[k] else 0
            fh.write(f"> {y:4d} {mo:02d} {d:02d} {h:02d} {mi:02d}{sec:11.7f}  {flag}{len(rows):3d}\n")
            fh.writelines(rows)
