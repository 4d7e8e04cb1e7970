"""RINEX 3 observation and navigation files: reading through cssrlib, writing simulated observations.

Reading uses cssrlib's ``rnxdec`` (a maintained RINEX decoder) fed through a line-counting file
wrapper, so that any decoding failure is reported as ``InputError`` naming the file and line.
One code signal per constellation is chosen (single-frequency SPP/TC): GPS and QZSS L1 C/A,
Galileo E1, BeiDou B1I, each with its Doppler and C/N0 where present.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import gzip
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from cssrlib.gnss import Nav, char2sys, gpst2time, rSigRnx, sat2id, sat2prn, sys2char, time2gpst, uTYP
from cssrlib.rinex import rnxdec

from dgcal.fields.constants import C_LIGHT, SECONDS_PER_DAY, SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.pos.gnss.observations import SYSTEMS, GnssEpoch, GnssObservations

# Preferred code observations per system, best first (RINEX 3 codes).
CODE_PRIORITY = {
    "G": ("C1C", "C1W", "C1X", "C1L"),
    "J": ("C1C", "C1X", "C1L"),
    "E": ("C1C", "C1X", "C1B"),
    "C": ("C2I", "C1I", "C2X"),
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

    In RINEX 3.01 BeiDou B1I is band '1'; from 3.02 on it is band '2' (both 1561.098 MHz).
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
    """File wrapper counting lines, so a decoder failure can name the line."""

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


def _open_text(path: Path):
    if not path.is_file():
        raise InputError("file not found", path)
    if path.suffix.lower() in (".gz", ".z"):
        return gzip.open(path, "rt", encoding="ascii", errors="replace")
    return open(path, "rt", encoding="ascii", errors="replace")


def _check_version(path: Path, kind: str) -> None:
    """RINEX 3+ only; names the file if the first line is not a RINEX 3 header of the right kind."""
    with _open_text(path) as fh:
        first = fh.readline()
    if "CRINEX VERS" in first:
        raise InputError("Hatanaka-compressed RINEX: decompress it first (crx2rnx)", path, 1)
    if "RINEX VERSION / TYPE" not in first:
        raise InputError("not a RINEX file (no 'RINEX VERSION / TYPE' header line)", path, 1)
    try:
        ver = float(first[:9])
    except ValueError:
        raise InputError("bad RINEX version", path, 1, "RINEX VERSION") from None
    if ver < 3.0:
        raise InputError(f"RINEX version {ver} is not supported (need 3.x)", path, 1, "RINEX VERSION")
    typ = first[20:21]
    if kind == "obs" and typ != "O":
        raise InputError(f"not an observation file (type '{typ}')", path, 1, "RINEX VERSION / TYPE")
    if kind == "nav" and typ != "N":
        raise InputError(f"not a navigation file (type '{typ}')", path, 1, "RINEX VERSION / TYPE")


# ----------------------------------------------------------------------------------------- nav
@dataclass
class BroadcastNav:
    """Broadcast ephemerides of a RINEX 3 navigation file.

    ``eph``: cssrlib ``Eph`` records (GPS, Galileo, BeiDou, QZSS; epochs converted to GPS time);
    ``by_sat``: the same grouped by satellite id ('G05'); ``ion_gps``: Klobuchar (alpha, beta)
    from the GPSA/GPSB header lines (2x4), ``ion_bds`` from BDSA/BDSB, None when absent.
    """

    eph: list
    by_sat: dict[str, list]
    ion_gps: np.ndarray | None
    ion_bds: np.ndarray | None
    leap_seconds: int
    source: str = ""
    _toe: dict[str, np.ndarray] = field(default_factory=dict, repr=False)


def _parse_ion_header(path: Path) -> tuple[np.ndarray | None, np.ndarray | None, int]:
    """GPSA/GPSB and BDSA/BDSB Klobuchar coefficients and leap seconds from the header."""
    coef: dict[str, list[float]] = {}
    leap = 18
    with _open_text(path) as fh:
        for lineno, line in enumerate(fh, start=1):
            label = line[60:].strip()
            if label.startswith("END OF HEADER"):
                break
            if label.startswith("IONOSPHERIC CORR"):
                key = line[0:4]
                try:
                    coef[key] = [float(line[5 + 12 * k:5 + 12 * (k + 1)].replace("D", "E").strip() or 0.0)
                                 for k in range(4)]
                except ValueError:
                    raise InputError("bad number in IONOSPHERIC CORR", path, lineno, key) from None
            elif label.startswith("LEAP SECONDS"):
                with contextlib.suppress(ValueError):
                    leap = int(line[:6])

    def pair(a: str, b: str):
        return np.array([coef[a], coef[b]]) if a in coef and b in coef else None

    return pair("GPSA", "GPSB"), pair("BDSA", "BDSB"), leap


def read_rinex_nav(path: str | Path, paths: Sequence[str | Path] = ()) -> BroadcastNav:
    """Read one or more RINEX 3 (mixed) navigation files into ``BroadcastNav`` via cssrlib."""

    all_paths = [Path(path)] + [Path(p) for p in paths]
    nav = Nav()
    ion_gps = ion_bds = None
    leap = 18
    for k, p in enumerate(all_paths):
        _check_version(p, "nav")
        g, b, leap = _parse_ion_header(p)
        ion_gps = g if g is not None else ion_gps
        ion_bds = b if b is not None else ion_bds
        dec = rnxdec()
        fh = _LineCounter(_open_text(p))
        try:
            nav = dec._decode_nav(fh, nav, append=k > 0)
        except (ValueError, IndexError, KeyError) as exc:
            raise InputError(f"cannot decode navigation record: {exc}", p, fh.line) from None
        finally:
            fh.close()
        if nav == -1:
            raise InputError("RINEX version < 3.02 is not supported by the decoder", p, 1)
    by_sat: dict[str, list] = {}
    for e in nav.eph:
        sid = sat2id(e.sat)
        if isinstance(sid, str) and sid[0] in SYSTEMS:
            by_sat.setdefault(sid, []).append(e)
    if not by_sat:
        raise InputError("no GPS/Galileo/BeiDou/QZSS ephemeris in navigation file", all_paths[0])
    return BroadcastNav(eph=nav.eph, by_sat=by_sat, ion_gps=ion_gps, ion_bds=ion_bds,
                        leap_seconds=leap, source=", ".join(str(p) for p in all_paths))


# ----------------------------------------------------------------------------------------- obs
@dataclass
class RinexObsHeader:
    """What the observation header says: marker, receiver, approximate position, signals per system."""

    marker: str
    receiver: str
    p_approx_ecef: np.ndarray
    obs_types: dict[str, list[str]]
    version: float


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


def read_rinex_obs(path: str | Path, systems: Sequence[str] = SYSTEMS,
                   t_start: float | None = None, t_end: float | None = None,
                   decimate_s: float | None = None) -> GnssObservations:
    """Read a RINEX 3 observation file (via cssrlib) into raw ``GnssEpoch``s (front-end fields NaN).

    One code signal per system (see ``CODE_PRIORITY``) with its Doppler and C/N0. When the file
    has no Doppler for a signal, the range rate is derived from the carrier phase of the same
    signal by central differences between neighbouring epochs (no loss-of-lock flag, gap <= 1.5
    epoch intervals); ``doppler_hz`` is then the equivalent Doppler. Times are GPS time.
    """

    path = Path(path)
    _check_version(path, "obs")
    dec = rnxdec()
    fh = _LineCounter(_open_text(path))
    try:
        dec.fobs = fh
        try:
            if dec._decode_obsh() != 0:
                raise InputError("RINEX version < 3.02 is not supported by the decoder", path, 1)
        except (ValueError, IndexError, KeyError) as exc:
            raise InputError(f"cannot decode observation header: {exc}", path, fh.line) from None
        obs_types = {}
        for gns, m in dec.sig_map.items():
            obs_types[_sys_letter(gns)] = [m[i].str() for i in sorted(m)]
        signals = _choose_signals(obs_types, [s for s in systems if s in SYSTEMS])
        if not signals:
            raise InputError(f"no usable code observations for systems {list(systems)} "
                             f"(have {obs_types})", path, field="SYS / # / OBS TYPES")
        sig_list, wavelength = [], {}
        for s, code in signals.items():
            band_att = code[1:]
            want = [code, "L" + band_att, "D" + band_att, "S" + band_att]
            for w in want:
                if w in obs_types[s]:
                    sig_list.append(rSigRnx(char2sys(s), w))
            wavelength[s] = C_LIGHT / signal_frequency_hz(s, code)
        dec.setSignals(sig_list)
        raw = _decode_obs_body(dec, fh, path, signals, obs_types, t_start, t_end, decimate_s)
    finally:
        fh.close()
    header = RinexObsHeader(marker="", receiver=(dec.rcv or "").strip(),
                            p_approx_ecef=np.asarray(dec.pos, float), obs_types=obs_types,
                            version=dec.ver)
    epochs = _raw_to_epochs(raw, signals, wavelength, sat2id)
    if not epochs:
        raise InputError("no observation epochs in the requested time span", path)
    p0 = header.p_approx_ecef if np.linalg.norm(header.p_approx_ecef) > 1e6 else np.full(3, np.nan)
    return GnssObservations(epochs=epochs, receiver=header.receiver, p_approx_ecef=p0,
                            signals=signals, source=str(path))


def _sys_letter(gns) -> str:
    return sys2char(gns)


def _decode_obs_body(dec, fh: _LineCounter, path: Path, signals, obs_types, t_start, t_end,
                     decimate_s) -> list[tuple[float, np.ndarray, dict]]:
    """Decode epochs with cssrlib; returns (t_gps, sats, {typ: values}) per epoch."""
    letter_cache: dict[int, str] = {}

    def letter_of(sat: int) -> str:
        if sat not in letter_cache:
            letter_cache[sat] = sys2char(sat2prn(sat)[0])
        return letter_cache[sat]

    typ_of = {"C": uTYP.C, "L": uTYP.L, "D": uTYP.D, "S": uTYP.S}
    has = {(c, k): c in signals and bool(dec.getSignals(char2sys(c), typ)) for c in "GRECJSI"
           for k, typ in typ_of.items()}
    out = []
    while True:
        line_before = fh.line
        try:
            obs = dec.decode_obs()
        except (ValueError, IndexError, KeyError) as exc:
            raise InputError(f"cannot decode observation record: {exc}", path, fh.line) from None
        if fh.line == line_before or obs.t.time == 0:
            break
        if len(obs.sat) == 0:
            continue
        t = gps_seconds_from_gtime(obs.t)
        if t_start is not None and t < t_start - 1e-6:
            continue
        if t_end is not None and t > t_end + 1e-6:
            break
        if decimate_s and abs(t / decimate_s - round(t / decimate_s)) > 1e-6:
            continue
        # cssrlib's per-type arrays hold our single signal per system in column 0
        vals = {k: np.full(len(obs.sat), np.nan) for k in ("C", "L", "D", "S")}
        lli = np.zeros(len(obs.sat), dtype=int)
        letters = [letter_of(int(sat)) for sat in obs.sat]
        for typ_name, arr in (("C", obs.P), ("L", obs.L), ("D", obs.D), ("S", obs.S)):
            if arr.shape[1] == 0:
                continue
            col = np.where(np.array([has[(c, typ_name)] for c in letters], dtype=bool), arr[:, 0], 0.0)
            vals[typ_name] = np.where(col != 0.0, col, np.nan)
            if typ_name == "L":
                lli = np.where(np.isfinite(vals["L"]), obs.lli[:, 0], 0)
        out.append((t, np.asarray(obs.sat), vals, lli))
    return out


def _raw_to_epochs(raw, signals, wavelength, sat2id) -> list[GnssEpoch]:
    """Build raw GnssEpochs; derive range rate from carrier phase where Doppler is missing."""
    epochs = []
    id_cache: dict[int, str] = {}
    for t, sats, vals, lli in raw:
        ok = np.isfinite(vals["C"]) & (vals["C"] > 1e6)
        ids = []
        for s in sats:
            s = int(s)
            if s not in id_cache:
                id_cache[s] = sat2id(s)
            ids.append(id_cache[s])
        keep = [i for i in range(len(ids)) if ok[i] and isinstance(ids[i], str) and ids[i][0] in signals]
        if not keep:
            continue
        keep = np.array(keep)
        sat = [ids[i] for i in keep]
        system = np.array([s[0] for s in sat])
        lam = np.array([wavelength[s] for s in system])
        dop = vals["D"][keep]
        n = len(sat)
        nan = np.full(n, np.nan)
        ep = GnssEpoch(t_gps=t, sat=sat, system=system, pr_m=vals["C"][keep], doppler_hz=dop,
                       range_rate_mps=-lam * dop, wavelength_m=lam, cn0_dbhz=vals["S"][keep],
                       sat_pos_ecef=np.full((n, 3), np.nan), sat_vel_ecef=np.full((n, 3), np.nan),
                       sat_clk_s=nan.copy(), sat_clk_drift=nan.copy(), iono_m=nan.copy(),
                       tropo_m=nan.copy(), elev_deg=nan.copy(), azim_deg=nan.copy(),
                       sigma_pr_m=nan.copy(), sigma_rr_mps=nan.copy())
        ep._phase = vals["L"][keep]  # cycles; used only to derive a missing Doppler
        ep._lli = lli[keep]
        epochs.append(ep)
    _doppler_from_phase(epochs)
    for ep in epochs:
        del ep._phase, ep._lli
    return epochs


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
    strength ('S..'); values that are NaN are left blank.
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
            order = sorted(range(ep.n), key=lambda i: (SYSTEMS.index(ep.sat[i][0]), ep.sat[i]))
            fh.write(f"> {y:4d} {mo:02d} {d:02d} {h:02d} {mi:02d}{sec:11.7f}  0{len(order):3d}\n")
            for i in order:
                fh.write(ep.sat[i] + val(ep.pr_m[i]) + val(ep.doppler_hz[i]) + val(ep.cn0_dbhz[i]).rstrip() + "\n")
