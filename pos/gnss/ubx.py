"""u-blox UBX raw logs (RXM-RAWX observations, RXM-SFRBX navigation subframes) as RINEX 3.04 text.

Low-cost UAV payloads log the receiver's binary stream rather than RINEX. ``ubx_rinex_lines`` turns such a log into
the lines of a RINEX 3.04 observation file (``kind="obs"``) or navigation file (``kind="nav"``), so that dgcal's
RINEX readers, and with them SPP, PPK, TC, their summaries and their errors, serve a UBX log unchanged
(`dgcal.pos.gnss.gnss_files` recognises a log by its first bytes, 0xB5 0x62).

Framing: sync 0xB5 0x62, class, id, little-endian length, payload, 8-bit Fletcher checksum over class..payload. A
message whose checksum fails, or whose length runs past the end of the data, is skipped and counted
(``UbxLog.bad_checksum``, ``UbxLog.truncated``); reading resumes at the next sync pattern, so one corrupt byte costs
one message, never the log. Bytes between messages (NMEA sentences of a mixed stream) are counted too.

RXM-RAWX (0x02 0x15): one epoch per message at the receiver's time (week, rcvTow: GPS time). Per measurement:
pseudorange only when trkStat bit 0 says it is valid, carrier phase only when bit 1 says so, it is not -0.5 and its
cpStdev index is at most 5 (RTKLIB's rules, `CPSTD_VALID`). The loss-of-lock indicator is RTKLIB's (ubx.c and convrnx):
bit 0 (slip) when the lock time is 0, is shorter than at the signal's previous measurement, or the
half-cycle-subtracted flag (trkStat bit 3) changed, held until the signal's next valid phase, and on every phase of
the first epoch; bit 1 (half-cycle ambiguity) when trkStat bit 2 (half cycle resolved) is clear. BeiDou GEO
phase gets RTKLIB's half-cycle shift (+0.5 cycle). Signals map to RINEX 3 codes by `SIGNALS` (u-blox interface
description, sigId); GLONASS satellites carry their frequency number (freqId - 7). The per-measurement parsing of a
message is one NumPy structured-array view.

RXM-SFRBX (0x02 0x13): the navigation words go to cssrlib's `RawNav` decoders (GPS/QZSS LNAV, Galileo I/NAV and
F/NAV, BeiDou D1), each new ephemeris (satellite, IOD, toe) kept once and written as RINEX 3 records by cssrlib's
RINEX encoder; GPS Klobuchar coefficients come from subframe 4 page 18 when the log holds it (every 12.5 min).
GLONASS navigation strings are not decoded (give a navigation file for GLONASS orbits).
"""
from __future__ import annotations

import io
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from cssrlib.gnss import bdt2gpst, gpst2bdt, prn2sat, sat2id, uGNSS
from cssrlib.rawnav import RawNav
from cssrlib.rinex import rnxenc

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.carrier import BAND_FREQ_HZ, CarrierObs, write_rinex_carrier
from dgcal.pos.gnss.glonass import F1_BASE_HZ, F1_STEP_HZ
from dgcal.pos.gnss.gnss_files import UBX_SYNC, ubx_checksum

SYNC = UBX_SYNC
RAWX, SFRBX = (0x02, 0x15), (0x02, 0x13)
CPSTD_VALID = 5                      # RTKLIB: phase with a cpStdev index above this (0.004 cycle units) is dropped

RAWX_HEAD = np.dtype([("rcvTow", "<f8"), ("week", "<u2"), ("leapS", "i1"), ("numMeas", "u1"), ("recStat", "u1"),
                      ("version", "u1"), ("reserved", "u1", 2)])
RAWX_MEAS = np.dtype([("prMes", "<f8"), ("cpMes", "<f8"), ("doMes", "<f4"), ("gnssId", "u1"), ("svId", "u1"),
                      ("sigId", "u1"), ("freqId", "u1"), ("locktime", "<u2"), ("cno", "u1"), ("prStdev", "u1"),
                      ("cpStdev", "u1"), ("doStdev", "u1"), ("trkStat", "u1"), ("reserved", "u1")])
SYSTEM_OF_GNSS_ID = {0: "G", 1: "S", 2: "E", 3: "C", 5: "J", 6: "R", 7: "I"}
# (system, sigId) -> RINEX 3 band and attribute (u-blox interface description, RXM-RAWX signal identifiers)
SIGNALS = {
    ("G", 0): "1C", ("G", 3): "2L", ("G", 4): "2S", ("G", 6): "5I", ("G", 7): "5Q",
    ("S", 0): "1C",
    ("E", 0): "1C", ("E", 1): "1B", ("E", 3): "5I", ("E", 4): "5Q", ("E", 5): "7I", ("E", 6): "7Q",
    ("E", 8): "6B", ("E", 9): "6C", ("E", 10): "6A",
    ("C", 0): "2I", ("C", 1): "2I", ("C", 2): "7I", ("C", 3): "7I", ("C", 4): "6I", ("C", 10): "6I",
    ("C", 5): "1P", ("C", 6): "1D", ("C", 7): "5P", ("C", 8): "5D",
    ("J", 0): "1C", ("J", 1): "1Z", ("J", 4): "2S", ("J", 5): "2L", ("J", 8): "5I", ("J", 9): "5Q", ("J", 12): "1E",
    ("R", 0): "1C", ("R", 2): "2C",
    ("I", 0): "5A",
}
_GLO_BAND2_BASE_HZ, _GLO_BAND2_STEP_HZ = 1246.0e6, 437.5e3
_CSSR_SYS = {"G": uGNSS.GPS, "E": uGNSS.GAL, "C": uGNSS.BDS, "J": uGNSS.QZS}
NO_RAWX = "no UBX-RXM-RAWX messages (raw observations) in the log: enable UBX-RXM-RAWX on the receiver"
NO_EPH = ("no ephemerides in the log: give --rinex-nav a navigation file (the log holds no complete "
          "UBX-RXM-SFRBX subframe set)")


@dataclass
class UbxFrames:
    """The intact messages of a UBX byte stream and what was skipped on the way."""

    messages: list[tuple[int, int, bytes]]     # (class, id, payload)
    bad_checksum: int = 0                      # frames whose checksum failed (skipped)
    truncated: int = 0                         # a last frame cut off by the end of the data
    junk_bytes: int = 0                        # bytes outside UBX frames (NMEA, noise)


@dataclass
class UbxLog:
    """What a UBX log holds: observations (``obs``, None without RAWX), cssrlib ephemerides, GPS Klobuchar
    coefficients (2x4 or None), leap seconds (None when the receiver did not know them) and the skip counts."""

    path: str
    obs: CarrierObs | None
    eph: list
    ion_gps: np.ndarray | None
    leap_seconds: int | None
    n_rawx: int = 0
    n_sfrbx: int = 0
    malformed: int = 0                         # RAWX/SFRBX frames with intact checksum but impossible contents
    bad_checksum: int = 0
    truncated: int = 0
    junk_bytes: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def skipped(self) -> int:
        """Messages skipped: failed checksums, a truncated last message, malformed RAWX/SFRBX contents."""
        return self.bad_checksum + self.truncated + self.malformed


def ubx_frame(cls: int, mid: int, payload: bytes) -> bytes:
    """One UBX message: sync, class, id, length, payload and checksum (to build or re-frame logs)."""
    body = bytes([cls, mid]) + len(payload).to_bytes(2, "little") + payload
    ck_a, ck_b = ubx_checksum(np.frombuffer(body, dtype=np.uint8))
    return SYNC + body + bytes([ck_a, ck_b])



def ubx_frames(data: bytes) -> UbxFrames:
    """Split a UBX byte stream into its intact messages; corrupt and truncated frames are counted and skipped."""
    out = UbxFrames([])
    arr = np.frombuffer(data, dtype=np.uint8)
    n, k = len(data), 0
    while True:
        j = data.find(SYNC, k)
        if j < 0:
            out.junk_bytes += n - k
            return out
        out.junk_bytes += j - k
        if j + 6 > n:
            out.truncated += 1
            return out
        length = int.from_bytes(data[j + 4:j + 6], "little")
        end = j + 6 + length + 2
        if end > n:
            if data.find(SYNC, j + 2) < 0:
                out.truncated += 1
                return out
            out.bad_checksum += 1      # a corrupt length field: resynchronise at the next sync pattern
            k = j + 2
            continue
        if ubx_checksum(arr[j + 2:end - 2]) != (data[end - 2], data[end - 1]):
            out.bad_checksum += 1
            k = j + 2
            continue
        out.messages.append((data[j + 2], data[j + 3], data[j + 6:end - 2]))
        k = end


def _rawx(payload: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """Header and measurement records of a RAWX payload, None when its length disagrees with numMeas."""
    if len(payload) < RAWX_HEAD.itemsize:
        return None
    head = np.frombuffer(payload, RAWX_HEAD, 1)[0]
    n = int(head["numMeas"])
    if len(payload) != RAWX_HEAD.itemsize + n * RAWX_MEAS.itemsize or not np.isfinite(head["rcvTow"]) \
            or not 0.0 <= head["rcvTow"] < SECONDS_PER_WEEK + 1.0:
        return None
    return head, np.frombuffer(payload, RAWX_MEAS, n, RAWX_HEAD.itemsize)


_SYSTEMS = "GRECJSI"                 # RINEX order of the satellites and their systems' header lines
_SYS_INDEX = np.full(256, -1, dtype=int)
for _g, _s in SYSTEM_OF_GNSS_ID.items():
    _SYS_INDEX[_g] = _SYSTEMS.index(_s)
_CODES = {s: list(dict.fromkeys(c for (ss, _), c in SIGNALS.items() if ss == s)) for s in _SYSTEMS}
_RANK = np.full((len(_SYSTEMS), 256), -1, dtype=int)        # [system, sigId] -> position in _CODES[system]
for (_s, _g), _c in SIGNALS.items():
    _RANK[_SYSTEMS.index(_s), _g] = _CODES[_s].index(_c)


def _observations(rawx: list[tuple[np.ndarray, np.ndarray]], path: str) -> CarrierObs:
    """Per-epoch code, phase, Doppler, C/N0 and RTKLIB's LLI of the RAWX messages as `CarrierObs` arrays."""
    t = np.array([h["week"] * SECONDS_PER_WEEK + h["rcvTow"] for h, _ in rawx], dtype=float)
    meas = np.concatenate([m for _, m in rawx])
    ep = np.repeat(np.arange(len(rawx)), [len(m) for _, m in rawx])
    si = _SYS_INDEX[meas["gnssId"]]
    rank = np.where(si >= 0, _RANK[np.maximum(si, 0), meas["sigId"]], -1)
    sv = meas["svId"].astype(int)
    prn = sv - np.where(si == _SYSTEMS.index("S"), 100, 0)
    keep = (si >= 0) & (rank >= 0) & (prn >= 1) & (prn <= 99) & ~((si == _SYSTEMS.index("R")) & (sv == 255))
    meas, ep, si, rank, prn = meas[keep], ep[keep], si[keep], rank[keep], prn[keep]
    trk = meas["trkStat"]
    P = np.where((trk & 1) != 0, meas["prMes"], np.nan)
    phase_ok = ((trk & 2) != 0) & (meas["cpMes"] != -0.5) & ((meas["cpStdev"] & 15) <= CPSTD_VALID)
    L = np.where(phase_ok, meas["cpMes"], np.nan)
    L = L + np.where((si == _SYSTEMS.index("C")) & ((prn <= 5) | (prn >= 59)), 0.5, 0.0)   # BeiDou GEO (RTKLIB)
    sat_key = si * 100 + prn                   # sorts in RINEX order: system, then PRN
    sat_keys, i_sat = np.unique(sat_key, return_inverse=True)
    sats = [f"{_SYSTEMS[k // 100]}{k % 100:02d}" for k in sat_keys.tolist()]
    # loss of lock per (satellite, signal): compared with that signal's previous measurement in the log
    order = np.lexsort((ep, rank, sat_key))
    k_s = (sat_key * 64 + rank)[order]
    lock, halfc = meas["locktime"][order].astype(int), (trk[order] >> 3) & 1
    first = np.r_[True, k_s[1:] != k_s[:-1]]
    prev_lock = np.where(first, 0, np.r_[0, lock[:-1]])
    prev_halfc = np.where(first, 0, np.r_[0, halfc[:-1]])
    slip_s = (lock == 0) | (lock < prev_lock) | (halfc != prev_halfc)
    slip = np.empty(len(order), dtype=bool)
    slip[order] = _held_slips(slip_s, np.isfinite(L[order]), first) | (ep[order] == 0)
    slip &= np.isfinite(L)
    lli = slip.astype(np.uint8) | np.where(trk & 4, 0, 2).astype(np.uint8)
    # one slot per signal a system has in the log, in the order of `SIGNALS`
    signals: dict[tuple[str, int], tuple[str, str]] = {}
    slot_lut = np.zeros((len(_SYSTEMS), 64), dtype=int)
    for k, sys in enumerate(_SYSTEMS):
        for f, r in enumerate(np.unique(rank[si == k]).tolist()):
            signals[(sys, f)] = ("C" + _CODES[sys][r], "L" + _CODES[sys][r])
            slot_lut[k, r] = f
    i_slot = slot_lut[si, rank]
    n_slots = max([f + 1 for (_, f) in signals] or [1])
    shape = (len(t), len(sats), n_slots)
    arrays = {name: np.full(shape, np.nan) for name in ("P", "L", "D", "snr")}
    for name, v in (("P", P), ("L", L), ("D", meas["doMes"].astype(float)), ("snr", meas["cno"].astype(float))):
        arrays[name][ep, i_sat, i_slot] = v
    lli_arr = np.zeros(shape, dtype=np.uint8)
    lli_arr[ep, i_sat, i_slot] = lli
    band_hz = np.full((len(_SYSTEMS), 64), np.nan)
    for k, sys in enumerate(_SYSTEMS):
        for r, c in enumerate(_CODES[sys]):
            band_hz[k, r] = BAND_FREQ_HZ.get((sys, c[0]), np.nan)
    f_meas = band_hz[si, rank]
    glo = si == _SYSTEMS.index("R")
    k_glo = meas["freqId"].astype(int) - 7
    g1 = np.array([c[0] == "1" for c in _CODES["R"]])[np.where(glo, rank, 0)]
    f_meas = np.where(glo, np.where(g1, F1_BASE_HZ + k_glo * F1_STEP_HZ,
                                    _GLO_BAND2_BASE_HZ + k_glo * _GLO_BAND2_STEP_HZ), f_meas)
    freq = np.full((len(sats), n_slots), np.nan)
    freq[i_sat, i_slot] = f_meas
    return CarrierObs(source=path, t_gps=t, sats=sats, freq_hz=freq, P=arrays["P"], L=arrays["L"], D=arrays["D"],
                      snr=arrays["snr"], lli=lli_arr, signals=signals, p_approx_ecef=np.full(3, np.nan),
                      receiver="U-BLOX", antenna="UNKNOWN")


def _held_slips(slip: np.ndarray, valid: np.ndarray, first: np.ndarray) -> np.ndarray:
    """RTKLIB convrnx's slip flags over measurements of one signal after another (`first` opens a signal): a slip
    seen where the phase is invalid is held until the signal's next valid phase, which carries it."""
    cs = np.cumsum(slip)
    grp = np.cumsum(first) - 1
    start = np.nonzero(first)[0]
    before_grp = cs[start] - slip[start]            # slips counted before each signal's first measurement
    pos = np.nonzero(valid)[0]
    prev = np.r_[-1, pos[:-1]]
    same = (prev >= 0) & (grp[np.maximum(prev, 0)] == grp[pos])
    c_prev = np.where(same, cs[np.maximum(prev, 0)], before_grp[grp[pos]])
    out = np.zeros(len(slip), dtype=bool)
    out[pos] = cs[pos] - c_prev > 0
    return out


def _bits(msg: bytes, pos: int, n: int, signed: bool = False) -> int:
    """`n` bits of `msg` from bit `pos` (MSB first), two's complement when `signed`."""
    v = (int.from_bytes(msg, "big") >> (len(msg) * 8 - pos - n)) & ((1 << n) - 1)
    return v - (1 << n) if signed and v >> (n - 1) else v


def _klobuchar(words: bytes) -> np.ndarray | None:
    """GPS Klobuchar (alpha, beta) of an LNAV subframe 4 page 18 (SV id 56) as u-blox delivers it (ten 32-bit
    words, 2 padding bits then 24 data bits each), else None."""
    if _bits(words, 2, 8) != 0x8B or _bits(words, 53, 3) != 4 or _bits(words, 68, 6) != 56:
        return None
    pos = (74, 82, 98, 106, 114, 130, 138, 146)
    v = [_bits(words, p, 8, signed=True) for p in pos]
    scale = (2.0 ** -30, 2.0 ** -27, 2.0 ** -24, 2.0 ** -24, 2.0 ** 11, 2.0 ** 14, 2.0 ** 16, 2.0 ** 16)
    return (np.array(v) * np.array(scale)).reshape(2, 4)


def _with_fit(eph, frames: bytearray | None):
    """An LNAV ephemeris with RTKLIB's fit interval (hours: 4 for fit flag 0, else 0) from its subframe 2, which
    cssrlib's decoder reads but does not keep."""
    if eph is not None and frames is not None:
        eph.fit = 0.0 if _bits(bytes(frames[40:80]), 32 * 9 + 2 + 16, 1) else 4.0
    return eph


def _decode_sfrbx(rn: RawNav, payload: bytes, week: int, tow: float):
    """A cssrlib ephemeris from one SFRBX message (None until a satellite's set is complete), or Klobuchar (2x4)."""
    if len(payload) < 8:
        raise ValueError("short SFRBX")
    gnss, sv, sig, _, n_words = payload[0], payload[1], payload[2], payload[3], payload[4]
    if len(payload) != 8 + 4 * n_words:
        raise ValueError("SFRBX length disagrees with numWords")
    words = np.frombuffer(payload, "<u4", n_words, 8).astype(">u4").tobytes()
    s = SYSTEM_OF_GNSS_ID.get(gnss, "")
    if s == "G" and sig == 0 and n_words >= 10:
        ion = _klobuchar(words[:40])
        if ion is not None:
            return ion
        return _with_fit(rn.decode_gps_lnav(week, tow, prn2sat(uGNSS.GPS, sv), words), rn.gps_lnav.get(sv - 1))
    if s == "J" and sig in (0, 12) and n_words >= 10:
        return _with_fit(rn.decode_gps_lnav(week, tow, prn2sat(uGNSS.QZS, sv + 192), words), rn.qzs_lnav.get(sv - 1))
    if s == "E" and sig in (1, 5) and n_words >= 8:      # I/NAV E1B, E5bI: even and odd page halves
        b = bytearray(words)
        b[15:30] = b[16:31]      # drop the 8 bits between the halves (cssrlib's page layout)
        b[30] = 0
        return rn.decode_gal_inav(week, tow, prn2sat(uGNSS.GAL, sv), 0 if sig == 1 else 2, bytes(b))
    if s == "E" and sig == 3 and n_words >= 8:           # F/NAV E5aI
        return rn.decode_gal_fnav(week, tow, prn2sat(uGNSS.GAL, sv), 1, words)
    if s == "C" and sig in (0, 4) and 6 <= sv <= 58 and n_words >= 10:   # D1 on B1I / B3I (MEO/IGSO)
        packed = 0
        for w in np.frombuffer(payload, "<u4", 10, 8).tolist():      # 30-bit words back to back (cssrlib, RTKLIB)
            packed = (packed << 30) | (w & 0x3FFFFFFF)
        eph = rn.decode_bds_d1(week, tow, prn2sat(uGNSS.BDS, sv), (packed << 20).to_bytes(40, "big"))
        if eph is not None:      # cssrlib's decoder leaves toc/toe in BDT, its encoder expects GPS time (tot: BDT)
            eph.toc, eph.toe, eph.tot = bdt2gpst(eph.toc), bdt2gpst(eph.toe), gpst2bdt(eph.tot)
        return eph
    return None


def read_ubx(data: bytes, path: str | Path = "") -> UbxLog:
    """Decode a UBX byte stream: RAWX observations and SFRBX ephemerides, with the counts of what was skipped."""
    frames = ubx_frames(data)
    log = UbxLog(path=str(path), obs=None, eph=[], ion_gps=None, leap_seconds=None, bad_checksum=frames.bad_checksum,
                 truncated=frames.truncated, junk_bytes=frames.junk_bytes)
    rawx = []
    for cls, mid, payload in frames.messages:
        if (cls, mid) != RAWX:
            continue
        r = _rawx(payload)
        if r is None:
            log.malformed += 1
            continue
        rawx.append(r)
        if r[0]["recStat"] & 1 and log.leap_seconds is None:     # leapSec determined
            log.leap_seconds = int(r[0]["leapS"])
    log.n_rawx = len(rawx)
    if rawx:
        t = np.array([h["week"] * SECONDS_PER_WEEK + h["rcvTow"] for h, _ in rawx])
        if np.any(np.diff(t) <= 0):      # a receiver restart or a concatenated log: epochs in time order, once
            t_u, i_u = np.unique(t, return_index=True)
            log.notes.append(f"{len(t) - len(t_u)} RAWX epoch(s) repeated or out of time order: sorted, once each")
            rawx = [rawx[i] for i in i_u]
        log.obs = _observations(rawx, str(path))
    _navigation(frames, rawx, log)
    return log


def _navigation(frames: UbxFrames, rawx: list, log: UbxLog) -> None:
    """Ephemerides and Klobuchar coefficients of the SFRBX messages (week and time of the nearest RAWX epoch)."""
    rn = RawNav()
    rn.monlevel = 0
    week, tow = (int(rawx[0][0]["week"]), float(rawx[0][0]["rcvTow"])) if rawx else (None, 0.0)
    seen: set[tuple] = set()
    for cls, mid, payload in frames.messages:
        if (cls, mid) == RAWX:
            r = _rawx(payload)
            if r is not None:
                week, tow = int(r[0]["week"]), float(r[0]["rcvTow"])
            continue
        if (cls, mid) != SFRBX:
            continue
        log.n_sfrbx += 1
        if week is None:
            continue
        try:
            out = _decode_sfrbx(rn, payload, week, tow)
        except (ValueError, IndexError, KeyError, OverflowError, ZeroDivisionError):
            log.malformed += 1
            continue
        if isinstance(out, np.ndarray):
            log.ion_gps = out
        elif out is not None:
            key = (out.sat, out.mode, out.iode, out.toes, out.week)
            if key not in seen:
                seen.add(key)
                log.eph.append(out)


def _hdr(text: str, label: str) -> str:
    return f"{text:<60.60}{label:<20}"


def obs_lines(log: UbxLog) -> list[str]:
    """RINEX 3.04 observation file lines of the log's RAWX observations (dgcal's carrier-phase RINEX writer)."""
    if log.obs is None or not len(log.obs.t_gps):
        raise InputError(NO_RAWX + _skipped_note(log), log.path)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ubx.obs"
        write_rinex_carrier(out, log.obs, marker="UBX", comment=f"u-blox UBX log {Path(log.path).name}"[:60])
        return out.read_text().splitlines()


def nav_lines(log: UbxLog) -> list[str]:
    """RINEX 3.04 navigation file lines of the log's ephemerides (cssrlib's RINEX encoder for the records)."""
    if not log.eph:
        raise InputError(NO_EPH + _skipped_note(log), log.path)
    lines = [_hdr(f"{3.04:9.2f}{'':11}{'N: GNSS NAV DATA':<20}{'M: Mixed':<20}", "RINEX VERSION / TYPE"),
             _hdr(f"{'dgcal':<20}{'':<40}", "PGM / RUN BY / DATE"),
             _hdr(f"u-blox UBX log {Path(log.path).name}", "COMMENT")]
    if log.ion_gps is not None:
        for name, row in (("GPSA", log.ion_gps[0]), ("GPSB", log.ion_gps[1])):
            lines.append(_hdr(f"{name} " + "".join(f"{v:12.4E}" for v in row), "IONOSPHERIC CORR"))
    if log.leap_seconds is not None:
        lines.append(_hdr(f"{log.leap_seconds:6d}", "LEAP SECONDS"))
    lines.append(_hdr("", "END OF HEADER"))
    enc, buf = rnxenc(), io.StringIO()
    for e in sorted(log.eph, key=lambda e: (sat2id(e.sat), e.week, e.toes)):
        enc.rnx_nav_body(e, buf)
    lines += [x for x in buf.getvalue().splitlines() if not x.startswith("> ")]   # RINEX 4 record lines
    return lines


def _skipped_note(log: UbxLog) -> str:
    if not (log.skipped or log.junk_bytes):
        return ""
    return (f" ({log.n_rawx} RAWX and {log.n_sfrbx} SFRBX messages read; skipped: {log.bad_checksum} failed "
            f"checksum(s), {log.truncated} truncated, {log.malformed} malformed; {log.junk_bytes} bytes outside UBX "
            "frames)")


def ubx_rinex_lines(data: bytes, path: str | Path, kind: str) -> list[str]:
    """RINEX 3.04 lines of a UBX log: its observations (`kind` "obs") or its ephemerides ("nav"); InputError naming
    the file when the log has none."""
    if kind not in ("obs", "nav"):
        raise InputError("a u-blox UBX log is read as observations (--rinex-obs) or navigation (--rinex-nav) "
                         "only", path)
    log = read_ubx(data, path)
    lines = obs_lines(log) if kind == "obs" else nav_lines(log)
    if log.skipped:      # said in the RINEX header's comments (a reader's warnings quote nothing else from the log)
        i = next(j for j, x in enumerate(lines) if x[60:].startswith("END OF HEADER"))
        lines.insert(i, _hdr(f"UBX: {log.skipped} message(s) skipped", "COMMENT"))
    return lines
