"""Precise satellite orbits (SP3-c/d) and clocks (RINEX clock 2.x/3.x): reading and interpolation at any time.

IGS-style products give satellite centre-of-mass positions (ECEF, every 5 or 15 min) and clock offsets (every
30 s or 5 min; the SP3 file's own clock column when no clock file is given). Orbits are interpolated as RTKLIB's
`peph2pos` and cssrlib's `peph.pephpos` do: a Lagrange polynomial of degree 10 through the 11 epochs around the
time, each sample first rotated by the earth's rotation into the ECEF frame of that time. Clocks are interpolated
linearly between the two epochs around the time. Products carry no periodic relativistic term: `states` adds
``-2 r.v / c^2`` (the broadcast clock's ``F e sqrt(A) sin E`` in another form). The precise clocks refer to the
ionosphere-free combination (GPS L1/L2 P(Y), Galileo E1/E5a, BeiDou B1I/B3I); `dgcal.pos.gnss.ephemeris` takes the
broadcast group delay off for single-frequency users as for broadcast clocks (RTKLIB 2.4.3 does the same).
Satellite antenna phase-centre offsets come from an ANTEX file when one is given (cssrlib's `atxdec` reads it):
the offset of the products' ionosphere-free combination (IGS: GPS/QZSS L1/L2, Galileo E1/E5a, BeiDou B1I/B3I),
rotated into ECEF by the nominal yaw attitude (z to the earth's centre, y along z x the sun direction), is added
to the centre-of-mass position, as RTKLIB's `satantoff` does; the antenna's phase variations are not applied.
Without an ANTEX file the positions are the centre of mass, up to ~2.5 m from the antenna along the radial
direction; for code positioning that offset is nearly common to all satellites of a system and goes mostly into
the receiver clock, and double differences over short baselines cancel it.

Files are recognised by content (`product_kind`); compressed files (gzip, .Z, bzip2, zip) are read as they are.
Every malformed value is an `InputError` naming file, line and field.
"""
from __future__ import annotations

import datetime as _dt
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from cssrlib.gnss import gpst2time, gpst2utc, sat2id
from cssrlib.peph import atxdec, sunmoonpos

from dgcal.fields.constants import C_LIGHT, OMEGA_EARTH, SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.gnss_files import first_gnss_line
from dgcal.pos.gnss.rinex_obs import read_lines
from dgcal.pos.gnss.rinex_nav import fortran_float

LAGRANGE_POINTS = 11                      # degree-10 Lagrange interpolation (RTKLIB's NMAX = 10)
SP3_BAD_CLOCK_US = 999999.0               # SP3 "no clock value" (999999.999999 us)
SP3_MAX_KM = 1.0e5                        # GNSS orbits lie within 50 000 km of the geocentre
PRECISE_SIGMA_M = 0.05                    # orbit and clock error of final/rapid products along a line of sight, m
# time system of a product -> seconds added to reach GPS time (UTC and GLONASS time need leap seconds: refused)
_TIME_TO_GPS_S = {"GPS": 0.0, "GAL": 0.0, "QZS": 0.0, "IRN": 0.0, "BDT": 14.0, "TAI": -19.0}
_GPS_EPOCH_DAYS = 722820                  # date(1980, 1, 6).toordinal()


def _open_lines(path: Path) -> list[str]:
    try:
        return read_lines(path)
    except (OSError, UnicodeDecodeError, EOFError) as exc:
        raise InputError(f"cannot read: {exc}", path) from None


def product_kind(path: str | Path, first_line: str | None = None) -> str:
    """What a navigation-side file is, from its first line: "sp3", "clk" (RINEX clock), "atx" (ANTEX) or "nav"
    (anything else, checked later as a RINEX navigation file)."""
    if first_line is None:
        first_line = first_gnss_line(path)
    if first_line[:1] == "#" and first_line[1:2] in "abcd" and first_line[1:2] != "":
        return "sp3"
    if "ANTEX VERSION" in first_line:
        return "atx"
    # RINEX clock: type 'C' after the version (column 21 up to 3.02; 3.04 writes F4.2,17X: column 23)
    if "RINEX VERSION / TYPE" in first_line and first_line.split()[1:2] in (["C"], ["CLOCK"]):
        return "clk"
    return "nav"


_KIND_NAMES = {"sp3": "an SP3 orbit file (first line #c or #d)", "clk": "a RINEX clock file (type 'C')",
               "atx": "an ANTEX file (first line ANTEX VERSION / SYST)", "nav": "a RINEX navigation file"}


def require_kind(path: str | Path, kind: str, field: str) -> Path:
    """`path` if its content is of `kind` ("sp3", "clk"), else an `InputError` naming the file and `field`."""
    path = Path(path)
    if product_kind(path) != kind:
        raise InputError(f"not {_KIND_NAMES[kind]}", path, 1, field)
    return path


def _gps_seconds(y: int, mo: int, d: int, h: int, mi: int, s: float) -> float:
    """Calendar epoch (any time scale) -> continuous seconds since the GPS epoch in that scale."""
    days = _dt.date(y, mo, d).toordinal() - _GPS_EPOCH_DAYS
    return days * 86400.0 + h * 3600.0 + mi * 60.0 + s


def _calendar(t: float) -> tuple[int, int, int, int, int, float]:
    """Continuous GPS seconds -> (year, month, day, hour, minute, second)."""
    days = int(t // 86400.0)
    d = _dt.date.fromordinal(_GPS_EPOCH_DAYS + days)
    r = t - days * 86400.0
    h, r = divmod(r, 3600.0)
    mi, s = divmod(r, 60.0)
    return d.year, d.month, d.day, int(h), int(mi), float(s)


def _float(text: str, path: Path, ln: int, name: str) -> float:
    return fortran_float(text, path, ln, name)


def _epoch(fields: list[str], path: Path, ln: int, name: str) -> float:
    try:
        y, mo, d, h, mi = (int(x) for x in fields[:5])
        s = float(fields[5])
        if not (1980 <= y <= 2200 and 0 <= h <= 23 and 0 <= mi <= 59 and 0.0 <= s < 61.0):
            raise ValueError
        return _gps_seconds(y, mo, d, h, mi, s)
    except (ValueError, IndexError, OverflowError):   # a month of 1e30 overflows the calendar
        raise InputError(f"bad epoch {' '.join(fields[:6])!r}", path, ln, name) from None


def _sat_id(text: str) -> str:
    """'G01', 'G 1' or ' 1' (SP3-a GPS) -> 'G01'."""
    t = text.replace(" ", "0")
    sys = "G" if t[0] in "0123456789" else t[0]
    return f"{sys}{int(t[1:]):02d}" if t[1:].isdigit() else text


@dataclass
class Sp3Data:
    """One SP3 file: epochs (continuous GPS s), satellites, positions (m, NaN missing), clocks (s, NaN missing)."""

    t: np.ndarray
    sats: list[str]
    p: np.ndarray
    clk: np.ndarray


def read_sp3(path: str | Path) -> Sp3Data:
    """Read an SP3-c/d orbit file (plain or compressed): ECEF positions in m and clocks in s per epoch and satellite,
    times in GPS time (the file's time system converted)."""
    path = Path(path)
    lines = _open_lines(path)
    if not lines or product_kind(path, lines[0]) != "sp3":
        raise InputError("not an SP3 file (first line must start with #c or #d)", path, 1, "SP3 version")
    if lines[0][1] not in "cd":
        raise InputError(f"SP3 version '{lines[0][1]}' is not read (SP3-c and SP3-d are)", path, 1, "SP3 version")
    tsys = "GPS"
    seen_c = False
    t_list: list[float] = []
    recs: list[tuple[int, int]] = []            # (epoch, line index) of every position record
    k = -1
    for i, line in enumerate(lines):
        ln = i + 1
        tag = line[:2]
        if tag == "%c" and not seen_c:
            seen_c = True
            ts = line[9:12].strip()
            tsys = "GPS" if ts in ("", "ccc") else ts
            if tsys not in _TIME_TO_GPS_S:
                raise InputError(f"time system {ts!r} is not read (GPS, GAL, QZS, BDT, TAI are)", path, ln,
                                 "%c time system")
        elif line[:1] == "*":
            t = _epoch(line[2:].split(), path, ln, "epoch header") + _TIME_TO_GPS_S[tsys]
            if t_list and t <= t_list[-1]:
                raise InputError("epochs out of order or repeated", path, ln, "epoch header")
            t_list.append(t)
            k += 1
        elif line[:1] == "P":
            if k < 0:
                raise InputError("position record before the first epoch header", path, ln, "P record")
            recs.append((k, i))
        elif line.startswith("EOF"):
            break
    if not t_list:
        raise InputError("no epoch in SP3 file", path, len(lines), "epoch header")
    vals = _sp3_values(lines, [i for _, i in recs], path)
    ids: dict[str, str] = {}
    sid = [ids.setdefault(lines[i][1:4], _sat_id(lines[i][1:4])) for _, i in recs]
    sats = sorted(set(sid))
    col = {x: j for j, x in enumerate(sats)}
    kk = np.array([k for k, _ in recs], int)
    jj = np.array([col[x] for x in sid], int)
    p = np.full((len(t_list), len(sats), 3), np.nan)
    clk = np.full((len(t_list), len(sats)), np.nan)
    has_p = np.any(vals[:, :3] != 0.0, axis=1)              # 0, 0, 0: no position
    p[kk[has_p], jj[has_p]] = vals[has_p, :3] * 1e3
    has_c = np.abs(vals[:, 3]) < SP3_BAD_CLOCK_US
    clk[kk[has_c], jj[has_c]] = vals[has_c, 3] * 1e-6
    return Sp3Data(np.array(t_list), sats, p, clk)


_SP3_FIELDS = ("x (km)", "y (km)", "z (km)", "clock (us)")


def _sp3_values(lines: list[str], rows: list[int], path: Path) -> np.ndarray:
    """x, y, z (km) and clock (us; a blank clock is SP3's missing value) of the position records at line indices
    `rows`, (n, 4): converted all at once; a bad field is found line by line and named (`InputError`)."""
    if not rows:
        return np.zeros((0, 4))
    text = np.array([[lines[i][4 + 14 * f:18 + 14 * f] for f in range(4)] for i in rows])
    text[:, 3] = np.where(np.char.strip(text[:, 3]) == "", "999999.999999", text[:, 3])
    try:
        vals = text.astype(float)
        good = bool(np.all(np.isfinite(vals)))
    except ValueError:
        good = False
    if not good:
        vals = np.array([[_float(text[r, f], path, rows[r] + 1, _SP3_FIELDS[f]) for f in range(4)]
                         for r in range(len(rows))])
    far = np.flatnonzero(np.any(np.abs(vals[:, :3]) > SP3_MAX_KM, axis=1))
    if len(far):
        raise InputError(f"position {vals[far[0], :3].tolist()} km is not a satellite's", path, rows[far[0]] + 1,
                         "x (km)")
    return vals


@dataclass
class ClockData:
    """Satellite clocks of a RINEX clock file: epochs (continuous GPS s), satellites, offsets (s, NaN missing)."""

    t: np.ndarray
    sats: list[str]
    clk: np.ndarray


def read_rinex_clock(path: str | Path) -> ClockData:
    """Read the satellite clock records (``AS``) of a RINEX clock file 2.x/3.x (plain or compressed), in GPS time."""
    path = Path(path)
    lines = _open_lines(path)
    if not lines or product_kind(path, lines[0]) != "clk":
        raise InputError("not a RINEX clock file (type 'C' in the RINEX VERSION / TYPE line)", path, 1,
                         "RINEX VERSION / TYPE")
    tsys = "GPS"
    end = None
    for i, line in enumerate(lines):
        lab = line[60:].strip()                  # labels from column 61 (up to 3.02) or 66 (3.04)
        if lab.startswith("TIME SYSTEM ID"):
            tsys = line[:line.index("TIME SYSTEM ID")].strip() or "GPS"
            if tsys not in _TIME_TO_GPS_S:
                raise InputError(f"time system {tsys!r} is not read (GPS, GAL, QZS, BDT, TAI are)", path, i + 1,
                                 "TIME SYSTEM ID")
        elif lab.startswith("END OF HEADER"):
            end = i
            break
    if end is None:
        raise InputError("no END OF HEADER line", path, len(lines))
    times: dict[float, int] = {}
    recs: list[tuple[int, str, float]] = []
    for i in range(end + 1, len(lines)):
        line = lines[i]
        if line[:3] != "AS ":
            continue
        ln = i + 1
        parts = line[3:].split()
        if len(parts) < 9:
            raise InputError("satellite clock record too short", path, ln, "AS record")
        t = _epoch(parts[1:7], path, ln, "AS epoch") + _TIME_TO_GPS_S[tsys]
        try:
            nval = int(parts[7])
        except ValueError:
            raise InputError(f"not an integer: {parts[7]!r}", path, ln, "number of data values") from None
        if nval < 1:
            raise InputError("no clock value", path, ln, "number of data values")
        bias = _float(parts[8], path, ln, "clock bias (s)")
        if abs(bias) > 1.0:
            raise InputError(f"clock bias {bias} s is not a satellite clock's", path, ln, "clock bias (s)")
        k = times.setdefault(t, len(times))
        recs.append((k, _sat_id(parts[0]), bias))
    if not recs:
        raise InputError("no satellite clock record (AS)", path, len(lines), "AS record")
    sats = sorted({r[1] for r in recs})
    col = {s: j for j, s in enumerate(sats)}
    t_arr = np.array(list(times))
    clk = np.full((len(t_arr), len(sats)), np.nan)
    for k, sid, b in recs:
        clk[k, col[sid]] = b
    order = np.argsort(t_arr)
    return ClockData(t_arr[order], sats, clk[order])


# the two carriers of each system's ionosphere-free clock reference in IGS products: ANTEX frequency code, Hz
IF_CARRIERS = {"G": (("L1", 1575.42e6), ("L2", 1227.60e6)), "J": (("L1", 1575.42e6), ("L2", 1227.60e6)),
               "E": (("L1", 1575.42e6), ("L5", 1176.45e6)), "C": (("L2", 1561.098e6), ("L6", 1268.52e6))}


def _gtime_seconds(t) -> float:
    """cssrlib gtime_t -> continuous GPS seconds (0 for an unset time)."""
    return float(t.time) + float(t.sec) - 315964800.0 if t.time else 0.0


def read_antex_pco(path: str | Path) -> dict[str, list[tuple[float, float, np.ndarray]]]:
    """Satellite antenna phase-centre offsets of an ANTEX file (plain), per satellite id: (valid from, valid until
    (continuous GPS s; 0: open), offset (m) in the antenna frame x, y, z) of the ionosphere-free combination of
    `IF_CARRIERS`; satellites of other systems, or without both carriers, are left out."""
    path = Path(path)
    if product_kind(path) != "atx":
        raise InputError("not an ANTEX file (no 'ANTEX VERSION / SYST' first line)", path, 1, "ANTEX VERSION / SYST")
    dec = atxdec()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / "sat.atx"            # cssrlib opens the file itself: a gzip file is unpacked first
            plain.write_text("\n".join(read_lines(path)) + "\n")
            dec.readpcv(str(plain))
    except (OSError, UnicodeDecodeError, ValueError, IndexError, KeyError) as exc:
        raise InputError(f"cannot read ANTEX file: {exc}", path) from None
    out: dict[str, list] = {}
    for pcv in dec.pcvs:
        sid = sat2id(pcv.sat) if pcv.sat else ""
        carriers = IF_CARRIERS.get(sid[:1])
        if not carriers:
            continue
        offs = {str(sig).strip()[1:]: np.asarray(off, float) for sig, off in pcv.off.items()
                if str(sig)[:1] == sid[0]}
        if not all(c in offs for c, _ in carriers):
            continue
        (c1, f1), (c2, f2) = carriers
        pco = (f1 ** 2 * offs[c1] - f2 ** 2 * offs[c2]) / (f1 ** 2 - f2 ** 2) * 1e-3
        if not np.all(np.abs(pco) < 10.0):
            raise InputError(f"satellite antenna offset {pco} m of {sid} is not a satellite's", path,
                             field="NORTH / EAST / UP")
        out.setdefault(sid, []).append((_gtime_seconds(pcv.ts), _gtime_seconds(pcv.te), pco))
    return out


def _sun_ecef(t_gps: float) -> np.ndarray:
    """Sun position (ECEF m) at continuous GPS seconds (cssrlib's ephemeris, UT1 = UTC)."""
    week = int(np.floor(t_gps / SECONDS_PER_WEEK))
    rsun, _, _ = sunmoonpos(gpst2utc(gpst2time(week, t_gps - week * SECONDS_PER_WEEK)), np.zeros(5), True)
    return np.asarray(rsun, float)


def antenna_offsets_ecef(p_ecef: np.ndarray, pco: np.ndarray, t_gps: np.ndarray) -> np.ndarray:
    """Antenna offsets (n,3) in ECEF (m) of satellites at `p_ecef` (n,3) with antenna-frame offsets `pco` (n,3) at
    times `t_gps` (n,), by the nominal yaw attitude: z to the earth's centre, y = z x (sun - sat) normalised,
    x = y x z (RTKLIB's `satantoff`, cssrlib's `orb2ecef`). The sun is placed once per minute (it moves 0.25 deg)."""
    minutes = np.round(np.asarray(t_gps, float) / 60.0)
    sun = {m: _sun_ecef(m * 60.0) for m in np.unique(minutes)}
    r_sun = np.array([sun[m] for m in minutes]).reshape(-1, 3)
    ez = -p_ecef / np.linalg.norm(p_ecef, axis=1, keepdims=True)
    es = r_sun - p_ecef
    es /= np.linalg.norm(es, axis=1, keepdims=True)
    ey = np.cross(ez, es)
    ey /= np.linalg.norm(ey, axis=1, keepdims=True)
    ex = np.cross(ey, ez)
    return pco[:, :1] * ex + pco[:, 1:2] * ey + pco[:, 2:3] * ez


def _merge(ts: list[np.ndarray], sats_l: list[list[str]], vals: list[np.ndarray]):
    """Epochs of several files on one time axis and one satellite list (first file wins at a repeated epoch)."""
    sats = sorted({s for ss in sats_l for s in ss})
    col = {s: j for j, s in enumerate(sats)}
    t_all = np.unique(np.concatenate(ts))
    shape = (len(t_all), len(sats)) + vals[0].shape[2:]
    out = np.full(shape, np.nan)
    for t, ss, v in zip(ts[::-1], sats_l[::-1], vals[::-1]):
        rows = np.searchsorted(t_all, t)
        cols = np.array([col[s] for s in ss], int)
        ok = np.isfinite(v) if v.ndim == 2 else np.all(np.isfinite(v), axis=2)
        for a, r in enumerate(rows):
            out[r, cols[ok[a]]] = v[a][ok[a]]
    return t_all, sats, out


@dataclass
class PreciseProducts:
    """Precise orbits (SP3) and clocks (RINEX clock, else the SP3 clocks) of one or more files, merged.

    ``t_orb`` (m,) GPS s, ``p_orb`` (m, n, 3) ECEF m of satellites ``sats``; ``t_clk`` (k,), ``clk`` (k, n) s."""

    sats: list[str]
    t_orb: np.ndarray
    p_orb: np.ndarray
    t_clk: np.ndarray
    clk: np.ndarray
    sp3_paths: tuple[str, ...] = ()
    clk_paths: tuple[str, ...] = ()
    pco: dict = field(default_factory=dict)     # satellite id -> [(from, until, offset xyz m)] (`read_antex_pco`)
    atx_paths: tuple[str, ...] = ()
    _col: dict = field(default_factory=dict, repr=False)
    _lam: np.ndarray | None = field(default=None, repr=False)

    @property
    def label(self) -> str:
        """Which products: "SP3 a.sp3 + CLK b.clk [+ ATX c.atx]", or "SP3 a.sp3 (its own clocks)"."""
        sp3 = "SP3 " + ", ".join(Path(p).name for p in self.sp3_paths)
        if self.clk_paths:
            sp3 += " + CLK " + ", ".join(Path(p).name for p in self.clk_paths)
        else:
            sp3 += " (its own clocks)"
        if self.atx_paths:
            sp3 += " + ATX " + ", ".join(Path(p).name for p in self.atx_paths)
        return sp3

    def offsets(self, sats: list[str], t_gps: np.ndarray) -> np.ndarray:
        """Antenna-frame offsets (n,3) m of satellites at times (GPS s) from the ANTEX file; NaN without one."""
        out = np.full((len(sats), 3), np.nan)
        for i, (sid, t) in enumerate(zip(sats, t_gps)):
            for t0, t1, off in self.pco.get(sid, ()):
                if (t0 == 0.0 or t >= t0) and (t1 == 0.0 or t <= t1):
                    out[i] = off
                    break
        return out

    def columns(self, sats: list[str]) -> np.ndarray:
        """Column of each satellite id in the products, -1 where absent."""
        if not self._col:
            self._col.update({s: j for j, s in enumerate(self.sats)})
        return np.array([self._col.get(s, -1) for s in sats], int)

    def _barycentric(self) -> np.ndarray:
        """Barycentric weights (m-10, 11) of every 11-epoch window: 1 / prod_{j != k} (t_k - t_j), fixed by the
        epochs alone, so an interpolation costs O(11) per time instead of O(11^2)."""
        if self._lam is None:
            n_win = max(len(self.t_orb) - LAGRANGE_POINTS + 1, 0)
            tw = self.t_orb[np.arange(n_win)[:, None] + np.arange(LAGRANGE_POINTS)]
            diff = tw[:, :, None] - tw[:, None, :]
            diff[:, np.arange(LAGRANGE_POINTS), np.arange(LAGRANGE_POINTS)] = 1.0
            self._lam = 1.0 / np.prod(diff, axis=2)
        return self._lam

    def _positions(self, t: np.ndarray, j: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Lagrange-interpolated ECEF positions (n,3) at times t of satellites j over windows from `start`
        (barycentric form: w_k = lam_k / (t - t_k) normalised; exactly the sample at a sample's time)."""
        w = start[:, None] + np.arange(LAGRANGE_POINTS)
        tw = self.t_orb[w] - t[:, None]                                   # (n, 11) s relative to t
        pw = self.p_orb[w, j[:, None]]                                    # (n, 11, 3)
        th = OMEGA_EARTH * tw                                            # sample at t_k into the frame of t
        c, s = np.cos(th), np.sin(th)
        x = c * pw[..., 0] - s * pw[..., 1]
        y = s * pw[..., 0] + c * pw[..., 1]
        at = tw == 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            q = self._barycentric()[start] / -tw
        q = np.where(at.any(axis=1, keepdims=True), at.astype(float), q)
        lw = q / np.sum(q, axis=1, keepdims=True)
        return np.stack([np.sum(lw * x, axis=1), np.sum(lw * y, axis=1), np.sum(lw * pw[..., 2], axis=1)], axis=1)

    def states(self, sats: list[str], t_gps: np.ndarray):
        """Satellite states at GPS times ``t_gps`` (s, per satellite) from the products.

        Returns ``p_ecef`` (n,3) m (centre of mass), ``v_ecef`` (n,3) m/s, ``clk_s`` (n,) the clock offset with
        the relativistic term ``-2 r.v/c^2`` (s, ionosphere-free reference), ``drift`` (n,) s/s and ``ok`` (n,):
        False (values NaN) outside the products' span or where a sample of the 11-epoch orbit window or one of the
        two clock epochs is missing."""
        t = np.array(np.broadcast_to(np.asarray(t_gps, float), (len(sats),)))
        n = len(sats)
        p = np.full((n, 3), np.nan)
        v = np.full((n, 3), np.nan)
        clk = np.full(n, np.nan)
        drift = np.full(n, np.nan)
        j = self.columns(list(sats))
        m = len(self.t_orb)
        ok = (j >= 0) & np.isfinite(t) & (m >= LAGRANGE_POINTS)
        if m:
            ok &= (t >= self.t_orb[0]) & (t <= self.t_orb[-1])
        kc = np.searchsorted(self.t_clk, t, side="right") - 1
        kc = np.clip(kc, 0, max(len(self.t_clk) - 2, 0))
        ok &= (len(self.t_clk) >= 2)
        if len(self.t_clk):
            ok &= (t >= self.t_clk[0]) & (t <= self.t_clk[-1])
        i = np.flatnonzero(ok)
        if len(i) == 0:
            return p, v, clk, drift, ok
        ti, ji = t[i], j[i]
        start = np.clip(np.searchsorted(self.t_orb, ti) - 1 - (LAGRANGE_POINTS - 1) // 2, 0, m - LAGRANGE_POINTS)
        w = start[:, None] + np.arange(LAGRANGE_POINTS)
        good = np.all(np.isfinite(self.p_orb[w, ji[:, None], 0]), axis=1)
        c0, c1 = self.clk[kc[i], ji], self.clk[kc[i] + 1, ji]
        good &= np.isfinite(c0) & np.isfinite(c1)
        i, ti, ji, start, c0, c1 = i[good], ti[good], ji[good], start[good], c0[good], c1[good]
        ok[:] = False
        ok[i] = True
        if len(i) == 0:
            return p, v, clk, drift, ok
        h = 0.5                  # central difference: exact to ~1e-6 m/s over +-0.5 s; shorter steps meet the
        # rounding of GPS seconds (~1e9 s, 2e-7 s resolution: 1 mm at 4 km/s)
        p0 = self._positions(ti, ji, start)
        vel = (self._positions(ti + h, ji, start) - self._positions(ti - h, ji, start)) / (2 * h)
        ta, tb = self.t_clk[kc[i]], self.t_clk[kc[i] + 1]
        slope = (c1 - c0) / (tb - ta)
        rel = -2.0 * np.sum(p0 * vel, axis=1) / C_LIGHT ** 2
        # d(r.v)/dt = |v|^2 + r.a in an inertial frame (r.v itself is the same in ECEF): v_inertial = v + w x r
        v_in = vel + OMEGA_EARTH * np.stack([-p0[:, 1], p0[:, 0], np.zeros(len(p0))], axis=1)
        acc = -3.986004418e14 * p0 / np.linalg.norm(p0, axis=1, keepdims=True) ** 3
        rel_rate = -2.0 * (np.sum(v_in * v_in, axis=1) + np.sum(p0 * acc, axis=1)) / C_LIGHT ** 2
        if self.pco:
            # antenna phase centre: the products' offset, rotated by the nominal attitude; satellites the ANTEX file
            # lacks are not used (their centre of mass would be metres off the others)
            off = self.offsets([sats[k] for k in i], ti)
            have = np.all(np.isfinite(off), axis=1)
            apc = antenna_offsets_ecef(p0[have], off[have], ti[have])
            p0[have] += apc
            keep_ok = np.zeros(len(i), bool)
            keep_ok[have] = True
            ok[i[~keep_ok]] = False
            p0[~keep_ok] = np.nan
        p[i], v[i] = p0, vel
        clk[i] = c0 + slope * (ti - ta) + rel
        drift[i] = slope + rel_rate
        bad = i[~ok[i]]
        p[bad], v[bad], clk[bad], drift[bad] = np.nan, np.nan, np.nan, np.nan
        return p, v, clk, drift, ok


def read_precise(sp3_paths, clk_paths=(), atx_paths=()) -> PreciseProducts:
    """Read SP3 orbit files (and RINEX clock files; without them the SP3 clocks; and ANTEX files for the satellite
    antenna offsets) into one `PreciseProducts`."""
    sp3 = [read_sp3(pth) for pth in sp3_paths]
    if not sp3:
        raise InputError("precise clocks need precise orbits: give an SP3 file too", Path(clk_paths[0]),
                         field="sp3")
    t_orb, sats_o, p_orb = _merge([d.t for d in sp3], [d.sats for d in sp3], [d.p for d in sp3])
    if clk_paths:
        cl = [read_rinex_clock(pth) for pth in clk_paths]
        t_clk, sats_c, clk = _merge([d.t for d in cl], [d.sats for d in cl], [d.clk for d in cl])
    else:
        t_clk, sats_c, clk = _merge([d.t for d in sp3], [d.sats for d in sp3], [d.clk for d in sp3])
    sats = sorted(set(sats_o) | set(sats_c))
    po = np.full((len(t_orb), len(sats), 3), np.nan)
    co = np.full((len(t_clk), len(sats)), np.nan)
    idx = {s: j for j, s in enumerate(sats)}
    po[:, [idx[s] for s in sats_o]] = p_orb
    co[:, [idx[s] for s in sats_c]] = clk
    pco: dict = {}
    for pth in atx_paths:
        for sid, rows in read_antex_pco(pth).items():
            pco.setdefault(sid, []).extend(rows)
    return PreciseProducts(sats, t_orb, po, t_clk, co, tuple(str(x) for x in sp3_paths),
                           tuple(str(x) for x in clk_paths), pco, tuple(str(x) for x in atx_paths))


def write_sp3(path: str | Path, t_gps: np.ndarray, sats: list[str], p_ecef: np.ndarray, clk_s: np.ndarray,
              agency: str = "DGC") -> None:
    """Write an SP3-d position file (GPS time): `p_ecef` (m, n, 3) m and `clk_s` (m, n) s of satellites `sats`
    at epochs `t_gps` (continuous GPS s); NaN positions/clocks are written as SP3's missing values."""
    t_gps = np.asarray(t_gps, float)
    m, n = len(t_gps), len(sats)
    y, mo, d, hh, mi, ss = _calendar(float(t_gps[0]))
    week = int(t_gps[0] // 604800)
    sow = float(t_gps[0] - week * 604800)
    dt = float(t_gps[1] - t_gps[0]) if m > 1 else 900.0
    mjd = 44244 + int(t_gps[0] // 86400)
    frac = (t_gps[0] % 86400) / 86400
    out = [f"#dP{y:4d} {mo:2d} {d:2d} {hh:2d} {mi:2d} {ss:11.8f} {m:7d} ORBIT IGS20 FIT {agency:>4s}",
           f"## {week:4d} {sow:15.8f} {dt:14.8f} {mjd:5d} {frac:15.13f}"]
    ids = list(sats) + ["  0"] * (-n % 17 if n > 85 else 85 - n)
    for r in range(0, len(ids), 17):
        head = f"+  {n:3d}   " if r == 0 else "+        "
        out.append(head + "".join(f"{s:>3s}" for s in ids[r:r + 17]))
    for r in range(0, len(ids), 17):
        out.append("++       " + "".join(f"{0 if s.strip() == '0' else 5:3d}" for s in ids[r:r + 17]))
    out += ["%c M  cc GPS ccc cccc cccc cccc cccc ccccc ccccc ccccc ccccc",
            "%c cc cc ccc ccc cccc cccc cccc cccc ccccc ccccc ccccc ccccc",
            "%f  1.2500000  1.025000000  0.00000000000  0.000000000000000",
            "%f  0.0000000  0.000000000  0.00000000000  0.000000000000000",
            "%i    0    0    0    0      0      0      0      0         0",
            "%i    0    0    0    0      0      0      0      0         0",
            "/* written by dgcal"]
    for k in range(m):
        y, mo, d, hh, mi, ss = _calendar(float(t_gps[k]))
        out.append(f"*  {y:4d} {mo:2d} {d:2d} {hh:2d} {mi:2d} {ss:11.8f}")
        for jj, s in enumerate(sats):
            pk = p_ecef[k, jj] / 1e3 if np.all(np.isfinite(p_ecef[k, jj])) else np.zeros(3)
            ck = clk_s[k, jj] * 1e6 if np.isfinite(clk_s[k, jj]) else 999999.999999
            out.append(f"P{s:3s}{pk[0]:14.6f}{pk[1]:14.6f}{pk[2]:14.6f}{ck:14.6f}")
    out.append("EOF")
    Path(path).write_text("\n".join(out) + "\n")


def write_rinex_clock(path: str | Path, t_gps: np.ndarray, sats: list[str], clk_s: np.ndarray) -> None:
    """Write the satellite clocks `clk_s` (m, n) s of `sats` at epochs `t_gps` as a RINEX clock 3.00 file (GPS
    time); NaN clocks are left out."""
    out = [f"{3.00:9.2f}{'':11}{'C':<20}{'M':<20}RINEX VERSION / TYPE",
           f"{'dgcal':<20}{'':<20}{'':<20}PGM / RUN BY / DATE",
           f"{'GPS':<60}TIME SYSTEM ID",
           f"{1:6d}{'AS':>6s}{'':48}# / TYPES OF DATA",
           f"{len(sats):6d}{'':54}# OF SOLN SATS",
           f"{'':60}END OF HEADER"]
    for k, t in enumerate(np.asarray(t_gps, float)):
        y, mo, d, hh, mi, ss = _calendar(float(t))
        for jj, s in enumerate(sats):
            if np.isfinite(clk_s[k, jj]):
                out.append(f"AS {s:<4s} {y:4d} {mo:02d} {d:02d} {hh:02d} {mi:02d} {ss:9.6f}  1   "
                           f"{clk_s[k, jj]:19.12E}")
    Path(path).write_text("\n".join(out) + "\n")
