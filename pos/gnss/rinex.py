"""RINEX observation and navigation files (2.10/2.11 and 3.x): reading for SPP/TC, writing simulated observations.

Observation files are read by ``dgcal.pos.gnss.rinex_obs.read_obs_file`` (every code of every
version); ``read_rinex_obs`` picks one code signal per constellation (single-frequency SPP/TC): GPS
and QZSS L1 C/A, Galileo E1, BeiDou B1I, each with its Doppler and C/N0 where present. Navigation
files are decoded by cssrlib's ``rnxdec`` (RINEX 2 GPS files are first laid out as RINEX 3 by
``dgcal.pos.gnss.rinex_nav``) through a line-counting wrapper, so that any decoding failure is
reported as ``InputError`` naming the file and line.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from cssrlib.gnss import Nav, gpst2time, sat2id, time2gpst
from cssrlib.rinex import rnxdec

from dgcal.fields.constants import C_LIGHT, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.gnss.glonass import F1_BASE_HZ, F1_STEP_HZ, GlonassEphemerides, glonass_frequency_hz
from dgcal.pos.gnss.observations import ALL_SYSTEMS, SYSTEMS, GnssEpoch, GnssObservations
from dgcal.pos.gnss.precise import product_kind, read_precise
from dgcal.pos.gnss.rinex_nav import ION_DEFAULT, nav_text_for_cssrlib
from dgcal.pos.gnss.rinex_obs import GLONASS_NOT_USED, RinexObsFile, read_obs_file

# Preferred code observations per system, best first (RINEX 3 codes).
CODE_PRIORITY = {
    "G": ("C1C", "C1W", "C1X", "C1L"),
    "J": ("C1C", "C1X", "C1L"),
    "E": ("C1C", "C1X", "C1B"),
    "C": ("C2I", "C1I", "C2X"),
    "R": ("C1C", "C1P"),
}
# The second code of each system for the dual-frequency ionosphere-free combination (first available; L1 as above).
CODE2_PRIORITY = {
    "G": ("C2W", "C2L", "C2S", "C2X", "C2P", "C2D", "C5Q", "C5X", "C5I"),
    "J": ("C2L", "C2S", "C2X", "C5Q", "C5X", "C5I"),
    "E": ("C5Q", "C5X", "C5I", "C7Q", "C7X", "C7I"),
    "R": ("C2C", "C2P"),
}
# Carrier frequency (Hz) by system and RINEX band digit.
FREQ_HZ = {
    ("G", "1"): 1575.42e6, ("G", "2"): 1227.60e6, ("G", "5"): 1176.45e6,
    ("J", "1"): 1575.42e6, ("J", "2"): 1227.60e6, ("J", "5"): 1176.45e6,
    ("E", "1"): 1575.42e6, ("E", "5"): 1176.45e6, ("E", "7"): 1207.14e6, ("E", "8"): 1191.795e6,
    ("C", "2"): 1561.098e6, ("C", "1"): 1561.098e6, ("C", "7"): 1207.14e6, ("C", "6"): 1268.52e6,
}
GPS_EPOCH = _dt.datetime(1980, 1, 6)


def signal_frequency_hz(system: str, code: str) -> float:
    """Carrier frequency (Hz) of a RINEX 3 observation code such as 'C1C' for a system letter.

    In RINEX 3.01 BeiDou B1I is band '1'; from 3.02 on it is band '2' (both 1561.098 MHz). GLONASS FDMA
    frequencies depend on the satellite (`dgcal.pos.gnss.glonass.glonass_frequency_hz`): ValueError here.
    """
    try:
        return FREQ_HZ[(system, code[1])]
    except KeyError:
        raise ValueError(f"unknown signal {system} {code}") from None


def gps_seconds_from_calendar(year: int, month: int, day: int, hour: int, minute: int,
                              sec: float) -> float:
    """Calendar date in GPS time scale -> continuous GPS seconds (week*604800 + sow)."""
    d = _dt.datetime(year, month, day, hour, minute) - GPS_EPOCH
    return d.days * SECONDS_PER_DAY + d.seconds + float(sec)


def calendar_from_gps_seconds(t_gps: float) -> tuple[int, int, int, int, int, float]:
    """Continuous GPS seconds -> (year, month, day, hour, minute, second) in GPS time scale."""
    whole = np.floor(t_gps)
    d = GPS_EPOCH + _dt.timedelta(seconds=int(whole))
    return d.year, d.month, d.day, d.hour, d.minute, d.second + float(t_gps - whole)


def gtime_from_gps_seconds(t_gps: float):
    """Continuous GPS seconds -> cssrlib ``gtime_t``."""
    week = int(np.floor(t_gps / SECONDS_PER_WEEK))
    return gpst2time(week, float(t_gps - week * SECONDS_PER_WEEK))


def gps_seconds_from_gtime(t) -> float:
    """cssrlib ``gtime_t`` -> continuous GPS seconds."""
    week, tow = time2gpst(t)
    return week * SECONDS_PER_WEEK + tow


class _LineCounter:
    """Text-stream wrapper counting lines, so a decoder failure can name the line."""

    def __init__(self, fh):
        self.fh, self.line = fh, 0
        self.text = ""

    def readline(self) -> str:
        s = self.fh.readline()
        if s:
            self.line += 1
            self.text = s
        return s

    def __iter__(self):
        return self

    def __next__(self) -> str:
        s = self.readline()
        if not s:
            raise StopIteration
        return s

    def close(self) -> None:
        self.fh.close()


# ----------------------------------------------------------------------------------------- nav
@dataclass
class BroadcastNav:
    """Broadcast ephemerides of RINEX navigation files (RINEX 2.10/2.11 GPS or 3.x mixed).

    ``eph``: cssrlib ``Eph`` records (GPS, Galileo, BeiDou, QZSS; epochs converted to GPS time);
    ``by_sat``: the same grouped by satellite id ('G05'); ``ion_gps``: Klobuchar (alpha, beta)
    (2x4) from the GPSA/GPSB (RINEX 2: ION ALPHA/BETA) header lines, else QZSA/QZSB, else RTKLIB's
    defaults (``ion_source`` says which; a warning is added to ``warnings``), ``ion_bds`` from
    BDSA/BDSB, None when absent. ``warnings``: one-line notes for summaries and reports.
    """

    eph: list
    by_sat: dict[str, list]
    ion_gps: np.ndarray | None
    ion_bds: np.ndarray | None
    leap_seconds: int
    source: str = ""
    _toe: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    ion_source: str = "GPSA/GPSB"
    warnings: list[str] = field(default_factory=list)
    precise: object | None = None           # dgcal.pos.gnss.precise.PreciseProducts: used for every satellite
    glonass: GlonassEphemerides | None = None   # GLONASS records (`dgcal.pos.gnss.glonass`), SPP only

    @property
    def orbits(self) -> str:
        """Which orbits and clocks positioning uses: "broadcast", or the precise products ("SP3 a + CLK b")."""
        return "broadcast" if self.precise is None else self.precise.label


def read_rinex_nav(path: str | Path, paths: Sequence[str | Path] = ()) -> BroadcastNav:
    """Read one or more RINEX navigation files (2.10/2.11 GPS, 3.x mixed) into ``BroadcastNav`` via cssrlib.

    Precise products among the files (SP3 orbits, RINEX clock files; recognised by content,
    `dgcal.pos.gnss.precise.product_kind`) are read into ``BroadcastNav.precise``: every satellite's orbit
    and clock then come from them, the broadcast records give the group delays, the ionosphere and the
    leap seconds (at least one broadcast file is needed). GLONASS records (RINEX 3 'R' records, RINEX 2 'G'
    files) go to ``BroadcastNav.glonass`` (used by SPP); records of systems dgcal does not use (SBAS, NavIC) are
    skipped with one warning per file (`dgcal.pos.gnss.rinex_nav`).
    Without Klobuchar coefficients in any header the QZSS ones are used, else RTKLIB's defaults,
    with a warning in ``BroadcastNav.warnings`` (never silently zero).
    """
    given = [Path(path)] + [Path(p) for p in paths]
    kinds = {p: product_kind(p) for p in given}
    sp3 = [p for p in given if kinds[p] == "sp3"]
    clk = [p for p in given if kinds[p] == "clk"]
    atx = [p for p in given if kinds[p] == "atx"]
    all_paths = [p for p in given if kinds[p] == "nav"]
    if not all_paths:
        raise InputError("precise orbits and clocks need a broadcast navigation file beside them (group delays, "
                         "ionosphere)", given[0], field="rinex_nav")
    precise = read_precise(sp3, clk, atx) if sp3 or clk else None
    skipped_notes: list[str] = []
    nav = Nav()
    ion_gps = ion_qzs = ion_bds = None
    leap = 18
    glonass: list[GlonassEphemerides] = []
    for k, p in enumerate(all_paths):
        text, hdr = nav_text_for_cssrlib(p)
        if hdr.skipped:
            skipped_notes.append(f"{p}: " + hdr.skipped)
        if hdr.glonass is not None:
            glonass.append(hdr.glonass)
        ion_gps = hdr.ion_gps if hdr.ion_gps is not None else ion_gps
        ion_qzs = hdr.ion_qzs if hdr.ion_qzs is not None else ion_qzs
        ion_bds = hdr.ion_bds if hdr.ion_bds is not None else ion_bds
        leap = hdr.leap_seconds
        dec = rnxdec()
        fh = _LineCounter(text)
        try:
            nav = dec._decode_nav(fh, nav, append=k > 0)
        except (ValueError, IndexError, KeyError, OverflowError) as exc:   # inf or 1e300 in a record overflows
            raise InputError(f"cannot decode navigation record: {exc}", p, fh.line) from None
        if nav == -1:
            raise InputError("RINEX version not supported by the decoder", p, 1)
    by_sat: dict[str, list] = {}
    dropped: list[str] = []
    kept = []                     # what `eph` holds: a corrupt record is left out of it too, not only of `by_sat`
    for e in nav.eph:
        sid = sat2id(e.sat)
        if isinstance(sid, str) and sid[0] in SYSTEMS:
            why = implausible_ephemeris(e)
            if why:
                dropped.append(f"{sid} toe {float(getattr(e, 'toes', np.nan)):.0f}: {why}")
                continue
            by_sat.setdefault(sid, []).append(e)
        kept.append(e)
    glo = GlonassEphemerides.concat(glonass) if glonass else None
    if not by_sat and glo is None:
        raise InputError("no GPS/Galileo/BeiDou/QZSS/GLONASS ephemeris in navigation file"
                         + (f" (all implausible: {dropped[0]})" if dropped else ""), all_paths[0])
    source = ", ".join(str(p) for p in all_paths)
    warnings, ion_source = list(skipped_notes), "GPSA/GPSB"
    if precise is not None:
        source += " + " + ", ".join(str(p) for p in sp3 + clk)
        warnings.append(f"orbits and clocks: {precise.label} ("
                        + ("satellite antenna phase-centre offsets from the ANTEX file, phase variations not applied"
                           if atx else "centre of mass: satellite antenna offsets not applied, no ANTEX file")
                        + "; the broadcast records give the group delays)")
    elif atx:
        warnings.append(f"{', '.join(str(p) for p in atx)}: ANTEX file not used (broadcast orbits are the antenna's "
                        "already; it serves SP3 orbits)")
    if dropped:
        warnings.append(f"{source}: {len(dropped)} ephemeris record(s) with impossible orbit or clock values left "
                        f"out: {'; '.join(dropped[:3])}" + (" ..." if len(dropped) > 3 else ""))
    if ion_gps is None:
        if ion_qzs is not None:
            ion_gps, ion_source = ion_qzs, "QZSA/QZSB"
            warnings.append(f"{source}: no GPS ionosphere coefficients (GPSA/GPSB, ION ALPHA/BETA); "
                            "the QZSS Klobuchar coefficients (QZSA/QZSB) are used")
        else:
            ion_gps, ion_source = ION_DEFAULT.copy(), "default"
            warnings.append(f"{source}: no ionosphere coefficients (GPSA/GPSB, ION ALPHA/BETA); "
                            "RTKLIB's default Klobuchar coefficients are used")
    return BroadcastNav(eph=kept, by_sat=by_sat, ion_gps=ion_gps, ion_bds=ion_bds,
                        leap_seconds=leap, source=source, ion_source=ion_source, warnings=warnings,
                        precise=precise, glonass=glo)


# what a GNSS broadcast ephemeris can hold: orbits from MEO to GEO (Galileo E14/E18: e 0.16), clocks below a second,
# angles in radians, harmonic corrections of a few km (radius) and milliradians (angles), group delays below 1 us
EPH_LIMITS = {"A": (2.0e7, 4.5e7), "e": (0.0, 0.25), "af0": (-1.0, 1.0), "af1": (-1e-6, 1e-6), "af2": (-1e-9, 1e-9),
              "i0": (-3.2, 3.2), "deln": (-1e-6, 1e-6), "idot": (-1e-6, 1e-6), "OMGd": (-1e-5, 1e-5),
              "M0": (-7.0, 7.0), "omg": (-7.0, 7.0), "OMG0": (-7.0, 7.0), "crc": (-1e4, 1e4), "crs": (-1e4, 1e4),
              "cuc": (-1e-2, 1e-2), "cus": (-1e-2, 1e-2), "cic": (-1e-2, 1e-2), "cis": (-1e-2, 1e-2),
              "toes": (0.0, 604800.0), "tgd": (-1e-6, 1e-6), "tgd_b": (-1e-6, 1e-6)}
EPH_MAX_ABS = 1e10      # no other number of a broadcast record is this large (weeks, IODs, health words, URA)


def implausible_ephemeris(e) -> str:
    """Why a decoded ephemeris cannot be a satellite's (a corrupt record: 1e20, inf), or '' when it can."""
    for name, (lo, hi) in EPH_LIMITS.items():
        v = getattr(e, name, None)
        if v is None:
            continue
        v = float(v)
        if not (np.isfinite(v) and lo <= v <= hi):
            return f"{name} = {v:.6g} outside [{lo:g}, {hi:g}]"
    for name, v in vars(e).items():
        vals = np.atleast_1d(np.asarray(v)) if isinstance(v, (int, float, np.number, np.ndarray)) else None
        if vals is not None and vals.dtype.kind in "iuf":
            bad = ~(np.abs(vals.astype(float)) <= EPH_MAX_ABS)
            if bad.any():
                return f"{name} = {vals.astype(float)[bad][0]:.6g}: not a broadcast value"
    return ""


# ----------------------------------------------------------------------------------------- obs
def _choose_signals(obs_types: dict[str, list[str]], systems: Iterable[str]) -> dict[str, str]:
    """The code observation used per system (first available of CODE_PRIORITY)."""
    chosen = {}
    for s in systems:
        have = obs_types.get(s, [])
        for code in CODE_PRIORITY.get(s, ()):
            if code in have:
                chosen[s] = code
                break
    return chosen


def _choose_second_codes(obs_types: dict[str, list[str]], signals: dict[str, str]) -> dict[str, str]:
    """The second code per system for the ionosphere-free combination (first available of CODE2_PRIORITY)."""
    out = {}
    for s in signals:
        have = obs_types.get(s, [])
        code = next((c for c in CODE2_PRIORITY.get(s, ()) if c in have), None)
        if code is not None:
            out[s] = code
    return out


def read_rinex_obs(path: str | Path, systems: Sequence[str] = SYSTEMS,
                   t_start: float | None = None, t_end: float | None = None,
                   decimate_s: float | None = None, rinex: RinexObsFile | None = None,
                   glonass_k: dict[str, int] | None = None) -> GnssObservations:
    """Read a RINEX 2.10/2.11/3.x observation file into raw ``GnssEpoch``s (front-end fields NaN).

    One code signal per system (see ``CODE_PRIORITY``) with its Doppler and C/N0, and a second code where the
    file has one (``CODE2_PRIORITY``: ``pr2_m``, ``wavelength2_m``, for the ionosphere-free combination). When the file
    has no Doppler for a signal, the range rate is derived from the carrier phase of the same
    signal by central differences between neighbouring epochs (no loss-of-lock flag, gap <= 1.5
    epoch intervals); ``doppler_hz`` is then the equivalent Doppler. Times are GPS time.
    ``rinex``: the file already read by ``dgcal.pos.gnss.rinex_obs.read_obs_file`` (not read again).
    GLONASS ('R' in ``systems``): each satellite's frequency channel from ``glonass_k`` (the navigation records',
    `GlonassEphemerides.frequency_numbers`) or the header's GLONASS SLOT / FRQ #; satellites of unknown channel
    are left out. GLONASS observations present but not asked for are named in ``rinex.warnings``.
    """

    path = Path(path)
    rx = rinex if rinex is not None else read_obs_file(path, t_start=t_start, t_end=t_end)
    obs_types = rx.obs_types
    signals = _choose_signals(obs_types, [s for s in systems if s in ALL_SYSTEMS])
    if "R" in rx.systems and rx.systems["R"].sats and "R" not in signals:
        n = len(rx.systems["R"].sats)
        note = f"{path}: " + (GLONASS_NOT_USED.format(n=n) if "R" not in systems
                              else f"GLONASS observations of {n} satellite(s) not used (no C1C/C1P code)")
        if note not in rx.warnings:
            rx.warnings.append(note)
    if not signals:
        raise InputError(f"no usable code observations for systems {list(systems)} "
                         f"(have {obs_types})", path, field="SYS / # / OBS TYPES")
    k_glo = {**rx.glonass_k, **(glonass_k or {})}
    wavelength = {s: C_LIGHT / signal_frequency_hz(s, code) for s, code in signals.items() if s != "R"}
    signals2 = _choose_second_codes(obs_types, signals)
    wavelength2 = {s: C_LIGHT / signal_frequency_hz(s, code) for s, code in signals2.items() if s != "R"}
    for sid, k in k_glo.items():
        if "R" in signals:
            wavelength[sid] = C_LIGHT / float(glonass_frequency_hz(k, signals["R"][1]))
        if "R" in signals2:
            wavelength2[sid] = C_LIGHT / float(glonass_frequency_hz(k, signals2["R"][1]))
    t = rx.t_gps
    keep_t = np.ones(len(t), dtype=bool)
    if rinex is not None:
        if t_start is not None:
            keep_t &= t >= t_start - 1e-6
        if t_end is not None:
            keep_t &= t <= t_end + 1e-6
    if decimate_s:
        keep_t &= np.abs(t / decimate_s - np.round(t / decimate_s)) <= 1e-6
    epochs = []
    for k, sat, vals in _chosen_rows(rx, np.nonzero(keep_t)[0], signals, signals2):
        if "R" in signals:      # GLONASS satellites of unknown frequency channel cannot be used
            known = np.array([s[0] != "R" or s in wavelength for s in sat], bool)
            sat, vals = [s for s, u in zip(sat, known) if u], vals[known]
        pr, pr2, ph, dop, cn0, lli = vals.T
        if not sat:
            continue
        n = len(sat)
        system = np.array([s[0] for s in sat])
        lam = np.array([wavelength[s if s[0] == "R" else s[0]] for s in sat])
        dop = np.array(dop, dtype=float)
        nan = np.full(n, np.nan)
        ep = GnssEpoch(t_gps=float(t[k]), sat=sat, system=system, pr_m=np.array(pr, dtype=float), doppler_hz=dop,
                       range_rate_mps=-lam * dop, wavelength_m=lam, cn0_dbhz=np.array(cn0, dtype=float),
                       sat_pos_ecef=np.full((n, 3), np.nan), sat_vel_ecef=np.full((n, 3), np.nan),
                       sat_clk_s=nan.copy(), sat_clk_drift=nan.copy(), iono_m=nan.copy(),
                       tropo_m=nan.copy(), elev_deg=nan.copy(), azim_deg=nan.copy(),
                       sigma_pr_m=nan.copy(), sigma_rr_mps=nan.copy())
        if signals2:
            ep.pr2_m = np.array(pr2, dtype=float)
            ep.wavelength2_m = np.array([wavelength2.get(s if s[0] == "R" else s[0], np.nan) for s in sat])
        ep._phase = np.array(ph, dtype=float)  # cycles; used only to derive a missing Doppler
        ep._lli = np.array(lli, dtype=int)
        epochs.append(ep)
    _doppler_from_phase(epochs)
    for ep in epochs:
        del ep._phase, ep._lli
    if not epochs:
        raise InputError("no observation epochs in the requested time span", path)
    return GnssObservations(epochs=epochs, receiver=rx.receiver, p_approx_ecef=rx.p_approx_ecef.copy(),
                            signals=signals, source=str(path), signals2=signals2)


_FIELD_CHUNK = 2048   # epochs gathered at a time (memory: chunk x satellites x 6 floats)


def _signal_fields(rx: RinexObsFile, signals: dict, signals2: dict):
    """The column of every satellite of the chosen systems, and a function giving epochs k0:k1 of all of them as
    one (k, satellites, 6) array of: code m, second code m (NaN unless > 1e6 m), phase cycles, Doppler Hz, C/N0
    dB-Hz, phase LLI (0 without a phase); built with NumPy instead of value by value."""
    parts = []
    column: dict = {}
    for s, code in signals.items():
        so = rx.systems.get(s)
        if so is None:
            continue
        ba = code[1:]
        j = [so.codes.index(c) if c is not None and c in so.codes else None
             for c in (code, signals2.get(s), "L" + ba, "D" + ba, "S" + ba)]
        column.update({sid: len(column) + i for i, sid in enumerate(so.sats)})
        parts.append((so, j))

    def blocks(k0: int, k1: int) -> np.ndarray:
        out = []
        for so, j in parts:
            v = so.val[k0:k1]
            f = np.full(v.shape[:2] + (6,), np.nan)
            for i, c in enumerate(j):
                if c is not None:
                    f[:, :, i] = v[:, :, c]
            q = f[:, :, 1]
            q[~(np.isfinite(q) & (q > 1e6))] = np.nan
            f[:, :, 5] = 0.0 if j[2] is None else np.where(np.isfinite(f[:, :, 2]), so.lli[k0:k1, :, j[2]], 0)
            out.append(f)
        return np.concatenate(out, axis=1) if out else np.full((max(k1 - k0, 0), 0, 6), np.nan)
    return column, blocks


def _chosen_rows(rx: RinexObsFile, kept: np.ndarray, signals: dict, signals2: dict):
    """(epoch index, satellites in file order, (n, 6) fields of `_signal_fields`) of each epoch in `kept`: the
    satellites of the chosen systems whose code is a range (finite, > 1e6 m)."""
    column, blocks = _signal_fields(rx, signals, signals2)
    for k0 in range(0, len(rx.t_gps), _FIELD_CHUNK):
        ks = kept[(kept >= k0) & (kept < k0 + _FIELD_CHUNK)]
        if not len(ks):
            continue
        block = blocks(k0, k0 + _FIELD_CHUNK)
        for k in ks:
            sids = [sid for sid in rx.epoch_sats[k] if sid in column]
            vals = block[k - k0, [column[sid] for sid in sids]].reshape(-1, 6)
            use = np.isfinite(vals[:, 0]) & (vals[:, 0] > 1e6)
            yield int(k), [sids[i] for i in np.flatnonzero(use)], vals[use]


def _doppler_from_phase(epochs: list[GnssEpoch]) -> None:
    """Fill missing Doppler by central differences of carrier phase (cycles) between epochs."""
    if len(epochs) < 2:
        return
    t = np.array([e.t_gps for e in epochs])
    dt_nom = np.median(np.diff(t))
    index = [{s: i for i, s in enumerate(e.sat)} for e in epochs]
    for k, ep in enumerate(epochs):
        for i, s in enumerate(ep.sat):
            if np.isfinite(ep.doppler_hz[i]):
                continue
            lo, hi = max(k - 1, 0), min(k + 1, len(epochs) - 1)
            if hi == lo:
                continue
            ia, ib = index[lo].get(s), index[hi].get(s)
            if ia is None or ib is None:
                continue
            dt = t[hi] - t[lo]
            if dt <= 0 or dt > 2.5 * dt_nom:
                continue
            La, Lb = epochs[lo]._phase[ia], epochs[hi]._phase[ib]
            # a loss of lock flagged on the later epoch (or the middle one) breaks the arc
            if not (np.isfinite(La) and np.isfinite(Lb)) or epochs[hi]._lli[ib] & 1 or \
                    (hi > k and ep._lli[i] & 1):
                continue
            d = -(Lb - La) / dt       # Hz; RINEX phase grows with range, Doppler = -dL/dt
            ep.doppler_hz[i] = d
            ep.range_rate_mps[i] = -ep.wavelength_m[i] * d


# -------------------------------------------------------------------------------------- writer
def write_rinex_obs(path: str | Path, obs: GnssObservations, marker: str = "DGCAL",
                    comment: str = "simulated by dgcal") -> None:
    """Write code, Doppler and C/N0 of ``obs`` as a RINEX 3.04 observation file (atomic write).

    Per system the codes of ``obs.signals`` are written with their Doppler ('D..') and signal
    strength ('S..'); values that are NaN are left blank. GLONASS satellites' frequency channels (from their
    wavelengths) go to the header's GLONASS SLOT / FRQ # lines.
    """

    systems = obs.systems
    types = {}
    for s in systems:
        code = obs.signals.get(s, CODE_PRIORITY[s][0])
        types[s] = [code, "D" + code[1:], "S" + code[1:]]
    p0 = obs.p_approx_ecef if np.all(np.isfinite(obs.p_approx_ecef)) else np.zeros(3)

    def hdr(text: str, label: str) -> str:
        return f"{text:<60.60}{label:<20}\n"

    t0, t1 = obs.t_gps[0], obs.t_gps[-1]
    dt = np.median(np.diff(obs.t_gps)) if len(obs) > 1 else 1.0
    lines = [hdr(f"{3.04:9.2f}{'':11}{'OBSERVATION DATA':<20}{'M':<20}", "RINEX VERSION / TYPE"),
             hdr(f"{'dgcal':<20}{'dgcal':<20}{_dt.datetime.utcnow():%Y%m%d %H%M%S} UTC", "PGM / RUN BY / DATE"),
             hdr(comment, "COMMENT"),
             hdr(marker, "MARKER NAME"),
             hdr(f"{'SIM':<20}{obs.receiver or 'DGCAL SIM':<20}{'':<20}", "REC # / TYPE / VERS"),
             hdr(f"{'SIM':<20}{'SIM':<20}", "ANT # / TYPE"),
             hdr(f"{p0[0]:14.4f}{p0[1]:14.4f}{p0[2]:14.4f}", "APPROX POSITION XYZ"),
             hdr(f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N")]
    for s in systems:
        lines.append(hdr(f"{s}{len(types[s]):5d} " + " ".join(types[s]), "SYS / # / OBS TYPES"))
    if "R" in systems:      # each GLONASS satellite's frequency channel, from its wavelength
        k = {}
        for ep in obs.epochs:
            for sid, lam in zip(ep.sat, ep.wavelength_m):
                if sid[0] == "R" and sid not in k and np.isfinite(lam):
                    k[sid] = int(round((C_LIGHT / lam - F1_BASE_HZ) / F1_STEP_HZ))
        items = sorted(k.items())
        for j in range(0, max(len(items), 1), 8):
            part = "".join(f"{sid} {kk:2d} " for sid, kk in items[j:j + 8])
            lines.append(hdr((f"{len(items):3d} " if j == 0 else "    ") + part, "GLONASS SLOT / FRQ #"))
    lines.append(hdr(f"{dt:10.3f}", "INTERVAL"))
    for tt, label in ((t0, "TIME OF FIRST OBS"), (t1, "TIME OF LAST OBS")):
        y, mo, d, h, mi, sec = calendar_from_gps_seconds(tt)
        lines.append(hdr(f"{y:6d}{mo:6d}{d:6d}{h:6d}{mi:6d}{sec:13.7f}     GPS", label))
    lines.append(hdr("DBHZ", "SIGNAL STRENGTH UNIT"))
    lines.append(hdr("", "END OF HEADER"))

    def val(v: float) -> str:
        return f"{v:14.3f}  " if np.isfinite(v) else " " * 16

    with atomic_write(path) as fh:
        fh.writelines(lines)
        for ep in obs.epochs:
            y, mo, d, h, mi, sec = calendar_from_gps_seconds(ep.t_gps)
            order = sorted(range(ep.n), key=lambda i: (ALL_SYSTEMS.index(ep.sat[i][0]), ep.sat[i]))
            fh.write(f"> {y:4d} {mo:02d} {d:02d} {h:02d} {mi:02d}{sec:11.7f}  0{len(order):3d}\n")
            for i in order:
                fh.write(ep.sat[i] + val(ep.pr_m[i]) + val(ep.doppler_hz[i]) + val(ep.cn0_dbhz[i]).rstrip() + "\n")
