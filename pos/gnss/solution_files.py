"""GNSS solution files of other software (and dgcal's gnss.csv) as loosely-coupled input: antenna positions with
their full covariance, fix quality and (when present) velocities.

- RTKLIB `.pos` (rnx2rtkp/rtkpost/rtknavi `outsol`, src/solution.c): `%` header lines, the last naming the
  columns; time `GPST`/`UTC `/`JST ` as `YYYY/MM/DD hh:mm:ss.sss` or `week tow`; position as
  latitude/longitude (deg, or d m s) + height (ellipsoidal; `geodetic` heights are refused), x/y/z-ecef, or
  e/n/u-baseline (refused: no base position); Q (1 fix, 2 float, 3 sbas, 4 dgps, 5 single, 6 ppp), ns; the
  covariance as standard deviations and RTKLIB's signed square roots of the cross terms
  (`sqvar(c) = sign(c) sqrt(|c|)`): llh: sdn sde sdu sdne sdeu sdun (local ENU covariance, RTKLIB `covenu`),
  xyz: sdx sdy sdz sdxy sdyz sdzx (ECEF); age, ratio; optional velocity vn ve vu (llh) / vx vy vz (xyz).
- NMEA-0183 GGA (`$GPGGA`, `$GNGGA`, ...): UTC time of day, latitude/longitude ddmm.mmmm + hemisphere, fix
  quality (0 invalid, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, ...), satellites, HDOP, altitude above mean sea
  level + geoid separation (ellipsoidal h = altitude + separation); the date from RMC sentences or `date`;
  sigmas from `--set`-style defaults per quality (GGA has none) or from GST sentences when present.
- dgcal `gnss.csv` (`dgcal pos --mode spp|ppk`): gps_week,gps_sow,x,y,z (ECEF m) and optional sx,sy,sz,
  sxy,sxz,syz (PPK: RTKLIB signed square roots), vx,vy,vz, svx,svy,svz, fix.
Everything comes out as `GnssSolution` (continuous GPS seconds, ECEF, covariance in local NED).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.crs import R_ecef_to_ned_at, ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.errors import InputError
from dgcal.fields.io.csv_tables import atomic_write, read_table
from dgcal.fields.io import validate
from dgcal.fields.io.text_files import read_text
from dgcal.fields.io.timescales import (calendar_from_unix, gps_from_unix_gpst, gps_from_unix_utc,
                                        unix_from_calendar, unix_utc_from_gps)

# quality codes, normalised: 1 fixed, 2 float, 3 sbas, 4 dgps, 5 single, 6 ppp (RTKLIB's)
QUALITY_NAMES = {1: "fixed", 2: "float", 3: "sbas", 4: "dgps", 5: "single", 6: "ppp"}
_NMEA_Q = {1: 5, 2: 4, 3: 5, 4: 1, 5: 2, 6: 5, 7: 5, 8: 5, 9: 3}   # GGA quality -> RTKLIB Q
# GGA has no sigmas: defaults per RTKLIB Q (horizontal, vertical m)
NMEA_DEFAULT_SIGMA = {1: (0.02, 0.04), 2: (0.3, 0.6), 3: (1.0, 2.0), 4: (0.7, 1.5), 5: (2.5, 5.0), 6: (0.1, 0.2)}
JST_MINUS_UTC_S = 9 * 3600.0


@dataclass
class GnssSolution:
    """Antenna positions: t (N,) GPS s, p_ecef (N,3) m, cov_ned (N,3,3) m^2 (local NED at each point),
    quality (N,) RTKLIB Q, n_sat (N,), v_ecef (N,3) m/s or None, cov_v_ned (N,3,3) or None; `lines` of the file."""

    t: np.ndarray
    p_ecef: np.ndarray
    cov_ned: np.ndarray
    quality: np.ndarray
    n_sat: np.ndarray
    v_ecef: np.ndarray | None = None
    cov_v_ned: np.ndarray | None = None
    lines: np.ndarray | None = None
    path: Path | None = None
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def sigma_ned(self) -> np.ndarray:
        """Standard deviations along N, E, D (m)."""
        return np.sqrt(np.clip(np.einsum("nii->ni", self.cov_ned), 0, None))

    def subset(self, mask) -> "GnssSolution":
        """The epochs selected by a boolean mask or index array."""
        def s(a):
            return None if a is None else a[mask]
        return GnssSolution(self.t[mask], self.p_ecef[mask], self.cov_ned[mask], self.quality[mask],
                            self.n_sat[mask], s(self.v_ecef), s(self.cov_v_ned), s(self.lines), self.path,
                            dict(self.info))


def sqvar_to_cov(v: np.ndarray) -> np.ndarray:
    """Covariance from RTKLIB's signed square root `sign(c) sqrt(|c|)`."""
    v = np.asarray(v, float)
    return np.sign(v) * v * v


def cov_to_sqvar(c: np.ndarray) -> np.ndarray:
    """RTKLIB's signed square root `sign(c) sqrt(|c|)` of a covariance."""
    c = np.asarray(c, float)
    return np.sign(c) * np.sqrt(np.abs(c))


def _enu_cov_to_ned(ee, nn, uu, en, eu, nu) -> np.ndarray:
    """(N,3,3) NED covariance from ENU variances and covariances."""
    n = len(ee)
    C = np.empty((n, 3, 3))
    C[:, 0, 0], C[:, 1, 1], C[:, 2, 2] = nn, ee, uu
    C[:, 0, 1] = C[:, 1, 0] = en
    C[:, 0, 2] = C[:, 2, 0] = -nu
    C[:, 1, 2] = C[:, 2, 1] = -eu
    return C


def _ecef_cov_to_ned(p_ecef, xx, yy, zz, xy, yz, zx) -> np.ndarray:
    n = len(xx)
    C = np.empty((n, 3, 3))
    C[:, 0, 0], C[:, 1, 1], C[:, 2, 2] = xx, yy, zz
    C[:, 0, 1] = C[:, 1, 0] = xy
    C[:, 1, 2] = C[:, 2, 1] = yz
    C[:, 0, 2] = C[:, 2, 0] = zx
    R_ecef_to_ned = R_ecef_to_ned_at(p_ecef).reshape(-1, 3, 3)
    return R_ecef_to_ned @ C @ np.swapaxes(R_ecef_to_ned, 1, 2)


# --------------------------------------------------------------------------------------------- RTKLIB .pos
_POS_COLUMNS = {
    "llh": ("latitude(deg)", "longitude(deg)", "height(m)"),
    "dms": ("latitude(d'\")", "longitude(d'\")", "height(m)"),
    "xyz": ("x-ecef(m)", "y-ecef(m)", "z-ecef(m)"),
    "enu": ("e-baseline(m)", "n-baseline(m)", "u-baseline(m)"),
}


def _pos_header(path: Path, lines: list[str]) -> tuple[int, str, str, list[str], str]:
    """(line index of the column header, time system, position kind, column names after time, separator)."""
    hdr_i = None
    for i, ln in enumerate(lines):
        s = ln.strip()
        if not s:
            continue
        if not s.startswith("%"):
            break
        if re.search(r"(latitude|x-ecef|e-baseline)", s):
            hdr_i = i
    if hdr_i is None:
        raise InputError("no RTKLIB column header ('%  GPST  latitude(deg) ...' or '... x-ecef(m) ...') before the "
                         "first solution line", path, field="header")
    h = lines[hdr_i].strip().lstrip("%").strip()
    m = re.match(r"(GPST|UTC|JST)\s*(.*)$", h)
    if m is None:
        raise InputError(f"column header must start with the time system GPST, UTC or JST: {h[:30]!r}", path,
                         hdr_i + 1, "GPST")
    tsys, rest = m.group(1), m.group(2)
    sep = "," if "," in rest else None
    names = [c.strip() for c in (rest.split(",") if sep else rest.split())]
    names = [c for c in names if c]
    kind = None
    for k, (a, b, c) in _POS_COLUMNS.items():
        if names[:3] == [a, b, c]:
            kind = k
    if kind is None:
        raise InputError(f"unknown position columns {' '.join(names[:3])!r}", path, hdr_i + 1, "header")
    if kind == "enu":
        raise InputError("e/n/u-baseline solutions have no absolute position: output llh or xyz from RTKLIB", path,
                         hdr_i + 1, "e-baseline(m)")
    for ln in lines[:hdr_i]:
        if "geodetic" in ln and "lat/lon/height" in ln:
            raise InputError("geodetic (geoid) heights: output ellipsoidal heights from RTKLIB", path,
                             lines.index(ln) + 1, "height(m)")
        if "Tokyo" in ln and "lat/lon/height" in ln:
            raise InputError("Tokyo datum: output WGS84 from RTKLIB", path, lines.index(ln) + 1, "datum")
    return hdr_i, tsys, kind, names, sep or "ws"


def read_rtklib_pos(path: str | Path) -> GnssSolution:
    """Read an RTKLIB `.pos` solution file (llh or xyz, any time format/system) with its covariance."""
    path = Path(path)
    lines = read_text(path).splitlines()
    hdr_i, tsys, kind, names, sep = _pos_header(path, lines)
    data = [(i + 1, ln) for i, ln in enumerate(lines) if i > hdr_i and ln.strip() and not ln.lstrip().startswith("%")]
    if not data:
        raise InputError("no solution lines after the header", path)
    tok = [(ln.split(",") if sep == "," else ln.split()) for _, ln in data]
    lno = np.array([n for n, _ in data])
    first = tok[0]
    calendar = bool(re.match(r"^\d{4}/\d{1,2}/\d{1,2}$", first[0].strip()))
    nt = 2  # both 'date time' and 'week tow' take two fields
    cols = ([names[0]] * 3 + [names[1]] * 3 + names[2:]) if kind == "dms" else names
    nval = len(cols)
    short = [k for k, t in enumerate(tok) if len(t) < nt + nval]
    if short:
        k = short[0]
        raise InputError(f"expected {nt + nval} fields, found {len(tok[k])}", path, int(lno[k]),
                         cols[max(0, min(len(tok[k]) - nt, nval - 1))])
    try:
        vals = np.array([t[nt:nt + nval] for t in tok], dtype=float)
    except ValueError:
        for k, t in enumerate(tok):
            for j, v in enumerate(t[nt:nt + nval]):
                if not _isnum(v):
                    raise InputError(f"not a number: {v.strip()[:30]!r}", path, int(lno[k]), cols[j]) from None
        raise InputError("not a number", path) from None
    bad = np.argwhere(~np.isfinite(vals))
    if len(bad):
        k, j = bad[0]
        raise InputError("not a finite number", path, int(lno[k]), cols[int(j)])
    t = _pos_times(path, tok, lno, calendar, tsys)
    npos = 7 if kind == "dms" else 3
    col = {n: vals[:, j] for j, n in enumerate(cols) if j >= npos}
    if kind in ("llh", "dms"):
        if kind == "llh":
            lat, lon, h = vals[:, 0], vals[:, 1], vals[:, 2]
        else:
            lat, lon, h = _dms(vals[:, 0], vals[:, 1], vals[:, 2]), _dms(vals[:, 3], vals[:, 4], vals[:, 5]), vals[:, 6]
        badll = np.flatnonzero((np.abs(lat) > 90) | (np.abs(lon) > 360))
        if badll.size:
            raise InputError(f"latitude/longitude out of range: {lat[badll[0]]}, {lon[badll[0]]}", path,
                             int(lno[badll[0]]), names[0])
        validate.values_in_range(h, -1.0e3, 5.0e4, path, names[2], lno, unit="m")   # below a balloon's ceiling
        p = np.asarray(geodetic_to_ecef(lat, lon, h), float).reshape(-1, 3)
    else:
        p = validate.ecef_near_surface(vals[:, :3].copy(), path, lno, names[0])
    q = _required(col, "Q", path).astype(int)
    ns = col.get("ns", np.zeros(len(t))).astype(int)
    if kind in ("llh", "dms"):
        sd = [_required(col, k, path) for k in ("sdn(m)", "sde(m)", "sdu(m)")]
        cr = [col.get(k, np.zeros(len(t))) for k in ("sdne(m)", "sdeu(m)", "sdun(m)")]
        C = _enu_cov_to_ned(sd[1] ** 2, sd[0] ** 2, sd[2] ** 2, sqvar_to_cov(cr[0]), sqvar_to_cov(cr[1]),
                            sqvar_to_cov(cr[2]))
    else:
        sd = [_required(col, k, path) for k in ("sdx(m)", "sdy(m)", "sdz(m)")]
        cr = [sqvar_to_cov(col.get(k, np.zeros(len(t)))) for k in ("sdxy(m)", "sdyz(m)", "sdzx(m)")]
        C = _ecef_cov_to_ned(p, sd[0] ** 2, sd[1] ** 2, sd[2] ** 2, *cr)
    negsd = np.flatnonzero(np.any(np.stack(sd) < 0, axis=0))
    if negsd.size:
        raise InputError("negative standard deviation", path, int(lno[negsd[0]]), "sdn(m)")
    for name, values in col.items():   # sigmas of a position (m) and of a velocity (m/s), velocities (m/s)
        is_vel = name.startswith(("sdv", "v"))
        if name.startswith(("sd", "v")):
            hi = validate.MAX_SPEED_M_S if is_vel else validate.MAX_HEIGHT_M
            validate.values_in_range(values, -hi, hi, path, name, lno, unit="m/s" if is_vel else "m")
    v = Cv = None
    if kind in ("llh", "dms") and all(k in col for k in ("vn(m/s)", "ve(m/s)", "vu(m/s)")):
        v_ned = np.column_stack([col["vn(m/s)"], col["ve(m/s)"], -col["vu(m/s)"]])
        R_ecef_to_ned = R_ecef_to_ned_at(p).reshape(-1, 3, 3)
        v = np.einsum("nji,nj->ni", R_ecef_to_ned, v_ned)
        s = [col.get(k, np.full(len(t), np.nan)) for k in ("sdvn", "sdve", "sdvu")]
        c = [sqvar_to_cov(col.get(k, np.zeros(len(t)))) for k in ("sdvne", "sdveu", "sdvun")]
        Cv = _enu_cov_to_ned(s[1] ** 2, s[0] ** 2, s[2] ** 2, *c)
    elif kind == "xyz" and all(k in col for k in ("vx(m/s)", "vy(m/s)", "vz(m/s)")):
        v = np.column_stack([col["vx(m/s)"], col["vy(m/s)"], col["vz(m/s)"]])
        s = [col.get(k, np.full(len(t), np.nan)) for k in ("sdvx", "sdvy", "sdvz")]
        c = [sqvar_to_cov(col.get(k, np.zeros(len(t)))) for k in ("sdvxy", "sdvyz", "sdvzx")]
        Cv = _ecef_cov_to_ned(p, s[0] ** 2, s[1] ** 2, s[2] ** 2, *c)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        raise InputError("time does not increase", path, int(lno[back[0] + 1]), tsys)
    return GnssSolution(t, p, C, q, ns, v, Cv, lno, path,
                        {"format": "rtklib-pos", "time_system": tsys, "position": kind})


def _required(col: dict, name: str, path: Path) -> np.ndarray:
    if name not in col:
        raise InputError(f"no column {name!r} in the header", path, field=name)
    return col[name]


def _dms(d, m, s) -> np.ndarray:
    sign = np.where(np.signbit(d), -1.0, 1.0)
    return sign * (np.abs(d) + m / 60.0 + s / 3600.0)


def _pos_times(path: Path, tok, lno, calendar: bool, tsys: str) -> np.ndarray:
    if calendar:
        u = np.empty(len(tok))
        for k, t in enumerate(tok):
            try:
                u[k] = unix_from_calendar(t[0].strip() + " " + t[1].strip())
            except ValueError as exc:
                raise InputError(str(exc), path, int(lno[k]), tsys) from None
        if tsys == "GPST":
            return gps_from_unix_gpst(u)
        if tsys == "JST":
            u = u - JST_MINUS_UTC_S
        return gps_from_unix_utc(u)
    try:
        wk = np.array([t[0] for t in tok], float)
        tow = np.array([t[1] for t in tok], float)
    except ValueError:
        k = next(k for k, t in enumerate(tok) if not _isnum(t[0]) or not _isnum(t[1]))
        raise InputError(f"not 'week tow' or 'YYYY/MM/DD hh:mm:ss': {' '.join(tok[k][:2])[:30]!r}", path,
                         int(lno[k]), tsys) from None
    bad = np.flatnonzero((wk < 0) | (wk != np.round(wk)) | (tow < 0) | (tow >= SECONDS_PER_WEEK))
    if bad.size:
        raise InputError(f"week/tow out of range: {tok[bad[0]][0]} {tok[bad[0]][1]}", path, int(lno[bad[0]]), tsys)
    t = wk * SECONDS_PER_WEEK + tow
    if tsys != "GPST":   # week/tow in UTC/JST: the same counting on the other scale
        u = t + 315964800.0 - (JST_MINUS_UTC_S if tsys == "JST" else 0.0)
        t = gps_from_unix_utc(u)
    return t


def _isnum(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_rtklib_pos(path: str | Path, sol: GnssSolution, kind: str = "llh") -> None:
    """Write an RTKLIB `.pos` (GPST calendar time, llh or xyz, covariance as RTKLIB writes it), atomically."""
    p = sol.p_ecef
    n = len(sol.t)
    R_ecef_to_ned = R_ecef_to_ned_at(p).reshape(-1, 3, 3)
    with atomic_write(path, newline="\n") as fh:
        fh.write("% program   : dgcal\n")
        if kind == "llh":
            fh.write("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,"
                     "ns=# of satellites)\n")
            fh.write("%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)"
                     "   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n")
            geo = ecef_to_geodetic(p)
        else:
            fh.write("% (x/y/z-ecef=WGS84,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n")
            fh.write("%  GPST                      x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)   sdy(m)"
                     "   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio\n")
        for i in range(n):
            ts = calendar_from_unix(sol.t[i] + 315964800.0, 3)
            C = sol.cov_ned[i]
            if kind == "llh":
                nn, ee, dd = C[0, 0], C[1, 1], C[2, 2]
                en, eu, nu = C[0, 1], -C[1, 2], -C[0, 2]
                sds = (np.sqrt(nn), np.sqrt(ee), np.sqrt(dd), *cov_to_sqvar([en, eu, nu]))
                fh.write(f"{ts} {geo[i, 0]:14.9f} {geo[i, 1]:14.9f} {geo[i, 2]:10.4f} {int(sol.quality[i]):3d} "
                         f"{int(sol.n_sat[i]):3d} " + " ".join(f"{v:8.4f}" for v in sds) + "   0.00    0.0\n")
            else:
                Ce = R_ecef_to_ned[i].T @ C @ R_ecef_to_ned[i]
                sds = (*np.sqrt(np.diag(Ce)), *cov_to_sqvar([Ce[0, 1], Ce[1, 2], Ce[2, 0]]))
                fh.write(f"{ts} {p[i, 0]:14.4f} {p[i, 1]:14.4f} {p[i, 2]:14.4f} {int(sol.quality[i]):3d} "
                         f"{int(sol.n_sat[i]):3d} " + " ".join(f"{v:8.4f}" for v in sds) + "   0.00    0.0\n")


# --------------------------------------------------------------------------------------------- NMEA GGA
_NMEA = re.compile(r"^\s*\$(?P<talker>[A-Z]{2})(?P<type>[A-Z]{3}),(?P<body>[^*]*)(?:\*(?P<ck>[0-9A-Fa-f]{2}))?\s*$")


def _nmea_checksum(sentence_body: str) -> int:
    c = 0
    for ch in sentence_body:
        c ^= ord(ch)
    return c


def read_nmea_gga(path: str | Path, date: str | None = None, leap_seconds: float | None = None) -> GnssSolution:
    """Read the GGA fixes of an NMEA-0183 log (UTC times; the date from RMC sentences or `date` YYYY-MM-DD),
    heights = altitude + geoid separation (ellipsoidal); sigmas from GST sentences or NMEA_DEFAULT_SIGMA."""
    path = Path(path)
    text = read_text(path, encoding="ascii")
    day_u = None
    if date is not None:
        try:
            day_u = unix_from_calendar(f"{date} 00:00:00")
        except ValueError:
            raise InputError(f"date {date!r} is not YYYY-MM-DD", field="nmea_date") from None
    rows, gst = [], {}
    rmc_day = None
    for ln, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _NMEA.match(line)
        if m is None:
            if line.lstrip().startswith("$"):
                raise InputError(f"not an NMEA sentence: {line.strip()[:40]!r}", path, ln, "sentence")
            continue   # other logger text between sentences
        body = f"{m.group('talker')}{m.group('type')},{m.group('body')}"
        if m.group("ck") is not None and int(m.group("ck"), 16) != _nmea_checksum(body):
            raise InputError(f"checksum {m.group('ck')} does not match {_nmea_checksum(body):02X}", path, ln,
                             "checksum")
        f = m.group("body").split(",")
        typ = m.group("type")
        if typ == "RMC" and len(f) >= 9 and len(f[8]) == 6 and f[8].isdigit():
            dd, mm, yy = int(f[8][:2]), int(f[8][2:4]), int(f[8][4:])
            try:
                rmc_day = unix_from_calendar(f"{2000 + yy:04d}-{mm:02d}-{dd:02d} 00:00:00")
            except ValueError:
                raise InputError(f"bad RMC date {f[8]!r}", path, ln, "date") from None
        elif typ == "GST" and len(f) >= 8 and f[0]:
            try:
                gst[f[0]] = (float(f[5]), float(f[6]), float(f[7]))   # sigma lat, lon, alt (m)
            except ValueError:
                pass
        elif typ == "GGA":
            rows.append((ln, f, rmc_day))
    if not rows:
        raise InputError("no GGA sentences", path)
    t, llh, q, ns, lines, sig = [], [], [], [], [], []
    names = ("time", "latitude", "N/S", "longitude", "E/W", "quality", "satellites", "hdop", "altitude", "M",
             "geoid separation")
    for ln, f, dday in rows:
        if len(f) < 11:
            raise InputError(f"GGA needs 14 fields, got {len(f)}", path, ln, names[min(len(f), 10)])
        if f[5].strip() in ("", "0"):
            continue   # no fix
        try:
            qq = int(f[5])
        except ValueError:
            raise InputError(f"not a fix quality: {f[5]!r}", path, ln, "quality") from None
        try:
            hh, mi, ss = int(f[0][:2]), int(f[0][2:4]), float(f[0][4:])
            lat = _nmea_deg(f[1], f[2], "NS", 2)
            lon = _nmea_deg(f[3], f[4], "EW", 3)
            alt = float(f[8])
            sep = float(f[10]) if f[10].strip() else 0.0
        except (ValueError, IndexError) as exc:
            fld = _gga_bad_field(f)
            raise InputError(f"bad value {str(exc)[:40]}", path, ln, fld) from None
        base = dday if dday is not None else day_u
        if base is None:
            raise InputError("GGA has no date: give the date (--nmea-date YYYY-MM-DD) or log RMC sentences", path,
                             ln, "time")
        t.append(base + hh * 3600 + mi * 60 + ss)
        llh.append((lat, lon, alt + sep))
        q.append(_NMEA_Q.get(qq, 5))
        ns.append(int(f[6]) if f[6].strip().isdigit() else 0)
        lines.append(ln)
        sig.append(gst.get(f[0]))
    if not t:
        raise InputError("no GGA sentence with a fix", path)
    u = np.array(t, float)
    tg = gps_from_unix_utc(u, leap_seconds)
    # a day rollover without a new RMC date
    roll = np.concatenate([[0.0], np.cumsum(np.diff(tg) < -43200.0)]) * 86400.0
    tg = tg + roll
    llh = np.array(llh)
    p = np.asarray(geodetic_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2]), float).reshape(-1, 3)
    qa = np.array(q)
    C = np.zeros((len(tg), 3, 3))
    for i, (qi, s) in enumerate(zip(qa, sig)):
        if s is not None and all(np.isfinite(s)) and min(s) > 0:
            C[i] = np.diag([s[0] ** 2, s[1] ** 2, s[2] ** 2])
        else:
            sh, sv = NMEA_DEFAULT_SIGMA.get(int(qi), (2.5, 5.0))
            C[i] = np.diag([sh ** 2, sh ** 2, sv ** 2])
    la = np.array(lines)
    back = np.flatnonzero(np.diff(tg) <= 0)
    if back.size:
        raise InputError("time does not increase", path, int(la[back[0] + 1]), "time")
    return GnssSolution(tg, p, C, qa, np.array(ns), None, None, la, path,
                        {"format": "nmea-gga", "sigmas": "GST" if any(s is not None for s in sig) else "default"})


def _nmea_deg(v: str, hemi: str, ok: str, deg_digits: int) -> float:
    if hemi.strip().upper() not in ok or "." not in v and len(v) < deg_digits + 2:
        raise ValueError(f"{v!r} {hemi!r}")
    d = float(v[:deg_digits]) + float(v[deg_digits:]) / 60.0
    if float(v[deg_digits:]) >= 60.0:
        raise ValueError(f"minutes {v[deg_digits:]!r}")
    return -d if hemi.strip().upper() in "SW" else d


def _gga_bad_field(f: list[str]) -> str:
    try:
        int(f[0][:2]), int(f[0][2:4]), float(f[0][4:])
    except (ValueError, IndexError):
        return "time"
    for j, (k, ok, dd) in enumerate(((1, "NS", 2), (3, "EW", 3))):
        try:
            _nmea_deg(f[k], f[k + 1], ok, dd)
        except (ValueError, IndexError):
            return ("latitude", "longitude")[j]
    try:
        float(f[8])
    except ValueError:
        return "altitude"
    return "geoid separation"


def write_nmea_gga(path: str | Path, sol: GnssSolution, leap_seconds: float | None = None, talker: str = "GN") -> None:
    """Write GGA (+ RMC for the date) sentences of a solution (ellipsoidal h as altitude with separation 0)."""
    inv = {v: k for k, v in _NMEA_Q.items() if k in (1, 2, 4, 5, 9)}
    geo = ecef_to_geodetic(sol.p_ecef)
    u = unix_utc_from_gps(sol.t, leap_seconds)
    with atomic_write(path, newline="\r\n") as fh:
        for i in range(len(sol.t)):
            cal = calendar_from_unix(u[i], 3)
            y, mo, d = cal[:10].split("/")
            hms = cal[11:].replace(":", "")
            lat, lon = geo[i, 0], geo[i, 1]
            la = f"{int(abs(lat)):02d}{(abs(lat) % 1) * 60:010.7f}"
            lo = f"{int(abs(lon)):03d}{(abs(lon) % 1) * 60:010.7f}"
            body = (f"{talker}GGA,{hms},{la},{'N' if lat >= 0 else 'S'},{lo},{'E' if lon >= 0 else 'W'},"
                    f"{inv.get(int(sol.quality[i]), 1)},{int(sol.n_sat[i]):02d},0.8,{geo[i, 2]:.4f},M,0.0,M,,")
            rmc = (f"{talker}RMC,{hms},A,{la},{'N' if lat >= 0 else 'S'},{lo},{'E' if lon >= 0 else 'W'},0.0,0.0,"
                   f"{d}{mo}{y[2:]},,,A")
            fh.write(f"${rmc}*{_nmea_checksum(rmc):02X}\n${body}*{_nmea_checksum(body):02X}\n")


# --------------------------------------------------------------------------------------------- dgcal gnss.csv
def _check_gnss_csv(tab) -> None:
    """Times, positions, sigmas and velocities of a gnss.csv finite and physically plausible (sigmas and the
    signed-root cross terms may be empty: defaults then), else InputError naming the row and column."""
    validate.gps_week_sow(tab["gps_week"], tab["gps_sow"], tab.path, tab.lines)
    big = validate.MAX_COORDINATE_M
    for name in ("x", "y", "z"):
        validate.values_in_range(tab[name], -big, big, tab.path, name, tab.lines, unit="m")
    limits = {"sx": big, "sy": big, "sz": big, "svx": validate.MAX_SPEED_M_S, "svy": validate.MAX_SPEED_M_S,
              "svz": validate.MAX_SPEED_M_S}
    for name, hi in limits.items():
        if name in tab:
            validate.positive_values(tab[name], tab.path, name, tab.lines, allow_nan=True, hi=hi, strict=False,
                                     what="sigma")
    for name, hi in (("sxy", big), ("sxz", big), ("syz", big), ("vx", validate.MAX_SPEED_M_S),
                     ("vy", validate.MAX_SPEED_M_S), ("vz", validate.MAX_SPEED_M_S)):
        if name in tab:
            validate.values_in_range(tab[name], -hi, hi, tab.path, name, tab.lines, allow_nan=True)


def read_gnss_csv(path: str | Path) -> GnssSolution:
    """dgcal's gnss.csv (spp/ppk): ECEF position with sx,sy,sz (+ PPK's signed-root sxy,sxz,syz), velocity."""
    tab = read_table(path, ("gps_week", "gps_sow", "x", "y", "z"),
                     ("sx", "sy", "sz", "sxy", "sxz", "syz", "vx", "vy", "vz", "svx", "svy", "svz"),
                     text=("fix", "rejected"))
    _check_gnss_csv(tab)
    t = tab["gps_week"] * SECONDS_PER_WEEK + tab["gps_sow"]
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError("time does not increase", tab.path, int(tab.lines[back[0] + 1]), "gps_sow")
    p = validate.ecef_near_surface(np.column_stack([tab["x"], tab["y"], tab["z"]]), tab.path, tab.lines)
    n = len(t)
    if all(c in tab for c in ("sx", "sy", "sz")):
        s = [np.where(np.isfinite(tab[c]), tab[c], 3.0) for c in ("sx", "sy", "sz")]
        cr = [sqvar_to_cov(np.nan_to_num(tab[c])) if c in tab else np.zeros(n) for c in ("sxy", "syz", "sxz")]
        C = _ecef_cov_to_ned(p, s[0] ** 2, s[1] ** 2, s[2] ** 2, *cr)
    else:
        C = np.tile(np.eye(3) * 9.0, (n, 1, 1))
    v = Cv = None
    if all(c in tab for c in ("vx", "vy", "vz")):
        v = np.column_stack([tab["vx"], tab["vy"], tab["vz"]])
        if all(c in tab for c in ("svx", "svy", "svz")):
            sv = [np.where(np.isfinite(tab[c]), tab[c], 0.2) for c in ("svx", "svy", "svz")]
        else:
            sv = [np.full(n, 0.2)] * 3
        Cv = _ecef_cov_to_ned(p, sv[0] ** 2, sv[1] ** 2, sv[2] ** 2, np.zeros(n), np.zeros(n), np.zeros(n))
    q = np.full(n, 5)
    if "fix" in tab.cols:
        q = np.array([{"fixed": 1, "float": 2, "single": 5}.get(str(f).strip().lower(), 5) for f in tab["fix"]])
    return GnssSolution(t, p, C, q, np.zeros(n, int), v, Cv, tab.lines, tab.path, {"format": "dgcal-gnss-csv"})


# --------------------------------------------------------------------------------------------- any
def sniff_gnss_format(path: str | Path) -> str:
    """'rtklib-pos', 'nmea' or 'dgcal-csv' from a file's first lines."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            head = [fh.readline() for _ in range(60)]
    except OSError as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    s = [h.strip() for h in head if h.strip()]
    if any(h.startswith("$") and re.match(r"^\$[A-Z]{5},", h) for h in s):
        return "nmea"
    if s and s[0].startswith("%"):
        return "rtklib-pos"
    if s and "gps_week" in s[0].lower():
        return "dgcal-csv"
    if any(re.match(r"^\d{4}/\d{2}/\d{2}\s", h) for h in s):
        return "rtklib-pos"
    raise InputError("unrecognised GNSS solution file (RTKLIB .pos with its % header, NMEA GGA, or dgcal gnss.csv)",
                     path)


def read_gnss_solution(path: str | Path, fmt: str | None = None, nmea_date: str | None = None) -> GnssSolution:
    """A GNSS solution file of any supported format (`fmt`: 'rtklib-pos', 'nmea', 'dgcal-csv'; default: sniffed)."""
    fmt = fmt or sniff_gnss_format(path)
    if fmt == "rtklib-pos":
        return read_rtklib_pos(path)
    if fmt == "nmea":
        return read_nmea_gga(path, nmea_date)
    if fmt == "dgcal-csv":
        return read_gnss_csv(path)
    raise InputError(f"unknown GNSS solution format {fmt!r} (rtklib-pos, nmea, dgcal-csv)", path)


def select_quality(sol: GnssSolution, allowed: str | None) -> GnssSolution:
    """The epochs whose quality is in `allowed` ('fixed', 'fixed,float', 'all'/None)."""
    if not allowed or allowed == "all":
        return sol
    want = set()
    codes = {v: k for k, v in QUALITY_NAMES.items()}
    for name in str(allowed).split(","):
        name = name.strip().lower()
        if name not in codes:
            raise InputError(f"unknown fix quality {name!r} (one of {', '.join(codes)}, all)", field="quality")
        want.add(codes[name])
    keep = np.isin(sol.quality, sorted(want))
    if keep.sum() < 2:
        raise InputError(f"fewer than two epochs of quality {allowed}", sol.path, field="Q")
    return sol.subset(keep)
