"""Readers and writers of the dgcal file formats of INTERFACES.md (points, measurements, trajectory, events, EOP).

Every reader checks columns and values and raises `InputError` naming file, line and field; every
writer is atomic. Times are GPS week + seconds of week in files and continuous GPS seconds
(`t = week * 604800 + sow`) in memory.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import Table, formatted, read_table, write_columns, write_table
from dgcal.fields.io.labels import Labels

TRAJECTORY_COLUMNS = ("gps_week", "gps_sow", "lat", "lon", "h", "vn", "ve", "vd", "roll", "pitch", "heading")
TRAJECTORY_SIGMA_COLUMNS = ("s_lat_m", "s_lon_m", "s_h_m", "s_roll", "s_pitch", "s_heading")
EOP_COLUMNS = ("image", "X", "Y", "Z", "omega", "phi", "kappa")
EOP_SIGMA_COLUMNS = ("sX", "sY", "sZ", "somega", "sphi", "skappa")


def gps_seconds(week, sow) -> np.ndarray:
    """Continuous GPS seconds from GPS week and seconds of week."""
    return np.asarray(week, float) * SECONDS_PER_WEEK + np.asarray(sow, float)


def week_sow(t_gps) -> tuple[np.ndarray, np.ndarray]:
    """GPS week (int) and seconds of week from continuous GPS seconds."""
    t = np.asarray(t_gps, float)
    week = np.floor(t / SECONDS_PER_WEEK).astype(int)
    return week, t - week * SECONDS_PER_WEEK


class _GpsTimed:
    """GPS week and seconds of week of the continuous GPS seconds `t` of a record set."""

    t: np.ndarray

    @property
    def week(self) -> np.ndarray:
        return week_sow(self.t)[0]

    @property
    def sow(self) -> np.ndarray:
        return week_sow(self.t)[1]

    def __len__(self) -> int:
        return len(self.t)


def _first_repeat(*columns: np.ndarray) -> int | None:
    """The first row (in file order) whose values in `columns` appeared in an earlier row, or None.

    Rows are sorted by the values' hashes (8 bytes a row, no copy of the strings; a str caches its hash) and
    rows with equal hashes are compared by value, so a hash collision is never taken for a repeat."""
    n = len(columns[0])
    if n < 2:
        return None
    hashes = [np.fromiter(map(hash, c.tolist() if c.dtype != object else c), np.int64, n) for c in columns]
    order = np.lexsort(hashes[::-1])                   # stable: equal keys keep file order
    same = np.ones(n - 1, bool)
    for h in hashes:
        hs = h[order]
        same &= hs[1:] == hs[:-1]
        del hs
    best = None
    for j in np.flatnonzero(same):
        a, b = int(order[j]), int(order[j + 1])
        if all(c[a] == c[b] for c in columns) and (best is None or b < best):
            best = b
    return best


def _check(tab: Table, names, lo: float, hi: float, allow_nan: bool = False, unit: str = "") -> None:
    """Columns `names` (those present) finite and within [lo, hi]; the first bad row's line is named."""
    for n in names:
        if n in tab:
            validate.values_in_range(tab[n], lo, hi, tab.path, n, tab.lines, allow_nan, unit)


def _check_sigmas(tab: Table, names, hi: float, allow_nan: bool, strict: bool = True) -> None:
    """Sigma columns `names` (those present) finite, positive (or zero unless `strict`) and <= hi."""
    for n in names:
        if n in tab:
            validate.positive_values(tab[n], tab.path, n, tab.lines, allow_nan, hi, strict, what="sigma")


# ---------------------------------------------------------------------------------------------
@dataclass
class Points:
    """Field or ground points: ids, coordinates (N,3) m, sigmas (N,3) m (NaN = not given), role per point."""

    ids: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    role: np.ndarray
    lines: np.ndarray | None = None
    path: Path | None = None

    def index(self) -> dict[str, int]:
        """Row of each point id."""
        return {str(k): i for i, k in enumerate(self.ids)}

    def subset(self, mask) -> "Points":
        """The points where `mask` is true."""
        return Points(self.ids[mask], self.xyz[mask], self.sigma[mask], self.role[mask],
                      None if self.lines is None else self.lines[mask], self.path)


def read_points(path: str | Path) -> Points:
    """Read a field/ground point CSV `id,x,y,z[,sx,sy,sz][,role]` (m)."""
    tab = read_table(path, ("id", "x", "y", "z"), ("sx", "sy", "sz", "role"))
    _check(tab, ("x", "y", "z"), -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, unit="m")
    _check_sigmas(tab, ("sx", "sy", "sz"), validate.MAX_COORDINATE_M, allow_nan=True)
    ids = tab["id"]
    k = _first_repeat(ids)
    if k is not None:
        raise InputError(f"duplicate point id {ids[k]!r}", tab.path, int(tab.lines[k]), "id")
    n = len(tab)
    sigma = np.column_stack([tab.get(c, np.full(n, np.nan)) for c in ("sx", "sy", "sz")])
    role = tab.get("role", np.full(n, "", dtype=object)).astype(object)
    role = np.array([(r or "control").lower() for r in role], dtype=object)
    bad = ~np.isin(role, ["control", "check"])
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"role must be 'control' or 'check', got {role[i]!r}", tab.path, int(tab.lines[i]), "role")
    xyz = np.column_stack([tab["x"], tab["y"], tab["z"]])
    return Points(ids, xyz, sigma, role, tab.lines, tab.path)


def write_points(path: str | Path, pts: Points, with_role: bool | None = None) -> None:
    """Write a point CSV; sigma columns when any sigma is given, `role` when any point is a check point."""
    has_sigma = np.isfinite(pts.sigma).any()
    with_role = bool(np.any(pts.role == "check")) if with_role is None else with_role
    header = ["id", "x", "y", "z"] + (["sx", "sy", "sz"] if has_sigma else []) + (["role"] if with_role else [])
    rows = []
    for i in range(len(pts.ids)):
        r = [pts.ids[i], *pts.xyz[i]]
        if has_sigma:
            r += list(pts.sigma[i])
        if with_role:
            r.append(pts.role[i])
        rows.append(r)
    write_table(path, header, rows, fmt="%.6f")


# ---------------------------------------------------------------------------------------------
class Measurements:
    """Image measurements: image label, point id, pixel xy (N,2), sigma (N,2) px (NaN = not given).

    `image` and `id` are arrays of labels. The reader keeps them as codes into the distinct labels
    (`image_labels`, `id_labels`: 4 bytes a row) and builds the arrays on first use; `sigma` of a file without
    sigma columns is built (NaN) on first use too (`stated_sigma` is then None)."""

    def __init__(self, image, id, xy: np.ndarray, sigma: np.ndarray | None, lines: np.ndarray | None = None,
                 path: Path | None = None):
        self._image, self._image_labels = _label_parts(image)
        self._id, self._id_labels = _label_parts(id)
        self.xy = xy
        self._sigma = sigma
        self.lines = lines
        self.path = path

    def __len__(self) -> int:
        return len(self.xy)

    def __repr__(self) -> str:
        return f"Measurements({len(self)} rows, {len(self.images())} images, path={self.path})"

    @property
    def image(self) -> np.ndarray:
        """Image label of every row."""
        if self._image is None:
            self._image = self._image_labels.values()
        return self._image

    @image.setter
    def image(self, value) -> None:
        self._image, self._image_labels = _label_parts(value)

    @property
    def id(self) -> np.ndarray:
        """Point id of every row."""
        if self._id is None:
            self._id = self._id_labels.values()
        return self._id

    @id.setter
    def id(self, value) -> None:
        self._id, self._id_labels = _label_parts(value)

    @property
    def image_labels(self) -> Labels:
        """The image labels as codes into the distinct labels (first appearance order)."""
        if self._image_labels is None:
            self._image_labels = Labels.of(self._image)
        return self._image_labels

    @property
    def id_labels(self) -> Labels:
        """The point ids as codes into the distinct ids (first appearance order)."""
        if self._id_labels is None:
            self._id_labels = Labels.of(self._id)
        return self._id_labels

    @property
    def sigma(self) -> np.ndarray:
        """(N,2) px, NaN where not given."""
        if self._sigma is None:
            self._sigma = np.full((len(self), 2), np.nan)
        return self._sigma

    @sigma.setter
    def sigma(self, value: np.ndarray | None) -> None:
        self._sigma = value

    @property
    def stated_sigma(self) -> np.ndarray | None:
        """(N,2) px as the file states them (NaN where a row gives none), or None when it gives none at all."""
        return self._sigma

    def images(self) -> list[str]:
        """Image labels in order of first appearance."""
        if self._image is None:
            lab = self._image_labels
            return lab.names[lab.present()].tolist()
        return list(dict.fromkeys(self.image.tolist()))

    def subset(self, mask) -> "Measurements":
        """The measurements where `mask` is true."""
        def part(arr, lab):
            return arr[mask] if arr is not None else lab.subset(mask)
        return Measurements(part(self._image, self._image_labels), part(self._id, self._id_labels), self.xy[mask],
                            None if self._sigma is None else self._sigma[mask],
                            None if self.lines is None else self.lines[mask], self.path)


def _label_parts(value) -> tuple[np.ndarray | None, Labels | None]:
    """(array, None) for an array of labels, (None, labels) for `Labels`."""
    return (None, value) if isinstance(value, Labels) else (value, None)


def _first_repeat_codes(a: np.ndarray, b: np.ndarray, nb: int) -> int | None:
    """The first row (in file order) whose code pair (a, b) appeared in an earlier row, or None (codes < 2^31)."""
    if len(a) < 2:
        return None
    key = a.astype(np.int64) * max(nb, 1) + b
    s = np.sort(key)
    if not (s[1:] == s[:-1]).any():          # the usual case: no repeat, found with one sort
        return None
    del s
    order = np.argsort(key, kind="stable")    # equal keys keep file order: the second of a pair is a repeat
    ks = key[order]
    rep = order[1:][ks[1:] == ks[:-1]]
    return int(rep.min())


def read_measurements(path: str | Path) -> Measurements:
    """Read image measurements `image,id,x,y[,sx,sy]` (px, OpenCV pixel convention)."""
    tab = read_table(path, ("image", "id", "x", "y"), ("sx", "sy"), coded=("image", "id"),
                     groups={"xy": ("x", "y"), "sigma": ("sx", "sy")})
    _check(tab, ("x", "y"), -validate.MAX_PIXEL, validate.MAX_PIXEL, unit="px")
    _check_sigmas(tab, ("sx", "sy"), validate.MAX_PIXEL, allow_nan=True)
    image, ids = tab["image"], tab["id"]      # Labels: codes into the distinct strings
    k = _first_repeat_codes(image.codes, ids.codes, len(ids.names))
    if k is not None:
        raise InputError(f"point {ids.names[ids.codes[k]]!r} measured twice in image {image.names[image.codes[k]]!r}",
                         tab.path, int(tab.lines[k]), "id")
    return Measurements(image, ids, tab.groups["xy"], tab.groups.get("sigma"), tab.lines, tab.path)


def write_measurements(path: str | Path, m: Measurements) -> None:
    """Write image measurements; sigma columns when any sigma is given."""
    has_sigma = np.isfinite(m.sigma).any()
    header = ["image", "id", "x", "y"] + (["sx", "sy"] if has_sigma else [])
    cols = [m.image.tolist(), m.id.tolist(), formatted(m.xy[:, 0], "%.4f"), formatted(m.xy[:, 1], "%.4f")]
    if has_sigma:
        cols += [formatted(m.sigma[:, 0], "%.4f"), formatted(m.sigma[:, 1], "%.4f")]
    write_columns(path, header, cols)


# ---------------------------------------------------------------------------------------------
@dataclass
class Trajectory(_GpsTimed):
    """Trajectory samples: GPS time, geodetic position (deg, m ellipsoidal), NED velocity, roll/pitch/heading (deg).

    `sigma` is (N,6): s_lat_m, s_lon_m, s_h_m (m), s_roll, s_pitch, s_heading (deg), or None.
    `image` holds event labels when the file is an events-at-trajectory file (first column `image`).
    """

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    v_ned: np.ndarray
    rph: np.ndarray
    sigma: np.ndarray | None = None
    image: np.ndarray | None = None
    lines: np.ndarray | None = None
    path: Path | None = None


def _check_trajectory(tab: Table) -> None:
    """GPS weeks and seconds of week, latitudes within +-90 deg, longitudes, heights, velocities and angles
    finite and plausible; the sigma columns (when all are given) finite and not negative."""
    validate.gps_week_sow(tab["gps_week"], tab["gps_sow"], tab.path, tab.lines)
    _check(tab, ("lat",), -90.0, 90.0, unit="deg")
    _check(tab, ("lon",), -360.0, 360.0, unit="deg")
    _check(tab, ("h",), -validate.MAX_HEIGHT_M, validate.MAX_HEIGHT_M, unit="m")
    _check(tab, ("vn", "ve", "vd"), -validate.MAX_SPEED_M_S, validate.MAX_SPEED_M_S, unit="m/s")
    _check(tab, ("roll", "pitch", "heading"), -validate.MAX_ANGLE_DEG, validate.MAX_ANGLE_DEG, unit="deg")
    if all(c in tab for c in TRAJECTORY_SIGMA_COLUMNS):
        _check_sigmas(tab, TRAJECTORY_SIGMA_COLUMNS[:3], validate.MAX_HEIGHT_M, allow_nan=False, strict=False)
        _check_sigmas(tab, TRAJECTORY_SIGMA_COLUMNS[3:], validate.MAX_ANGLE_DEG, allow_nan=False, strict=False)


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory CSV (INTERFACES.md columns, optional sigma columns and leading `image`)."""
    tab = read_table(path, TRAJECTORY_COLUMNS, TRAJECTORY_SIGMA_COLUMNS + ("image",))
    _check_trajectory(tab)
    t = gps_seconds(tab["gps_week"], tab["gps_sow"])
    image = tab.get("image")
    if image is None:
        back = np.nonzero(np.diff(t) <= 0)[0]
        if len(back):
            raise InputError("time does not increase", tab.path, int(tab.lines[back[0] + 1]), "gps_sow")
    sig = None
    if all(c in tab for c in TRAJECTORY_SIGMA_COLUMNS):
        sig = np.column_stack([tab[c] for c in TRAJECTORY_SIGMA_COLUMNS])
    return Trajectory(t, tab["lat"], tab["lon"], tab["h"], np.column_stack([tab["vn"], tab["ve"], tab["vd"]]),
                      np.column_stack([tab["roll"], tab["pitch"], tab["heading"]]), sig,
                      None if image is None else image.astype(str).astype(object), tab.lines, tab.path)


def write_trajectory(path: str | Path, tr: Trajectory) -> None:
    """Write a trajectory CSV; with `tr.image` set, an events file whose first column is `image`."""
    week, sow = week_sow(tr.t)
    header = (["image"] if tr.image is not None else []) + list(TRAJECTORY_COLUMNS)
    if tr.sigma is not None:
        header += list(TRAJECTORY_SIGMA_COLUMNS)
    cols = [list(tr.image)] if tr.image is not None else []
    cols += [np.asarray(week, np.int64).tolist(), formatted(sow, "%.6f"), formatted(tr.lat, "%.10f"),
             formatted(tr.lon, "%.10f"), formatted(tr.h, "%.4f")]
    cols += [formatted(tr.v_ned[:, j], "%.4f") for j in range(3)] + [formatted(tr.rph[:, j], "%.6f") for j in range(3)]
    if tr.sigma is not None:
        cols += [formatted(tr.sigma[:, j], "%.4f" if j < 3 else "%.6f") for j in range(6)]
    write_columns(path, header, cols)


# ---------------------------------------------------------------------------------------------
@dataclass
class Events(_GpsTimed):
    """Camera events: image label and recorded event (trigger) time in continuous GPS seconds."""

    image: np.ndarray
    t: np.ndarray
    lines: np.ndarray | None = None
    path: Path | None = None


def read_events(path: str | Path) -> Events:
    """Read an events CSV `image,gps_week,gps_sow`."""
    tab = read_table(path, ("image", "gps_week", "gps_sow"))
    validate.gps_week_sow(tab["gps_week"], tab["gps_sow"], tab.path, tab.lines)
    image = tab["image"]
    k = _first_repeat(image)
    if k is not None:
        raise InputError(f"image {image[k]!r} has two events", tab.path, int(tab.lines[k]), "image")
    return Events(image, gps_seconds(tab["gps_week"], tab["gps_sow"]), tab.lines, tab.path)


def write_events(path: str | Path, ev: Events) -> None:
    """Write an events CSV."""
    week, sow = week_sow(ev.t)
    write_columns(path, ["image", "gps_week", "gps_sow"],
                  [list(ev.image), np.asarray(week, np.int64).tolist(), formatted(sow, "%.6f")])


# ---------------------------------------------------------------------------------------------
@dataclass
class EOP:
    """Exterior orientations: image, projection centre (N,3) in the map CRS (m), PATB omega/phi/kappa (deg).

    `sigma` is (N,6): sX, sY, sZ (m), somega, sphi, skappa (deg), or None. `cov` optionally holds
    full (N,6,6) covariances in the same order and units.
    """

    image: np.ndarray
    xyz: np.ndarray
    opk: np.ndarray
    sigma: np.ndarray | None = None
    cov: np.ndarray | None = field(default=None, repr=False)
    lines: np.ndarray | None = None
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.image)


def read_eop(path: str | Path) -> EOP:
    """Read an EOP CSV `image,X,Y,Z,omega,phi,kappa[,sX,sY,sZ,somega,sphi,skappa]` (column names case-insensitive)."""
    req = tuple(c.lower() for c in EOP_COLUMNS)
    opt = tuple(c.lower() for c in EOP_SIGMA_COLUMNS)
    tab = read_table(path, req, opt)
    _check(tab, ("x", "y", "z"), -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, unit="m")
    _check(tab, ("omega", "phi", "kappa"), -validate.MAX_ANGLE_DEG, validate.MAX_ANGLE_DEG, unit="deg")
    image = tab["image"]
    k = _first_repeat(image)
    if k is not None:
        raise InputError(f"image {image[k]!r} appears twice", tab.path, int(tab.lines[k]), "image")
    sig = None
    if all(c in tab for c in opt):
        _check_sigmas(tab, opt[:3], validate.MAX_COORDINATE_M, allow_nan=False)
        _check_sigmas(tab, opt[3:], validate.MAX_ANGLE_DEG, allow_nan=False)
        sig = np.column_stack([tab[c] for c in opt])
    return EOP(image, np.column_stack([tab["x"], tab["y"], tab["z"]]),
               np.column_stack([tab["omega"], tab["phi"], tab["kappa"]]), sig, None, tab.lines, tab.path)


def write_eop(path: str | Path, eop: EOP) -> None:
    """Write an EOP CSV (sigma columns when given)."""
    header = list(EOP_COLUMNS) + (list(EOP_SIGMA_COLUMNS) if eop.sigma is not None else [])
    cols = [list(eop.image)] + [formatted(eop.xyz[:, j], "%.6f") for j in range(3)]
    cols += [formatted(eop.opk[:, j], "%.9f") for j in range(3)]
    if eop.sigma is not None:
        cols += [formatted(eop.sigma[:, j], "%.5f" if j < 3 else "%.7f") for j in range(6)]
    write_columns(path, header, cols)
