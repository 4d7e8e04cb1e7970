"""Camera event marks beyond the events CSV: DJI `.MRK` timestamp files, `image,utc` CSV, PX4 camera-capture
messages (dgcal.pos.ins.ulog), `read_any_events` choosing by content, and building Events from times.

`image,utc` CSV: a header with `image` and `utc` (UTC as `YYYY-MM-DD[T ]hh:mm:ss[.fff][Z]` or Unix seconds);
GPS time = UTC + the leap seconds (dgcal.fields.io.timescales), or a `gpst` column (same forms) without them.

DJI `Timestamp.MRK` (Phantom 4 RTK, Matrice RTK payloads such as the Zenmuse P1): one tab-separated line per photo:
  `1  282401.669089  [2404]  101,N  107,E  129,V  22.77995359,Lat  114.10089118,Lon  139.231,Ellh
   0.002967, 0.003104, 0.007622  50,Q`
= photo index, GPS seconds of week, [GPS week], the compensation (mm) applied along North, East and Vertical
(V positive downward) from the GNSS antenna phase centre to the camera's CMOS centre, the latitude, longitude (deg)
and ellipsoidal height (m) *after compensation*, i.e. of the camera, their standard deviations N, E, V (m) and the
RTK flag (50 fixed, 34 float, 16 single). Source: DJI Zenmuse P1 User Manual (2021, "Image Log File", items 4-9:
"Compensation value in the north/east/elevation direction ... downward direction is represented by a positive
value", "Longitude after compensation", "Latitude after compensation", "Ellipsoid height"); the DJI Matrice 4
Series User Manual (2025) describes the same columns. For the Phantom 4 RTK, DJI's white paper describes columns 4-6
as the antenna-to-CMOS offsets; whether its columns 7-9 are compensated was not confirmed. A PPK solution computed at
the antenna needs the N/E/V offsets added to reach the camera (as SBG Qinertia's DJI import does).
The time is the recorded trigger time (an event, in dgcal's delay convention).

Pairing MRK rows with image files: DJI names the photos of an MRK `DJI_0001.JPG`, ... on older payloads, while the
P1 writes `DJI_<yyyymmddhhmmss>_<index>.JPG`. `MrkRecords.events(pattern, image_names)` pairs by the index in the
name: a pattern with `{index}` (digits, compared as a number, so `0436` is photo 436) and `{any}` (any text), e.g.
`DJI_{any}_{index}.JPG`, or a regular expression `re:<regex>` with a group `(?P<index>...)`; letter case is ignored.
`pair_by_time_order` pairs the rows in time order with the image names in name order (P1 names sort by time).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.constants import GPS_EPOCH_UNIX_S
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import atomic_write, read_table
from dgcal.fields.io.text_files import read_text
from dgcal.fields.crs import MapGrid, height_unit_factor
from dgcal.fields.io.formats import EOP, Events, gps_seconds, read_events, week_sow
from dgcal.fields.io.timescales import gps_from_unix_gpst, gps_from_unix_utc, unix_from_calendar
from dgcal.pos.ins.ulog import read_ulog_camera_capture

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
# the row's fields in order: (name used in errors, regex piece)
_PARTS = (
    ("index", r"^\s*(?P<idx>\d+)"),
    ("seconds of week", rf"\s+(?P<sow>{_NUM})"),
    ("[week]", r"\s+\[(?P<week>\d+)\]"),
    ("N offset", rf"\s+(?P<n>{_NUM})\s*,\s*N"),
    ("E offset", rf"\s+(?P<e>{_NUM})\s*,\s*E"),
    ("V offset", rf"\s+(?P<v>{_NUM})\s*,\s*V"),
    ("Lat", rf"\s+(?P<lat>{_NUM})\s*,\s*Lat"),
    ("Lon", rf"\s+(?P<lon>{_NUM})\s*,\s*Lon"),
    ("Ellh", rf"\s+(?P<h>{_NUM})\s*,\s*Ellh"),
    ("sigmas", rf"\s+(?P<sn>{_NUM})\s*,\s*(?P<se>{_NUM})\s*,\s*(?P<sv>{_NUM})"),
    ("Q", r"\s+(?P<q>\d+)\s*,\s*Q\s*$"),
)
_MRK = re.compile("".join(p for _, p in _PARTS))
_PREFIXES = [re.compile("".join(p for _, p in _PARTS[:k + 1])) for k in range(len(_PARTS))]


@dataclass
class MrkRecords:
    """DJI MRK rows: event time (GPS s), compensation antenna -> camera (N, E, V down; m), the compensated camera
    position (lat, lon deg, ellipsoidal h m) and its sigmas N, E, V (m), RTK flag."""

    index: np.ndarray
    t: np.ndarray
    offset_nev_m: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    sigma_nev_m: np.ndarray
    quality: np.ndarray
    lines: np.ndarray
    path: Path | None = None

    def events(self, name_pattern: str = "DJI_{index:04d}.JPG", image_names=None) -> Events:
        """The marks as Events. Without `image_names`: names made from `name_pattern` (`{index}` fields). With
        them: each image whose name matches the pattern gets the row of its index (see the module docstring)."""
        if image_names is None:
            if "{any}" in name_pattern or name_pattern.startswith("re:"):
                raise InputError(f"the pattern {name_pattern!r} can only pair existing image names: give the images",
                                 self.path, field="name_pattern")
            names = np.array([name_pattern.format(index=int(i)) for i in self.index], dtype=object)
            return Events(image=names, t=self.t.copy(), lines=self.lines.copy(), path=self.path)
        return pair_by_index(self, image_names, name_pattern)


def index_pattern(pattern: str) -> re.Pattern:
    """A regex (case-insensitive, whole name) with a group `index` from a name pattern: `{index}` / `{index:04d}` =
    digits, `{any}` = any text, `*` = any text, the rest literal; `re:<regex>` is used as it is."""
    if pattern.startswith("re:"):
        try:
            rx = re.compile(pattern[3:], re.I)
        except re.error as exc:
            raise InputError(f"invalid regular expression: {exc}", field="name_pattern") from None
        if "index" not in rx.groupindex:
            raise InputError("the regular expression needs a group (?P<index>...)", field="name_pattern")
        return rx
    parts = re.split(r"(\{index(?::[^}]*)?\}|\{any\}|\*)", pattern)
    if sum(1 for t in parts if t.startswith("{index")) != 1:
        raise InputError(f"the pattern {pattern!r} needs exactly one {{index}}", field="name_pattern")
    body = "".join("(?P<index>\\d+)" if t.startswith("{index") else ".*?" if t in ("{any}", "*") else re.escape(t)
                   for t in parts)
    return re.compile(body + "$", re.I)


def pair_by_index(rec: MrkRecords, image_names, pattern: str = "DJI_{any}_{index}.JPG") -> Events:
    """Events named by the image files whose names carry an MRK photo index (`pattern`, see `index_pattern`), in
    MRK row order; an image whose index has no MRK row, or two images with one index, are InputErrors."""
    rx = index_pattern(pattern)
    names = sorted(str(n) for n in image_names)
    by_index: dict[int, str] = {}
    for n in names:
        m = rx.match(Path(n).name)
        if m is None:
            continue
        k = int(m.group("index"))
        if k in by_index:
            raise InputError(f"images {by_index[k]!r} and {n!r} both carry photo index {k}", rec.path,
                             field="name_pattern")
        by_index[k] = n
    if not by_index:
        raise InputError(f"no image name matches {pattern!r} (e.g. {names[0] if names else 'no images'!r})",
                         rec.path, field="name_pattern")
    row = {int(k): i for i, k in enumerate(rec.index)}
    missing = sorted(k for k in by_index if k not in row)
    if missing:
        raise InputError(f"{len(missing)} image(s) have no MRK row, e.g. {by_index[missing[0]]!r} (photo index "
                         f"{missing[0]}; the MRK has {int(rec.index.min())}..{int(rec.index.max())})", rec.path,
                         field="index")
    rows = np.array(sorted(row[k] for k in by_index))
    return Events(image=np.array([by_index[int(rec.index[i])] for i in rows], dtype=object), t=rec.t[rows].copy(),
                  lines=rec.lines[rows].copy(), path=rec.path)


def mrk_centres(rec: MrkRecords, crs: str, events: Events | None = None) -> EOP:
    """Camera-centre priors from MRK rows: the compensated camera positions (DJI P1 manual) in map CRS `crs` with
    sX, sY, sZ from the rows' sigmas E, N, V (NaN where 0); one per event of `events` (paired rows, e.g. from
    `pair_by_index`), or one per row named as `rec.events()` names them. Angles NaN."""
    ev = rec.events() if events is None else events
    row = {int(ln): i for i, ln in enumerate(rec.lines)}
    try:
        rows = np.array([row[int(ln)] for ln in ev.lines], int)
    except (KeyError, TypeError):
        raise InputError("the events are not rows of this MRK file", rec.path, field="events") from None
    grid = MapGrid(crs)
    if grid.crs.is_geographic:
        raise InputError(f"camera centres need a projected CRS, not the geographic {crs!r}", rec.path, field="crs")
    xyz = grid.from_geodetic(rec.lat[rows], rec.lon[rows], rec.h[rows])
    unit = height_unit_factor(grid.crs)
    s = np.where(rec.sigma_nev_m[rows] > 0, rec.sigma_nev_m[rows], np.nan)    # a zero sigma is "not given"
    sig = np.full((len(rows), 6), np.nan)
    sig[:, 0], sig[:, 1], sig[:, 2] = s[:, 1] / unit, s[:, 0] / unit, s[:, 2] / grid.z_unit_m
    return EOP(np.asarray(ev.image, dtype=object), xyz, np.full((len(rows), 3), np.nan), sig, None,
               rec.lines[rows].copy(), rec.path)


def pair_by_time_order(rec: MrkRecords, image_names) -> Events:
    """Events pairing the MRK rows in time order with the image names in name order (counts must agree)."""
    order = np.argsort(rec.t, kind="stable")
    ev = Events(image=np.array([f"#{int(i)}" for i in rec.index[order]], dtype=object), t=rec.t[order].copy(),
                lines=rec.lines[order].copy(), path=rec.path)
    return match_events_to_images(ev, image_names)


def _diagnose(line: str) -> str:
    """The first MRK field (in row order) that does not parse, for the error message."""
    for (name, _), rx in zip(_PARTS, _PREFIXES):
        if rx.match(line) is None:
            return name
    return "Q"


def read_mrk(path: str | Path) -> MrkRecords:
    """Read a DJI `.MRK` timestamp file; InputError naming file, line and field on malformed rows."""
    path = Path(path)
    text = read_text(path)
    rows, lines = [], []
    for ln, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _MRK.match(line)
        if m is None:
            raise InputError(f"not a DJI MRK row: {line.strip()[:60]!r}", path, ln, _diagnose(line))
        rows.append(m.groupdict())
        lines.append(ln)
    if not rows:
        raise InputError("no MRK rows", path)

    def col(k):
        return np.array([float(r[k]) for r in rows])
    lines_a = np.array(lines)
    week, sow = col("week"), col("sow")
    validate.gps_week_sow(week, sow, path, lines_a, ("[week]", "seconds of week"))
    for k, name, lim in (("lat", "Lat", 90.0), ("lon", "Lon", 360.0), ("h", "Ellh", validate.MAX_HEIGHT_M),
                         ("n", "N offset", 1e6), ("e", "E offset", 1e6), ("v", "V offset", 1e6)):
        validate.values_in_range(col(k), -lim, lim, path, name, lines_a)
    for k in ("sn", "se", "sv"):
        validate.positive_values(col(k), path, "sigmas", lines_a, hi=1e6, strict=False, what="sigma")
    validate.whole_values(col("idx"), 0, 10 ** 9, path, "index", lines_a)
    validate.whole_values(col("q"), 0, 10 ** 6, path, "Q", lines_a)
    t = gps_seconds(week, sow)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        raise InputError("event time does not increase", path, int(lines_a[back[0] + 1]), "seconds of week")
    idx = col("idx").astype(np.int64)
    dup = np.flatnonzero(np.diff(np.sort(idx)) == 0)
    if dup.size:
        i = int(np.sort(idx)[dup[0]])
        raise InputError(f"photo index {i} appears twice", path, int(lines_a[np.flatnonzero(idx == i)[1]]), "index")
    return MrkRecords(index=idx, t=t, offset_nev_m=np.column_stack([col("n"), col("e"), col("v")]) * 1e-3,
                      lat=col("lat"), lon=col("lon"), h=col("h"),
                      sigma_nev_m=np.column_stack([col("sn"), col("se"), col("sv")]), quality=col("q").astype(np.int64),
                      lines=lines_a, path=path)


def write_mrk(path: str | Path, rec: MrkRecords) -> None:
    """Write MRK rows in DJI's layout (for tests and simulated data sets), atomically."""
    week, sow = week_sow(rec.t)
    with atomic_write(path, newline="\n") as fh:
        for i in range(len(rec.t)):
            n, e, v = np.round(rec.offset_nev_m[i] * 1e3).astype(int)
            sn, se, sv = rec.sigma_nev_m[i]
            fh.write(f"{int(rec.index[i])}\t{sow[i]:.6f}\t[{int(week[i])}]\t{n:6d},N\t{e:6d},E\t{v:6d},V\t"
                     f"{rec.lat[i]:.8f},Lat\t{rec.lon[i]:.8f},Lon\t{rec.h[i]:.3f},Ellh\t"
                     f"{sn:.6f}, {se:.6f}, {sv:.6f}\t{int(rec.quality[i])},Q\n")


def make_events(t_gps, names=None, prefix: str = "IMG_", suffix: str = ".JPG", start: int = 1) -> Events:
    """Events at GPS times (s) with the given names or `prefix` + zero-padded counter + `suffix`."""
    t = np.asarray(t_gps, float)
    if names is None:
        names = [f"{prefix}{k:04d}{suffix}" for k in range(start, start + len(t))]
    names = np.asarray(names, dtype=object)
    if len(names) != len(t):
        raise ValueError("names and times differ in length")
    return Events(image=names, t=t)


def match_events_to_images(events: Events, image_names) -> Events:
    """Events renamed to sorted image names one-to-one (cameras name files, triggers only count).

    Raises InputError when the counts differ, naming the events file.
    """
    imgs = sorted(str(n) for n in image_names)
    if len(imgs) != len(events.t):
        raise InputError(f"{len(events.t)} events but {len(imgs)} images; cannot pair them in order",
                         events.path, field="image")
    return Events(image=np.array(imgs, dtype=object), t=np.asarray(events.t, float).copy(), lines=events.lines,
                  path=events.path)


def read_utc_events(path: str | Path, leap_seconds: float | None = None) -> Events:
    """Events from a CSV `image,utc` (or `image,gpst`): date-time texts or Unix seconds (see the module docstring)."""
    path = Path(path)
    tab = read_table(path, ("image",), (), text=("image", "utc", "gpst", "time"))
    head = [c for c in ("utc", "gpst") if c in tab.cols]
    if not head:
        tab = read_table(path, ("image", "utc"), (), text=("image", "utc"))
        head = ["utc"]
    col = head[0]
    u = np.empty(len(tab))
    for i, v in enumerate(tab[col]):
        s = str(v).strip()
        try:
            u[i] = float(s)
        except ValueError:
            try:
                u[i] = unix_from_calendar(s.rstrip("Zz"))
            except ValueError as exc:
                raise InputError(str(exc), path, int(tab.lines[i]), col) from None
        if not np.isfinite(u[i]):
            raise InputError("not a finite time", path, int(tab.lines[i]), col)
    validate.values_in_range(u, GPS_EPOCH_UNIX_S, GPS_EPOCH_UNIX_S + validate.GPS_SECONDS_MAX, path, col, tab.lines,
                             unit="s")
    t = gps_from_unix_utc(u, leap_seconds) if col == "utc" else gps_from_unix_gpst(u)
    image = np.array([str(v) for v in tab["image"]], dtype=object)
    _, first = np.unique(image, return_index=True)
    if len(first) < len(image):
        dup = np.setdiff1d(np.arange(len(image)), first)[0]
        raise InputError(f"image {image[dup]!r} has two events", path, int(tab.lines[dup]), "image")
    return Events(image, t, tab.lines, path)


EVENT_FORMATS = ("dgcal", "mrk", "utc-csv", "px4")


def sniff_events_format(path: str | Path) -> str:
    """The events file's format from its content: dgcal, mrk, utc-csv or px4 (ULog)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"ULog"):
        return "px4"
    text = head.decode("utf-8", "replace").lstrip("\ufeff")
    first = next((ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")), "")
    low = first.lower()
    if _MRK.match(first) or re.search(r",\s*Lat\b", first):
        return "mrk"
    cols = [c.strip() for c in low.split(",")]
    if "image" in cols and ("utc" in cols or "gpst" in cols) and "gps_sow" not in cols:
        return "utc-csv"
    return "dgcal"


def read_any_events(path: str | Path, fmt: str | None = None, name_pattern: str = "DJI_{index:04d}.JPG",
                    image_names=None, pairing: str = "index") -> Events:
    """Camera events from a dgcal events CSV, a DJI `.MRK`, an `image,utc` CSV or a PX4 ULog's camera_capture
    (`fmt` one of EVENT_FORMATS; default: recognised by content). An MRK's rows are named by `name_pattern`, or
    paired with `image_names` (the image files) by the index in their names (`pairing="index"`) or in time order
    (`pairing="time"`); see the module docstring."""
    fmt = fmt or sniff_events_format(path)
    if fmt == "dgcal":
        return read_events(path)
    if fmt == "mrk":
        rec = read_mrk(path)
        if pairing == "time":
            if image_names is None:
                raise InputError(f"{path}: pairing MRK rows in time order needs the image folder", field="event_images")
            return pair_by_time_order(rec, image_names)
        if pairing != "index":
            raise InputError(f"unknown pairing {pairing!r} (index or time)", field="mrk_pairing")
        return rec.events(name_pattern, image_names)
    if fmt == "utc-csv":
        return read_utc_events(path)
    if fmt == "px4":
        return read_ulog_camera_capture(path)
    raise InputError(f"unknown events format {fmt!r} (one of {', '.join(EVENT_FORMATS)})", path,
                     field="events_format")
