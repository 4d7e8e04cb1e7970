"""RINEX 2.10/2.11 and 3.x observation files: every observation code of every system, read into arrays.

``read_obs_file`` is dgcal's own reader (cssrlib reads only RINEX >= 3.02 and refuses some codes of
the RINEX 3 tables, such as the receiver channel numbers ``X1`` of Septentrio files). It keeps every
observation type of the header, per system, as ``(epoch, satellite, code)`` arrays of values, loss-
of-lock indicators (LLI) and signal strengths (SSI). RINEX 2 observation types are translated into
RINEX 3 codes on reading (``rinex2_code``, RTKLIB's conventions: GPS ``C1`` -> ``C1C``, ``P1`` ->
``C1W``, ``P2`` -> ``C2W``, ``L1`` -> ``L1C``, ``L2`` -> ``L2W``, Galileo ``C1`` -> ``C1X`` ...),
and RINEX 3.00/3.01 BeiDou band ``1`` (B1I) becomes band ``2`` as from RINEX 3.02, so that files of
every version come out in the same form. Times are GPS time (``BDT`` files are shifted by 14 s, a
``GLO`` (UTC) file by the leap seconds).

Fields are decoded with NumPy over all records of a system at once; a malformed field is reported
as ``InputError`` naming the file, the line and the observation code. Epoch records are checked for their
structure: a satellite count that disagrees with the lines that follow skips the record, epochs out of time
order are sorted, repeated epochs dropped, each with a warning naming the file and line
(``RinexObsFile.warnings``).
"""
from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_DAY
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.gnss_files import read_gnss_lines

GPS_EPOCH = _dt.datetime(1980, 1, 6)
BDT_MINUS_GPST_S = -14.0          # BeiDou time = GPS time - 14 s
GLONASS_NOT_USED = ("GLONASS observations of {n} satellite(s) not used (add R to --systems: spp, and lc/ukf without a "
                    "base station, use GLONASS)")
KNOWN_SYSTEMS = "GRECJSI"         # GPS, GLONASS, Galileo, BeiDou, QZSS, SBAS, NavIC/IRNSS


def read_lines(path: str | Path, kind: str | None = None) -> list[str]:
    """All lines of a GNSS text file without line ends: plain, gzip, .Z, bzip2, zip or Hatanaka-compressed, or a
    u-blox UBX log as RINEX 3.04 observations (`kind` "obs") or navigation ("nav") (`dgcal.pos.gnss.gnss_files`)."""
    return read_gnss_lines(path, kind)


def rinex2_code(system: str, code: str, version: float) -> str | None:
    """The RINEX 3 code of a RINEX 2.10/2.11 (or 2.12) observation type for a system letter, or None.

    RTKLIB's translation: pseudorange ``C1`` is C/A (``C1C``; Galileo ``C1X``), ``P1``/``P2`` are
    P(Y) (``C1W``/``C2W``), ``C2`` is L2C (``C2X``; BeiDou B1 ``C2X``), phase/Doppler/SNR on band 1
    follow C/A (``L1C``) and on band 2 P(Y) (``L2W``); bands 5/6/7/8 have attribute ``X``.
    """
    if len(code) != 2 or code[0] not in "CPLDS":
        return None
    typ, band = code[0], code[1]
    if typ == "P":
        if band in "12" and system == "G":
            return f"C{band}W"
        if band in "12" and system == "R":
            return f"C{band}P"
        return None
    if system == "G":
        if band == "1":
            return f"{typ}1C"
        if band == "2":
            if typ == "C":
                return "C2W" if version >= 2.12 else "C2X"
            return f"{typ}2W"
        if band == "5":
            return f"{typ}5X"
    elif system == "R":
        if band in "12":
            return f"{typ}{band}" + ("C" if typ == "C" or band == "1" else "P")
    elif system == "E":
        if band in "15678":
            return f"{typ}{band}X"
    elif system == "J":
        if band == "1":
            return f"{typ}1C"
        if band in "256":
            return f"{typ}{band}X"
    elif system == "C":
        if band in "12":             # RINEX 2.12 B1 (1561.098 MHz) is band 2 in RINEX 3.02+
            return f"{typ}2X"
        if band in "67":
            return f"{typ}{band}X"
    elif system == "S":
        if band == "1":
            return f"{typ}1C"
        if band == "5":
            return f"{typ}5X"
    return None


@dataclass
class SystemObs:
    """The observations of one system: ``val[epoch, sat, code]`` (NaN = blank or zero), ``lli`` and
    ``ssi`` (0 when blank) in the same layout; ``sats`` ('G05', sorted), ``codes`` (RINEX 3, header order)."""

    sats: list[str]
    codes: list[str]
    val: np.ndarray
    lli: np.ndarray
    ssi: np.ndarray

    def column(self, code: str) -> int:
        """Index of an observation code in ``codes``."""
        return self.codes.index(code)


@dataclass
class RinexObsFile:
    """A RINEX observation file: header items and all observations (see ``SystemObs``).

    ``t_gps``: epoch times (continuous GPS seconds); ``power_failure``: epoch flag 1 (all carrier
    phases of that epoch may have slipped); ``epoch_line``: the line of each epoch record (for messages);
    ``epoch_sats``: the satellites of each epoch in file order. ``p_approx_ecef`` is NaN when the
    header has no (or a zero) APPROX POSITION XYZ. ``warnings``: epoch records skipped (satellite count
    inconsistent with the lines that follow), sorted into time order or dropped (repeated), each naming the file
    and line. ``glonass_k``: the GLONASS frequency channel of each satellite the header's GLONASS SLOT / FRQ #
    lines name (RINEX 3).
    """

    path: str
    version: float
    marker: str
    receiver: str
    antenna: str
    p_approx_ecef: np.ndarray
    antenna_delta_hen: np.ndarray
    interval_s: float
    time_system: str
    obs_types: dict[str, list[str]]
    t_gps: np.ndarray
    power_failure: np.ndarray
    epoch_line: np.ndarray
    epoch_sats: list[list[str]]
    systems: dict[str, SystemObs]
    first_obs_line: int = 0
    header_lines: int = 0
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)   # epoch records skipped, sorted or dropped (file:line)
    glonass_k: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_gps)


def gps_seconds(year: int, month: int, day: int, hour: int, minute: int, sec: float) -> float:
    """Calendar date and time (in the GPS time scale) -> continuous GPS seconds."""
    d = _dt.datetime(year, month, day, hour, minute) - GPS_EPOCH
    return d.days * SECONDS_PER_DAY + d.seconds + float(sec)


def _header_label(line: str) -> str:
    return line[60:80].strip()


def _float(s: str, path, lineno, name) -> float:
    s = s.strip()
    if not s:
        return float("nan")
    try:
        return float(s.replace("D", "E").replace("d", "e"))
    except ValueError:
        raise InputError(f"not a number: {s!r}", path, lineno, name) from None


def _int(s: str, path, lineno, name, default: int | None = None) -> int:
    s = s.strip()
    if not s and default is not None:
        return default
    try:
        return int(s)
    except ValueError:
        raise InputError(f"not an integer: {s!r}", path, lineno, name) from None


def rinex_version_type(lines: list[str], path: Path) -> tuple[float, str]:
    """Version and file type (column 21: ``O``, ``N``, ...) of a RINEX 2/3 file from its first line, checked: the
    file is not empty, not left Hatanaka-compressed, begins with a ``RINEX VERSION / TYPE`` line of a version 2.x,
    3.x or 4.x (`InputError` naming line 1 otherwise). The caller checks the type."""
    if not lines:
        raise InputError("empty file", path, 1)
    first = lines[0]
    if "CRINEX VERS" in first:
        raise InputError("Hatanaka-compressed RINEX that did not expand (crx2rnx)", path, 1)
    if "RINEX VERSION / TYPE" not in first:
        raise InputError("not a RINEX file (no 'RINEX VERSION / TYPE' header line)", path, 1)
    try:
        version = float(first[:9])
    except ValueError:
        raise InputError("bad RINEX version", path, 1, "RINEX VERSION") from None
    if not 2.0 <= version < 5.0:                # written so that a 'nan' version fails it too
        raise InputError(f"RINEX version {version} is not supported (need 2.10-4.02)", path, 1, "RINEX VERSION")
    return version, first[20:21]


def _parse_header(lines: list[str], path: Path) -> dict:
    """Header items of a RINEX 2/3 observation file (version checked, obs types in RINEX 3 codes)."""
    version, typ = rinex_version_type(lines, path)
    if typ != "O":
        raise InputError(f"not an observation file (type '{typ}')", path, 1, "RINEX VERSION / TYPE")
    file_sys = lines[0][40:41].strip() or "G"
    h = {"version": version, "file_system": file_sys, "marker": "", "receiver": "", "antenna": "",
         "p_approx": np.full(3, np.nan), "delta_hen": np.zeros(3), "interval": float("nan"),
         "time_system": "", "obs_types": {}, "types2": [], "leap": None, "wavelength2": False, "glonass_k": {}}
    i = 1
    pending: tuple[str, int] | None = None   # (system, count) of a continued obs-types record
    n2 = 0
    while i < len(lines):
        line = lines[i]
        lab = _header_label(line)
        ln = i + 1
        if lab.startswith("END OF HEADER"):
            h["end"] = i
            break
        if lab == "MARKER NAME":
            h["marker"] = line[:60].strip()
        elif lab == "REC # / TYPE / VERS":
            h["receiver"] = line[20:40].strip()
        elif lab == "ANT # / TYPE":
            h["antenna"] = line[20:40].strip()
        elif lab == "APPROX POSITION XYZ":
            p = np.array([_float(line[14 * k:14 * (k + 1)], path, ln, lab) for k in range(3)])
            h["p_approx"] = p if np.all(np.isfinite(p)) and np.linalg.norm(p) > 1e6 else np.full(3, np.nan)
        elif lab == "ANTENNA: DELTA H/E/N":
            d = np.array([_float(line[14 * k:14 * (k + 1)], path, ln, lab) for k in range(3)])
            h["delta_hen"] = np.nan_to_num(d)
        elif lab == "INTERVAL":
            h["interval"] = _float(line[:10], path, ln, lab)
        elif lab == "TIME OF FIRST OBS":
            h["time_system"] = line[48:51].strip()
        elif lab == "LEAP SECONDS":
            h["leap"] = _int(line[:6], path, ln, lab, 18)
        elif lab == "GLONASS SLOT / FRQ #":
            # I3, then up to 8 of 'Rnn kk ' (A1, I2, 1X, I2, 1X) per line
            for k in range(8):
                sid, frq = line[4 + 7 * k:7 + 7 * k], line[8 + 7 * k:10 + 7 * k]
                if sid.strip():
                    if sid[0] != "R" or not sid[1:].strip().isdigit():
                        raise InputError(f"not a GLONASS satellite: {sid!r}", path, ln, lab)
                    h["glonass_k"][f"R{int(sid[1:]):02d}"] = _int(frq, path, ln, lab)
        elif lab == "WAVELENGTH FACT L1/2":
            if line[:12].split() and any(v.strip() == "2" for v in (line[0:6], line[6:12])):
                h["wavelength2"] = True
        elif lab == "SYS / # / OBS TYPES" and version >= 3.0:
            if line[0] != " ":
                s = line[0]
                n = _int(line[3:6], path, ln, lab)
                h["obs_types"][s] = []
                pending = (s, n)
            if pending is None:
                raise InputError("continuation line without a system", path, ln, lab)
            s, n = pending
            for k in range(13):
                c = line[7 + 4 * k:10 + 4 * k].strip()
                if c and len(h["obs_types"][s]) < n:
                    h["obs_types"][s].append(c)
        elif lab == "# / TYPES OF OBSERV" and version < 3.0:
            if line[:6].strip():
                n2 = _int(line[:6], path, ln, lab)
            for k in range(9):
                c = line[10 + 6 * k:12 + 6 * k].strip()
                if c and len(h["types2"]) < n2:
                    h["types2"].append(c)
        i += 1
    else:
        raise InputError("no END OF HEADER line", path, len(lines))
    if version >= 3.0:
        for s, codes in h["obs_types"].items():
            if version < 3.02 and s == "C":     # RINEX 3.00/3.01: B1I is band 1; band 2 from 3.02 on
                codes[:] = [c[0] + "2" + c[2:] if len(c) == 3 and c[1] == "1" else c for c in codes]
        if not h["obs_types"]:
            raise InputError("no SYS / # / OBS TYPES record", path, field="SYS / # / OBS TYPES")
    else:
        if not h["types2"]:
            raise InputError("no # / TYPES OF OBSERV record", path, field="# / TYPES OF OBSERV")
        if h["wavelength2"]:
            raise InputError("half-wavelength (squaring) phase data are not supported", path,
                             field="WAVELENGTH FACT L1/2")
    return h


def _time_offset(h: dict, path: Path) -> float:
    """Seconds to add to the file's epochs to get GPS time."""
    ts = h["time_system"] or {"C": "BDT", "R": "GLO", "E": "GAL", "J": "QZS"}.get(h["file_system"], "GPS")
    if ts in ("GPS", "GAL", "QZS", "IRN", ""):
        return 0.0
    if ts == "BDT":
        return -BDT_MINUS_GPST_S
    if ts in ("GLO", "UTC"):
        return float(h["leap"] if h["leap"] is not None else 18)
    raise InputError(f"unknown time system {ts!r}", path, field="TIME OF FIRST OBS")


def _epoch_time(line: str, v3: bool, path: Path, ln: int) -> float:
    if v3:
        parts = (line[2:6], line[7:9], line[10:12], line[13:15], line[16:18])
        sec = line[18:29]
    else:
        parts = (line[1:3], line[4:6], line[7:9], line[10:12], line[13:15])
        sec = line[15:26]
    try:
        y, mo, d, hh, mi = (int(p) for p in parts)
        s = float(sec)
    except ValueError:
        raise InputError(f"bad epoch time {line[:29].strip()!r}", path, ln, "EPOCH") from None
    if not v3:
        y += 2000 if y < 80 else 1900
    try:
        return gps_seconds(y, mo, d, hh, mi, s)
    except ValueError:
        raise InputError(f"bad epoch date {line[:29].strip()!r}", path, ln, "EPOCH") from None


def _decode_fields(rows: list[str], line_no: np.ndarray, n_codes: int, codes: list[str], path: Path):
    """Values, LLI and SSI of fixed-width records (field k at columns 16k..16k+15), vectorised."""
    width = 16 * n_codes
    n = len(rows)
    if n == 0:
        z = np.zeros((0, n_codes))
        return z, z.astype(np.uint8), z.astype(np.uint8)
    buf = "".join(r[:width].ljust(width) for r in rows).encode("ascii", "replace")
    a = np.frombuffer(buf, dtype=np.uint8).reshape(n, n_codes, 16)
    txt = np.ascontiguousarray(a[:, :, :14])
    blank = np.all(txt == 32, axis=2)
    s = txt.view("S14").reshape(n, n_codes)
    s = np.where(blank, b"nan", s)
    try:
        val = s.astype(np.float64)
    except ValueError:
        for r in range(n):
            for k in range(n_codes):
                if not blank[r, k]:
                    try:
                        float(s[r, k])
                    except ValueError:
                        raise InputError(f"not a number: {s[r, k].decode(errors='replace').strip()!r}", path,
                                         int(line_no[r, k]), codes[k]) from None
        raise
    # an F14.3 field holds at most 9 999 999 999.999: "inf", "nan" or 1e308 in one is a damaged record
    bad = ~blank & ~(np.abs(val) < 1e10)
    if bad.any():
        r, k = np.argwhere(bad)[0]
        raise InputError(f"not an observation value: {s[r, k].decode(errors='replace').strip()!r}", path,
                         int(line_no[r, k]), codes[k])
    val[val == 0.0] = np.nan

    def flag(col):
        c = a[:, :, col]
        out = np.where((c >= 48) & (c <= 57), c - 48, 0).astype(np.uint8)
        bad = ~((c >= 48) & (c <= 57)) & (c != 32)
        if bad.any():
            r, k = np.argwhere(bad)[0]
            raise InputError(f"bad {'LLI' if col == 14 else 'signal strength'} flag {chr(c[r, k])!r}", path,
                             int(line_no[r, k]), codes[k])
        return out
    return val, flag(14), flag(15)


def _sat_id(raw: str, file_system: str, path: Path, ln: int) -> str:
    """'G05' from a RINEX satellite field ('G05', 'G 5', ' 5' = the file's system in RINEX 2)."""
    r = raw.ljust(3)[:3]
    s = r[0] if r[0] != " " else file_system if file_system in KNOWN_SYSTEMS else "G"
    num = r[1:].strip()
    if s not in KNOWN_SYSTEMS or not num.isdigit():
        raise InputError(f"bad satellite {raw.strip()!r}", path, ln, "SATELLITE")
    return f"{s}{int(num):02d}"


# an epoch header of RINEX 2 (F11.7 seconds, flag, satellite count), or the blank-epoch form of event records
_EPOCH2 = re.compile(r"^ [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d[ \d]{2}\d\.\d{7}  [0-6][ \d]{2}\d"
                     r"|^ {28}[2-5][ \d]{2}\d")


@dataclass
class _Record:
    """One observation epoch record: its line index, time (GPS s), flag, satellite ids and per satellite
    (line index, field text)."""

    i: int
    t: float
    flag: int
    ids: list
    body: list


def _next_epoch(lines: list[str], j: int, v3: bool) -> int:
    """Index of the first epoch header line at or after j (len(lines) if none)."""
    n = len(lines)
    while j < n and not (lines[j].startswith(">") if v3 else _EPOCH2.match(lines[j])):
        j += 1
    return j


def _at_record_end(lines: list[str], j: int, v3: bool) -> bool:
    """Whether the first non-blank line at or after j starts an epoch record (or the file ends there)."""
    n = len(lines)
    while j < n and not lines[j].strip():
        j += 1
    return j >= n or (lines[j].startswith(">") if v3 else bool(_EPOCH2.match(lines[j])))


def _record_v3(lines: list[str], i: int, nsat: int):
    """Satellite ids and bodies of the RINEX 3 record at line index i claiming `nsat` satellites, and the index
    after it; None when the lines that follow do not hold exactly `nsat` satellite records."""
    n = len(lines)
    end = i + 1 + nsat
    if end > n or any(lines[j].startswith(">") for j in range(i + 1, end)) or not _at_record_end(lines, end, True):
        return None
    return [lines[j][:3] for j in range(i + 1, end)], [(j, lines[j][3:]) for j in range(i + 1, end)], end


def _record_v2(lines: list[str], i: int, nsat: int, per_sat_lines: int):
    """As `_record_v3` for RINEX 2: the satellite list (12 per line, continuation lines blank in columns 1-32),
    then `per_sat_lines` lines per satellite; None when the list, the bodies or what follows them disagree with
    the count (a field beyond the last id, a body line that is an epoch header, no epoch header after)."""
    n = len(lines)
    ids, j, cont = [], i, lines[i]
    for k in range(nsat):
        if k > 0 and k % 12 == 0:
            j += 1
            if j >= n or lines[j][:32].strip():
                return None
            cont = lines[j]
        ids.append(cont[32 + 3 * (k % 12):35 + 3 * (k % 12)])
    if nsat % 12 and cont[32 + 3 * (nsat % 12):35 + 3 * (nsat % 12)].strip():
        return None                                     # more satellites listed than claimed
    if any(not re.fullmatch(r"[A-Z ][ \d]\d", r.ljust(3)[:3]) for r in ids):
        return None
    j += 1
    end = j + nsat * per_sat_lines
    if end > n or any(_EPOCH2.match(lines[m]) for m in range(j, end)) or not _at_record_end(lines, end, False):
        return None
    body = [(j + per_sat_lines * k, "".join(lines[m].ljust(80)[:80] for m in range(j + per_sat_lines * k,
                                                                                   j + per_sat_lines * (k + 1))))
            for k in range(nsat)]
    return ids, body, end


def _special_record_end(lines: list[str], i: int, flag: int, nsat: int, v3: bool, per_sat_lines: int,
                        path: Path) -> int:
    """The index after an event record (flags 2-5: `nsat` header lines; 6: cycle-slip records)."""
    n = len(lines)
    if flag == 4 and any(("OBS TYPES" in lines[j][60:] or "TYPES OF OBSERV" in lines[j][60:])
                         for j in range(i + 1, min(i + 1 + nsat, n))):
        raise InputError("observation types change inside the file (event flag 4): not supported",
                         path, i + 1, "EPOCH FLAG")
    if flag == 6:
        return i + 1 + (nsat if v3 else (nsat * per_sat_lines + (max(nsat - 1, 0) // 12)))
    return i + 1 + nsat


def _scan_records(lines: list[str], h: dict, path: Path, t_start, t_end, warnings: list) -> list[_Record]:
    """The observation records in [t_start, t_end] (GPS s), in file order. A record whose satellite count
    disagrees with the lines that follow is skipped with a warning naming its line (the reading resumes at the
    next epoch header)."""
    v3 = h["version"] >= 3.0
    offset = _time_offset(h, path)
    per_sat_lines = (len(h["types2"]) + 4) // 5 if not v3 else 1
    out: list[_Record] = []
    i = h["end"] + 1
    n = len(lines)
    while i < n:
        line = lines[i]
        ln = i + 1
        if not line.strip():
            i += 1
            continue
        if v3:
            if line[0] != ">":
                raise InputError("expected an epoch record starting with '>'", path, ln, "EPOCH")
            flag = _int(line[31:32], path, ln, "EPOCH FLAG", 0)
            nsat = _int(line[32:35], path, ln, "NUMBER OF SATELLITES", 0)
        else:
            flag = _int(line[28:29], path, ln, "EPOCH FLAG", 0)
            nsat = _int(line[29:32], path, ln, "NUMBER OF SATELLITES", 0)
        if flag > 1:
            nxt = _special_record_end(lines, i, flag, nsat, v3, per_sat_lines, path)
            if nxt > n or not _at_record_end(lines, nxt, v3):
                nxt = _next_epoch(lines, i + 1, v3)
                warnings.append(f"{path}:{ln}: event record (flag {flag}) claims {nsat} lines that do not follow it: "
                                "skipped to the next epoch")
            i = nxt
            continue
        t = _epoch_time(line, v3, path, ln) + offset
        rec = _record_v3(lines, i, nsat) if v3 else _record_v2(lines, i, nsat, per_sat_lines)
        if rec is None:
            nxt = _next_epoch(lines, i + 1, v3)
            follow = nxt - i - 1 if v3 else None
            warnings.append(f"{path}:{ln}: epoch record claims {nsat} satellites" +
                            (f", {follow} satellite lines follow" if follow is not None else
                             ", which the lines that follow do not hold") + ": record skipped")
            i = nxt
            continue
        ids, body, i = rec
        if (t_start is not None and t < t_start - 1e-6) or (t_end is not None and t > t_end + 1e-6):
            continue
        out.append(_Record(ln - 1, t, flag, ids, body))
    return out


def _ordered(recs: list[_Record], path: Path, warnings: list) -> list[_Record]:
    """Records in time order: an epoch earlier than the one before it is moved (sorted, with a warning); an
    epoch repeating an earlier one's time is dropped (the first in the file kept, with a warning)."""
    if len(recs) < 2:
        return recs
    t = np.array([r.t for r in recs])
    back = np.flatnonzero(t[1:] < np.maximum.accumulate(t)[:-1]) + 1
    for k in back:
        j = int(np.argmax(t[:k]))
        warnings.append(f"{path}:{recs[k].i + 1}: epoch {_stamp(t[k])} comes after the later epoch {_stamp(t[j])} "
                        f"(line {recs[j].i + 1}): epochs sorted into time order")
    order = np.argsort(t, kind="stable")
    recs = [recs[k] for k in order]
    t = t[order]
    dup = np.flatnonzero(np.diff(t) < 1e-6) + 1
    for k in dup:
        first = k - 1
        while first > 0 and t[k] - t[first - 1] < 1e-6:
            first -= 1
        warnings.append(f"{path}:{recs[k].i + 1}: epoch {_stamp(t[k])} repeats the epoch of line {recs[first].i + 1}:"
                        " dropped (the first kept)")
    drop = set(dup.tolist())
    return [r for k, r in enumerate(recs) if k not in drop]


def _stamp(t_gps: float) -> str:
    d = GPS_EPOCH + _dt.timedelta(seconds=float(t_gps))
    return d.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def _system_arrays(recs: list[_Record], types: dict, keep_sys: set, h: dict, path: Path, warnings: list):
    """Per system the SystemObs of the records, and each epoch's satellites in file order."""
    v3 = h["version"] >= 3.0
    rows: dict[str, list[str]] = {s: [] for s in types}
    fline: dict[str, list] = {s: [] for s in types}
    where: dict[str, list[tuple[int, str]]] = {s: [] for s in types}
    sats_list = []
    known: dict[str, str] = {}       # raw satellite field -> id, checked once
    for k_ep, r in enumerate(recs):
        ep_sats: list[str] = []
        for raw_id, (lno, rec) in zip(r.ids, r.body):
            sid = known.get(raw_id)
            if sid is None:
                sid = known[raw_id] = _sat_id(raw_id, h["file_system"], path, (lno + 1) if v3 else r.i + 1)
            s = sid[0]
            if s not in types:
                if v3:
                    raise InputError(f"satellite {sid} of a system without SYS / # / OBS TYPES", path, lno,
                                     "SATELLITE")
                continue
            if s not in keep_sys:
                continue
            if sid in ep_sats:
                warnings.append(f"{path}:{lno + 1}: satellite {sid} twice in the epoch record of line {r.i + 1}: "
                                "the second dropped")
                continue
            ep_sats.append(sid)
            rows[s].append(rec)
            where[s].append((k_ep, sid))
            fline[s].append(lno + 1)
        sats_list.append(ep_sats)
    n_ep = len(recs)
    out_sys: dict[str, SystemObs] = {}
    for s in types:
        if not rows[s] or s not in keep_sys:
            continue
        codes = types[s]
        kc = len(codes)
        # each field's line: the record's in RINEX 3, in RINEX 2 five fields to a line
        first = np.array(fline[s], dtype=int)[:, None]
        lines = first + (np.zeros(kc, int) if v3 else np.arange(kc) // 5)[None, :]
        val, lli, ssi = _decode_fields(rows[s], lines, kc, codes, path)
        sats = sorted({sid for _, sid in where[s]})
        col = {sid: j for j, sid in enumerate(sats)}
        ep = np.array([k for k, _ in where[s]], dtype=int)
        sj = np.array([col[sid] for _, sid in where[s]], dtype=int)
        V = np.full((n_ep, len(sats), kc), np.nan)
        L = np.zeros((n_ep, len(sats), kc), dtype=np.uint8)
        S = np.zeros((n_ep, len(sats), kc), dtype=np.uint8)
        V[ep, sj], L[ep, sj], S[ep, sj] = val, lli, ssi
        keep = [k for k, c in enumerate(codes) if not c.startswith("?")]
        out_sys[s] = SystemObs(sats, [codes[k] for k in keep], V[:, :, keep], L[:, :, keep], S[:, :, keep])
    return out_sys, sats_list


def read_obs_file(path: str | Path, t_start: float | None = None, t_end: float | None = None,
                  systems: str | None = None) -> RinexObsFile:
    """Read a RINEX 2.10/2.11/3.x observation file: every code of every system (``systems``: letters to
    keep, default all), epochs in [t_start, t_end] (continuous GPS s) only.

    Epoch records are checked: a satellite count that disagrees with the lines that follow skips the record,
    an epoch out of time order is sorted in, a repeated epoch (or a satellite repeated in a record) is
    dropped — each with a warning naming the file and line in ``RinexObsFile.warnings``; so are GLONASS observations
    that ``systems`` leaves out (`GLONASS_NOT_USED`)."""
    path = Path(path)
    lines = read_lines(path, "obs")
    h = _parse_header(lines, path)
    v3 = h["version"] >= 3.0
    keep_sys = set(systems) if systems else set(KNOWN_SYSTEMS)
    if v3:
        types = {s: list(c) for s, c in h["obs_types"].items()}
    else:
        types = {s: [rinex2_code(s, c, h["version"]) or f"?{c}" for c in h["types2"]] for s in KNOWN_SYSTEMS}
    warnings: list[str] = []
    recs = _ordered(_scan_records(lines, h, path, t_start, t_end, warnings), path, warnings)
    if systems and "R" not in keep_sys:     # PPK and the GNSS/INS modes: say that GLONASS is left out
        glo = {i.strip() for r in recs for i in r.ids if i[:1] == "R" or (i[:1] == " " and h["file_system"] == "R")}
        if glo:
            warnings.append(f"{path}: " + GLONASS_NOT_USED.format(n=len(glo)))
    out_sys, sats_list = _system_arrays(recs, types, keep_sys, h, path, warnings)
    obs_types = {s: [c for c in types[s] if not c.startswith("?")] for s in types
                 if v3 or s in out_sys}
    return RinexObsFile(path=str(path), version=h["version"], marker=h["marker"], receiver=h["receiver"],
                        antenna=h["antenna"], p_approx_ecef=h["p_approx"], antenna_delta_hen=h["delta_hen"],
                        interval_s=h["interval"], time_system=h["time_system"] or "GPS", obs_types=obs_types,
                        t_gps=np.array([r.t for r in recs], dtype=float),
                        power_failure=np.array([r.flag == 1 for r in recs], dtype=bool),
                        epoch_line=np.array([r.i + 1 for r in recs], dtype=int), epoch_sats=sats_list,
                        systems=out_sys, first_obs_line=h["end"] + 2, header_lines=h["end"] + 1,
                        warnings=warnings, glonass_k=dict(h["glonass_k"]))
