"""RINEX navigation files of every version in the form cssrlib's decoder reads (RINEX 3.02+).

RINEX 4.00-4.02 files (IGS's BRD4 merged files, receivers' own) are laid out as RINEX 3 first: their record-type
lines blanked, the messages RINEX 3 carries kept, the Klobuchar ION records read into the header's coefficients.

cssrlib decodes RINEX >= 3.02 navigation records. ``nav_text_for_cssrlib`` hands it RINEX 3.02-3.05
files unchanged, 3.00/3.01 files with the version patched (their GPS/Galileo/BeiDou/QZSS records are
laid out the same), and RINEX 2.10/2.11 GPS navigation files (type ``N``) rewritten record by record
into RINEX 3 layout with **the same line numbers**, so that decoder messages still name the original
line. Every numeric field of a RINEX 2 record is checked on the way (``InputError`` naming file, line
and the field's name). GLONASS records (RINEX 3 ``R`` records of 4 or 5 lines, RINEX 2 ``G`` files), which cssrlib's
path does not serve here, are read into `dgcal.pos.gnss.glonass.GlonassEphemerides` (``NavHeader.glonass``) and left
out of the text handed on. The header's Klobuchar coefficients are returned as well (RINEX 3
``GPSA/GPSB``, ``QZSA/QZSB``, ``BDSA/BDSB``; RINEX 2 ``ION ALPHA/ION BETA``) with the leap seconds.
"""
from __future__ import annotations

import datetime as _dt
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.pos.gnss.glonass import GlonassEphemerides, gps_minus_utc_s, gps_seconds_from_utc
from dgcal.pos.gnss.rinex_obs import read_lines, rinex_version_type

# RTKLIB's default Klobuchar coefficients (alpha, beta; 2004/1/1), used when a file has none
ION_DEFAULT = np.array([[0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06],
                        [0.1167e+06, -0.2294e+06, -0.1311e+06, 0.1049e+07]])

_GPS_FIELDS = (("SV clock bias", "SV clock drift", "SV clock drift rate"),
               ("IODE", "Crs", "Delta n", "M0"), ("Cuc", "e", "Cus", "sqrt(A)"),
               ("Toe", "Cic", "OMEGA0", "Cis"), ("i0", "Crc", "omega", "OMEGA DOT"),
               ("IDOT", "L2 codes", "GPS week", "L2 P flag"), ("SV accuracy", "SV health", "TGD", "IODC"),
               ("transmission time", "fit interval", "spare", "spare"))
_GAL_FIELDS = (("SV clock bias", "SV clock drift", "SV clock drift rate"),
               ("IODnav", "Crs", "Delta n", "M0"), ("Cuc", "e", "Cus", "sqrt(A)"),
               ("Toe", "Cic", "OMEGA0", "Cis"), ("i0", "Crc", "omega", "OMEGA DOT"),
               ("IDOT", "data sources", "GAL week", "spare"), ("SISA", "SV health", "BGD E5a/E1", "BGD E5b/E1"),
               ("transmission time", "spare", "spare", "spare"))
_BDS_FIELDS = (("SV clock bias", "SV clock drift", "SV clock drift rate"),
               ("AODE", "Crs", "Delta n", "M0"), ("Cuc", "e", "Cus", "sqrt(A)"),
               ("Toe", "Cic", "OMEGA0", "Cis"), ("i0", "Crc", "omega", "OMEGA DOT"),
               ("IDOT", "spare", "BDT week", "spare"), ("SV accuracy", "SatH1", "TGD1", "TGD2"),
               ("transmission time", "AODC", "spare", "spare"))
_FIELDS = {"G": _GPS_FIELDS, "J": _GPS_FIELDS, "E": _GAL_FIELDS, "C": _BDS_FIELDS}
USED_SYSTEMS = "GECJ"                    # read by cssrlib; GLONASS ('R') by `_glonass_record`
_GLO_FIELDS = (("-TauN", "+GammaN", "message frame time"), ("X", "X velocity", "X acceleration", "health"),
               ("Y", "Y velocity", "Y acceleration", "frequency number"),
               ("Z", "Z velocity", "Z acceleration", "age of operation"))
SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "C": "BeiDou", "J": "QZSS", "S": "SBAS", "I": "NavIC"}


@dataclass
class NavHeader:
    """What a navigation header says: version, file type, Klobuchar pairs (2x4 or None), leap seconds."""

    version: float
    file_type: str
    ion_gps: np.ndarray | None
    ion_qzs: np.ndarray | None
    ion_bds: np.ndarray | None
    leap_seconds: int
    end_line: int
    skipped: str = ""                   # the records left out (systems dgcal does not use), for a warning
    glonass: GlonassEphemerides | None = None   # the GLONASS records, read here (not by cssrlib)


def fortran_float(s: str, path, ln: int, name: str, blank: float | None = None) -> float:
    """A number of a RINEX/SP3 field (Fortran `D` exponents allowed); a blank field is `blank` (None: an error);
    InputError naming file, line and field for anything else that is not a finite number."""
    t = s.strip()
    if not t and blank is not None:
        return blank
    try:
        v = float(t.replace("D", "E").replace("d", "e"))
    except ValueError:
        raise InputError(f"not a number: {t!r}", path, ln, name) from None
    if not np.isfinite(v):
        raise InputError(f"not a finite number: {t!r}", path, ln, name)
    return v


def _num(s: str, path, ln: int, name: str) -> float:
    return fortran_float(s, path, ln, name, blank=0.0)


def parse_nav_header(lines: list[str], path: Path) -> NavHeader:
    """Version, type, ionosphere coefficients and leap seconds of a RINEX 2/3/4 navigation header (RINEX 4 keeps
    the coefficients in ION records: `_rinex4_as_3`)."""
    ver, typ = rinex_version_type(lines, path)
    if ver >= 3.0 and typ != "N":
        raise InputError(f"not a navigation file (type '{typ}')", path, 1, "RINEX VERSION / TYPE")
    if ver < 3.0 and typ not in ("N", "G", "H", "E", "J"):
        raise InputError(f"not a navigation file (type '{typ}')", path, 1, "RINEX VERSION / TYPE")
    coef: dict[str, list[float]] = {}
    leap = 18
    end = None
    for i, line in enumerate(lines[1:], start=1):
        lab = line[60:80].strip()
        ln = i + 1
        if lab.startswith("END OF HEADER"):
            end = i
            break
        if lab.startswith("IONOSPHERIC CORR"):
            key = line[0:4]
            coef[key] = [_num(line[5 + 12 * k:5 + 12 * (k + 1)], path, ln, key) for k in range(4)]
        elif lab.startswith("ION ALPHA") or lab.startswith("ION BETA"):
            key = "GPSA" if "ALPHA" in lab else "GPSB"
            coef[key] = [_num(line[2 + 12 * k:2 + 12 * (k + 1)], path, ln, lab) for k in range(4)]
        elif lab.startswith("LEAP SECONDS"):
            try:
                leap = int(line[:6])
            except ValueError:
                raise InputError("not an integer", path, ln, "LEAP SECONDS") from None
    if end is None:
        raise InputError("no END OF HEADER line", path, len(lines))

    def pair(a: str, b: str):
        if a in coef and b in coef:
            v = np.array([coef[a], coef[b]])
            return v if np.any(v) else None
        return None

    return NavHeader(ver, typ, pair("GPSA", "GPSB"), pair("QZSA", "QZSB"), pair("BDSA", "BDSB"), leap, end)


def _glonass_record(lines: list[str], i: int, path: Path, rinex2: bool) -> dict:
    """One GLONASS record starting at line index i: RINEX 3 ``Rnn yyyy mm dd hh mm ss`` + 3 orbit lines (a 3.05
    status line after them is not needed), or RINEX 2 ``nn yy mm dd hh mm ss.s`` + 3; epoch UTC -> GPS seconds,
    kilometres -> metres; every field checked (`InputError` naming file, line and field)."""
    line, ln = lines[i], i + 1
    try:
        if rinex2:
            prn = int(line[0:2])
            ep = [int(line[2 + 3 * k:5 + 3 * k]) for k in range(5)] + [float(line[17:22])]
            ep[0] += 2000 if ep[0] < 80 else 1900
            c0, c1 = 22, 3
        else:
            prn = int(line[1:3])
            ep = [int(x) for x in line[4:23].split()]
            c0, c1 = 23, 4
        if len(ep) != 6 or not (1980 <= ep[0] <= 2200 and 1 <= ep[1] <= 12 and 1 <= ep[2] <= 31
                                and 0 <= ep[5] < 61):
            raise ValueError
    except ValueError:
        raise InputError(f"bad GLONASS satellite / epoch {line[:23].strip()!r}", path, ln,
                         "SV / EPOCH / SV CLK") from None
    clk = [_num(line[c0 + 19 * k:c0 + 19 * (k + 1)], path, ln, _GLO_FIELDS[0][k]) for k in range(3)]
    orb = []
    for m in range(1, 4):
        if i + m >= len(lines) or not lines[i + m].strip():
            raise InputError(f"GLONASS record with {m - 1} orbit lines (3 expected)", path, min(i + m + 1, len(lines)),
                             f"BROADCAST ORBIT - {m}")
        orb.append([_num(lines[i + m][c1 + 19 * k:c1 + 19 * (k + 1)], path, i + m + 1,
                         f"BROADCAST ORBIT - {m}: {_GLO_FIELDS[m][k]}") for k in range(4)])
    o = np.array(orb)
    sec = float(ep[5])
    try:
        toe = gps_seconds_from_utc(*ep[:5], sec)
    except ValueError:          # 30 February, hour 25
        raise InputError(f"not a date: {line[:23].strip()!r}", path, ln, "SV / EPOCH / SV CLK") from None
    pos, vel, acc = o[:, 0] * 1e3, o[:, 1] * 1e3, o[:, 2] * 1e3
    if not (1.5e7 < np.linalg.norm(pos) < 3.5e7 and np.linalg.norm(vel) < 1e4 and abs(clk[0]) < 1.0
            and abs(clk[1]) < 1e-6 and abs(o[1, 3]) <= 20 and abs(o[0, 3]) < 1e6 and abs(o[2, 3]) < 1e6):
        raise InputError("GLONASS record with an impossible orbit, clock, health, age or frequency number", path, ln,
                         "SV / EPOCH / SV CLK")
    return {"sat": f"R{prn:02d}", "toe": toe, "pos": pos, "vel": vel, "acc": acc, "taun": -clk[0], "gamn": clk[1],
            "frq": int(round(o[1, 3])), "svh": int(round(o[0, 3])), "age": o[2, 3], "line": ln}


def _add_glonass(lines: list[str], i: int, path: Path, rinex2: bool, rows: list, bad: list) -> None:
    """`_glonass_record` at line index i into `rows`, or, when it cannot be read, its location and reason into `bad`:
    GLONASS is optional (SPP only, when asked for), so a record dgcal cannot use leaves the file readable."""
    try:
        rows.append(_glonass_record(lines, i, path, rinex2))
    except InputError as exc:
        bad.append(f"line {exc.line}" + (f" ({exc.field})" if exc.field else "") + f": {exc.reason}")


def _glonass_note(bad: list[str]) -> str:
    """The warning for GLONASS records left out (first three named)."""
    if not bad:
        return ""
    return (f"{len(bad)} GLONASS record(s) that cannot be read left out: " + "; ".join(bad[:3])
            + (" ..." if len(bad) > 3 else ""))


def _rinex2_glonass(lines: list[str], hdr: NavHeader, path: Path) -> GlonassEphemerides | None:
    """The records of a RINEX 2 GLONASS navigation file (type 'G'; 4 lines each); unreadable ones are named in
    ``hdr.skipped``."""
    rows: list = []
    bad: list = []
    i = hdr.end_line + 1
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        _add_glonass(lines, i, path, True, rows, bad)
        i += 4
    hdr.skipped = _glonass_note(bad)
    return GlonassEphemerides.from_rows(rows) if rows else None


def _rinex2_gps_to_3(lines: list[str], hdr: NavHeader, path: Path) -> list[str]:
    """RINEX 2 GPS records rewritten in RINEX 3 layout, line for line (same numbering)."""
    out = [""] * len(lines)
    out[0] = f"{3.04:9.2f}{'':11}{'N: GNSS NAV DATA':<20}{'G: GPS':<20}RINEX VERSION / TYPE"
    for i in range(1, hdr.end_line):
        out[i] = f"{'converted from RINEX 2 by dgcal':<60}COMMENT"
    out[hdr.end_line] = f"{'':60}END OF HEADER"
    i = hdr.end_line + 1
    n = len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            out[i] = ""
            i += 1
            continue
        ln = i + 1
        try:
            prn = int(line[0:2])
            yy, mo, dd, hh, mi = (int(line[2 + 3 * k:5 + 3 * k]) for k in range(5))
            sec = float(line[17:22])
            if not 0.0 <= sec < 61.0:               # also refuses nan and inf
                raise ValueError(sec)
        except ValueError:
            raise InputError(f"bad PRN / EPOCH {line[:22].strip()!r}", path, ln, "PRN / EPOCH / SV CLK") from None
        year = yy + (2000 if yy < 80 else 1900)
        vals = [line[22 + 19 * k:41 + 19 * k].ljust(19) for k in range(3)]
        for k, v in enumerate(vals):
            _num(v, path, ln, _GPS_FIELDS[0][k])
        out[i] = f"G{prn:02d} {year:04d} {mo:02d} {dd:02d} {hh:02d} {mi:02d} {int(round(sec)):02d}" + "".join(vals)
        for m in range(1, 8):
            j = i + m
            if j >= n:
                raise InputError("file ends inside a navigation record", path, n, "BROADCAST ORBIT")
            orb = lines[j]
            fields = [orb[3 + 19 * k:22 + 19 * k].ljust(19) for k in range(4)]
            for k, v in enumerate(fields):
                _num(v, path, j + 1, f"BROADCAST ORBIT - {m}: {_GPS_FIELDS[m][k]}")
            out[j] = "    " + "".join(fields)
        i += 8
    return out


def _rinex3_used_records(lines: list[str], hdr: NavHeader, path: Path) -> tuple[list[str], str]:
    """The lines of a RINEX 3 navigation file with the records of systems cssrlib does not decode here blanked (same
    line numbers), and a note naming what was left out (SBAS, NavIC). A record is its first line (system letter,
    PRN, epoch) and the indented lines after it, so GLONASS records of any length (4 lines before RINEX 3.05, 5 from
    3.05 on, as DJI writes them either way) are found alike: they are read into ``hdr.glonass``. Records of the
    systems used are checked field by field (`InputError` naming file, line and field); they must have their 8
    lines."""
    out = list(lines)
    skipped: dict[str, list[int]] = {}
    glonass: list[dict] = []
    bad_glonass: list[str] = []
    n = len(lines)
    i = hdr.end_line + 1
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        ln = i + 1
        sys = line[0]
        if sys not in SYSTEM_NAMES or not line[1:3].strip().isdigit():
            raise InputError(f"expected a record's first line (system letter, PRN, epoch), not {line[:23]!r}",
                             path, ln, "SV / EPOCH / SV CLK")
        j = i + 1
        while j < n and lines[j][:4] == "    " and lines[j].strip():
            j += 1
        if sys == "R":
            _add_glonass(lines, i, path, False, glonass, bad_glonass)
            for k in range(i, j):
                out[k] = ""
            i = j
            continue
        if sys not in USED_SYSTEMS:
            cnt = skipped.setdefault(sys, [0, ln])
            cnt[0] += 1
            for k in range(i, j):
                out[k] = ""
            i = j
            continue
        names = _FIELDS[sys]
        if j - i < 8:                   # line j is where the missing orbit line should be
            raise InputError(f"{SYSTEM_NAMES[sys]} record with {j - i - 1} orbit lines (7 expected)", path,
                             min(j + 1, n), f"BROADCAST ORBIT - {j - i}")
        if j - i > 8:
            raise InputError(f"{SYSTEM_NAMES[sys]} record with {j - i - 1} orbit lines (7 expected)", path,
                             i + 9, "BROADCAST ORBIT - 8")
        try:
            ep = [int(x) for x in line[4:23].split()]
            if len(ep) != 6 or not (1980 <= ep[0] <= 2200 and 1 <= ep[1] <= 12 and 1 <= ep[2] <= 31):
                raise ValueError
        except ValueError:
            raise InputError(f"bad epoch {line[4:23].strip()!r}", path, ln, "SV / EPOCH / SV CLK") from None
        for k in range(3):
            _num(line[23 + 19 * k:42 + 19 * k], path, ln, names[0][k])
        for m in range(1, 8):
            orb = lines[i + m]
            for k in range(4):
                _num(orb[4 + 19 * k:23 + 19 * k], path, i + m + 1, f"BROADCAST ORBIT - {m}: {names[m][k]}")
        i = j
    note = ""
    if skipped:
        parts = [f"{c} {SYSTEM_NAMES[sy]} (first at line {first})" for sy, (c, first) in skipped.items()]
        note = (f"{sum(c for c, _ in skipped.values())} navigation record(s) of systems dgcal does not use skipped: "
                + ", ".join(parts))
    hdr.glonass = GlonassEphemerides.from_rows(glonass) if glonass else None
    note = "; ".join(x for x in (note, _glonass_note(bad_glonass)) if x)
    return out, note


def _klobuchar_record(lines: list[str], i: int, path: Path, label: str) -> np.ndarray:
    """The (alpha, beta) 2x4 of a RINEX 4 Klobuchar ION record whose epoch line is line index i: alpha0-2 after the
    epoch, alpha3 beta0-2 on the next line, beta3 on the third (19-column fields from column 4)."""
    if i + 2 >= len(lines):
        raise InputError("file ends inside an ION record (3 lines expected)", path, len(lines), label)
    f = [_num(lines[i][4 + 19 * k:23 + 19 * k], path, i + 1, f"{label} alpha{k - 1}") for k in (1, 2, 3)]
    f += [_num(lines[i + 1][4 + 19 * k:23 + 19 * k], path, i + 2, f"{label} {n}")
          for k, n in enumerate(("alpha3", "beta0", "beta1", "beta2"))]
    f.append(_num(lines[i + 2][4:23], path, i + 3, f"{label} beta3"))
    return np.array(f).reshape(2, 4)


# RINEX 4 ephemeris messages laid out as RINEX 3's records (the ones dgcal reads; the others are left out)
RINEX4_KEPT = {("G", "LNAV"), ("J", "LNAV"), ("E", "INAV"), ("E", "FNAV"), ("C", "D1"), ("C", "D2"), ("R", "FDMA"),
               ("S", "SBAS"), ("I", "LNAV")}
_RINEX4_KLOBUCHAR = {("G", "LNAV"): "ion_gps", ("J", "LNAV"): "ion_qzs", ("C", "D1D2"): "ion_bds"}


def _rinex4_as_3(lines: list[str], hdr: NavHeader, path: Path) -> tuple[list[str], str]:
    """A RINEX 4 navigation file in RINEX 3 layout, line numbers unchanged: each record's ``> EPH|ION|STO|EOP``
    line blanked, the ephemeris messages RINEX 3 carries kept (`RINEX4_KEPT`: GPS/QZSS LNAV, Galileo I/NAV and
    F/NAV, BeiDou D1/D2, GLONASS FDMA), the others (CNAV, CNV1-3, L1OC, ...) and the STO/EOP records blanked; the
    first Klobuchar ION record of GPS, QZSS and BeiDou fills the header's coefficients (RINEX 4 moved them out of the
    header). Returns the lines and a note naming the messages left out."""
    out = list(lines)
    out[0] = f"{3.04:9.2f}" + lines[0][9:]
    left: dict[str, int] = {}
    n = len(lines)
    i = hdr.end_line + 1
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        if not line.startswith("> "):
            raise InputError(f"expected a RINEX 4 record line ('> EPH', '> ION', '> STO', '> EOP'), not {line[:23]!r}",
                             path, i + 1, "record type")
        kind, sys, msg = line[2:5], line[6:7], line[10:14].strip()
        j = i + 1
        while j < n and not lines[j].startswith("> "):
            j += 1
        out[i] = ""
        keep = kind == "EPH" and (sys, msg) in RINEX4_KEPT
        if kind == "ION" and (sys, msg) in _RINEX4_KLOBUCHAR and getattr(hdr, _RINEX4_KLOBUCHAR[sys, msg]) is None:
            coef = _klobuchar_record(lines, i + 1, path, f"ION {sys} {msg}")
            setattr(hdr, _RINEX4_KLOBUCHAR[sys, msg], coef if np.any(coef) else None)
        if kind == "EPH" and not keep:
            name = f"{SYSTEM_NAMES.get(sys, sys)} {msg}"
            left[name] = left.get(name, 0) + 1
        if not keep:
            for k in range(i + 1, j):
                out[k] = ""
        i = j
    note = ("RINEX 4 messages RINEX 3 does not carry left out: " + ", ".join(f"{c} {m}" for m, c in left.items())
            if left else "")
    return out, note


def nav_text_for_cssrlib(path: str | Path) -> tuple[io.StringIO, NavHeader]:
    """The file's text in a layout cssrlib's ``rnxdec._decode_nav`` reads, line numbers unchanged, and its header."""
    path = Path(path)
    lines = read_lines(path, "nav")
    hdr = parse_nav_header(lines, path)
    if hdr.version >= 3.0:
        note4 = ""
        if hdr.version >= 4.0:
            lines, note4 = _rinex4_as_3(lines, hdr, path)
        text, hdr.skipped = _rinex3_used_records(lines, hdr, path)
        hdr.skipped = "; ".join(x for x in (note4, hdr.skipped) if x)
        if hdr.version < 3.02:
            text[0] = f"{3.02:9.2f}" + lines[0][9:]
    elif hdr.file_type == "N":
        text = _rinex2_gps_to_3(lines, hdr, path)
    elif hdr.file_type == "G":
        hdr.glonass = _rinex2_glonass(lines, hdr, path)
        text = [f"{3.04:9.2f}{'':11}{'N: GNSS NAV DATA':<20}{'R: GLONASS':<20}RINEX VERSION / TYPE",
                f"{'':60}END OF HEADER"]
    else:
        kind = {"H": "SBAS", "E": "Galileo", "J": "QZSS"}[hdr.file_type]
        raise InputError(f"RINEX 2 {kind} navigation files are not read (GPS 'N', GLONASS 'G' files and RINEX 3 are)",
                         path, 1, "RINEX VERSION / TYPE")
    return io.StringIO("\n".join(text) + "\n"), hdr


def glonass_rinex3_lines(eph: GlonassEphemerides) -> list[str]:
    """RINEX 3 navigation records (4 lines each; epochs UTC, kilometres) of GLONASS ephemerides, as
    `_glonass_record` reads them back."""
    def d(x: float) -> str:
        m, e = f"{x:.12E}".split("E")
        return f"{m:>15}E{int(e):+03d}"

    out = []
    gps_epoch = _dt.datetime(1980, 1, 6)
    for i in np.argsort(eph.toe, kind="stable"):
        t = gps_epoch + _dt.timedelta(seconds=float(eph.toe[i]))
        t -= _dt.timedelta(seconds=gps_minus_utc_s(t.year, t.month))
        out.append(f"{eph.sat[i]} {t:%Y %m %d %H %M %S}" + d(-eph.taun[i]) + d(eph.gamn[i]) + d(0.0))
        extra = (eph.svh[i], eph.frq[i], eph.age[i])
        for c in range(3):
            out.append("    " + d(eph.pos[i, c] / 1e3) + d(eph.vel[i, c] / 1e3) + d(eph.acc[i, c] / 1e3)
                       + d(float(extra[c])))
    return out
