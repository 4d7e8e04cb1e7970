"""Camera centres from DJI images: the XMP `drone-dji:` tags (and EXIF GPS) in the JPEG bytes -> EOP in a map CRS.

DJI writes an XMP packet (plain text in a JPEG APP1 segment starting `http://ns.adobe.com/xap/1.0/\\0`) with
`drone-dji:` attributes (DJI Mavic 3E/3M and Matrice 4 user manuals, "Photo File" field lists): `GpsLatitude`,
`GpsLongitude` (older firmware spells it `GpsLongtitude`), `AbsoluteAltitude` ("absolute (geodetic) altitude"),
`RelativeAltitude`, `GimbalRollDegree`/`GimbalPitchDegree`/`GimbalYawDegree` and `FlightRoll/Pitch/YawDegree`
(NED, rotation order Z-Y-X), `RtkFlag` (0 no position, 16 single point, 32-49 float, 50 fixed),
`RtkStdLon`/`RtkStdLat`/`RtkStdHgt` (RTK standard deviations, m), `AltitudeType`. Without XMP the EXIF GPS IFD
(GPSLatitude/Ref, GPSLongitude/Ref, GPSAltitude/Ref) gives the position.

Heights: dgcal takes `AbsoluteAltitude` as the ellipsoidal height its CRS needs. DJI's manuals call it "geodetic
altitude" without naming the datum, and many DJI drones without RTK write heights above the EGM96 geoid: give
`geoid_undulation_m` (N, added: h = H + N) when yours does (the record keeps `AltitudeType` to check).
Sigmas: RtkStdLat/Lon/Hgt when present and positive, else by RtkFlag: fixed (50) 0.02/0.02/0.05 m, float (32-49)
0.5/0.5/1 m, single (16) 3/3/5 m, anything else (no RTK) 5/5/10 m — assumed defaults, not DJI's figures.
"""
from __future__ import annotations

import io
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from dgcal.fields.crs import MapGrid, height_unit_factor
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_NED_TO_ENU, R_body_to_ned_from_rph, R_enu_to_grid, opk_from_R_cam_to_map
from dgcal.fields.io import validate
from dgcal.fields.io.centres import read_centres
from dgcal.fields.io.formats import EOP

XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
EXIF_HEADER = b"Exif\x00\x00"
JPEG_SUFFIXES = (".jpg", ".jpeg")
DEFAULT_SIGMA_M = {"fixed": (0.02, 0.02, 0.05), "float": (0.5, 0.5, 1.0), "single": (3.0, 3.0, 5.0),
                   "none": (5.0, 5.0, 10.0)}
_ATTR = re.compile(rb'drone-dji:(\w+)\s*=\s*"([^"]*)"')
_ELEM = re.compile(rb"<drone-dji:(\w+)>([^<]*)</drone-dji:\1>")


@dataclass
class DjiPhoto:
    """What a DJI image says about its exposure: geodetic position (deg, m), RTK state and sigmas (m), angles (deg)."""

    name: str
    lat: float
    lon: float
    h: float
    rtk_flag: int | None = None
    sigma_nev_m: tuple[float, float, float] | None = None
    gimbal_rpy_deg: tuple[float, float, float] | None = None
    flight_rpy_deg: tuple[float, float, float] | None = None
    tags: dict[str, str] = field(default_factory=dict, repr=False)


def jpeg_app1_segments(data: bytes | BinaryIO, path: Path | None = None) -> list[bytes]:
    """The payloads of a JPEG's APP1 segments (EXIF, XMP), read up to the start of the scan: only the segment
    headers and the APP1 payloads are read from a file (the previews DJI stores in APP2 are skipped over)."""
    fh = io.BytesIO(data) if isinstance(data, (bytes, bytearray)) else data
    if fh.read(2) != b"\xff\xd8":
        raise InputError("not a JPEG file (no SOI marker)", path, field="image")
    out = []
    while True:
        pos = fh.tell()
        head = fh.read(2)
        if len(head) < 2:
            break
        if head[0] != 0xFF:
            raise InputError(f"damaged JPEG: no segment marker at byte {pos}", path, field="image")
        marker = head[1]
        if marker == 0xFF:               # fill byte
            fh.seek(pos + 1)
            continue
        if marker in (0xD9, 0xDA):       # end of image / start of scan: no metadata after it
            break
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue
        raw = fh.read(2)
        length = struct.unpack(">H", raw)[0] if len(raw) == 2 else 0
        if length < 2:
            raise InputError(f"damaged JPEG: bad segment length at byte {pos}", path, field="image")
        if marker == 0xE1:
            payload = fh.read(length - 2)
            if len(payload) < length - 2:
                raise InputError(f"damaged JPEG: segment at byte {pos} runs past the end of the file", path,
                                 field="image")
            out.append(payload)
        else:
            fh.seek(length - 2, io.SEEK_CUR)
    return out


def dji_xmp_tags(segments: list[bytes]) -> dict[str, str]:
    """The `drone-dji:` XMP properties (attribute or element form) of the APP1 payloads, as text."""
    tags: dict[str, str] = {}
    for seg in segments:
        if not seg.startswith(XMP_HEADER):
            continue
        body = seg[len(XMP_HEADER):]
        for rx in (_ATTR, _ELEM):
            for k, v in rx.findall(body):
                tags.setdefault(k.decode("ascii"), v.decode("utf-8", "replace").strip())
    return tags


def exif_gps(segments: list[bytes], path: Path | None = None) -> tuple[float, float, float] | None:
    """(lat, lon deg, altitude m) from the EXIF GPS IFD, or None when the image has none."""
    for seg in segments:
        if not seg.startswith(EXIF_HEADER):
            continue
        t = seg[len(EXIF_HEADER):]
        try:
            return _tiff_gps(t)
        except (struct.error, IndexError, ZeroDivisionError, ValueError):
            raise InputError("damaged EXIF GPS block", path, field="GPS") from None
    return None


def _tiff_gps(t: bytes) -> tuple[float, float, float] | None:
    end = {b"II": "<", b"MM": ">"}.get(t[:2])
    if end is None:
        raise ValueError("not TIFF")

    def ifd(off: int) -> dict[int, tuple[int, int, bytes]]:
        n = struct.unpack(end + "H", t[off:off + 2])[0]
        out = {}
        for k in range(n):
            e = t[off + 2 + 12 * k: off + 14 + 12 * k]
            tag, typ, cnt = struct.unpack(end + "HHI", e[:8])
            out[tag] = (typ, cnt, e[8:12])
        return out

    def rationals(typ, cnt, raw) -> list[float]:
        off = struct.unpack(end + "I", raw)[0]
        vals = struct.unpack(end + "%dI" % (2 * cnt), t[off:off + 8 * cnt])
        return [vals[2 * k] / vals[2 * k + 1] for k in range(cnt)]

    ifd0 = ifd(struct.unpack(end + "I", t[4:8])[0])
    if 0x8825 not in ifd0:
        return None
    gps = ifd(struct.unpack(end + "I", ifd0[0x8825][2])[0])
    if 2 not in gps or 4 not in gps:
        return None
    lat_dms, lon_dms = rationals(*gps[2]), rationals(*gps[4])
    lat = lat_dms[0] + lat_dms[1] / 60 + lat_dms[2] / 3600
    lon = lon_dms[0] + lon_dms[1] / 60 + lon_dms[2] / 3600
    if gps.get(1, (0, 0, b"N"))[2][:1] == b"S":
        lat = -lat
    if gps.get(3, (0, 0, b"E"))[2][:1] == b"W":
        lon = -lon
    alt = rationals(*gps[6])[0] if 6 in gps else float("nan")
    if 5 in gps and gps[5][2][:1] == b"\x01":
        alt = -alt
    return lat, lon, alt


def _tag_number(tags: dict[str, str], names, path, lo, hi, unit="") -> float | None:
    for n in names:
        if n in tags and tags[n] != "":
            return validate.in_range(tags[n].lstrip("+"), lo, hi, path, None, f"drone-dji:{n}", unit)
    return None


def read_dji_photo(path: str | Path, geoid_undulation_m: float = 0.0) -> DjiPhoto:
    """Position, RTK state and angles of one DJI JPEG (XMP `drone-dji:` tags, EXIF GPS as the fallback)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            segs = jpeg_app1_segments(fh, path)
    except OSError as exc:
        raise InputError(f"cannot read image ({exc.strerror})", path, field="image") from None
    tags = dji_xmp_tags(segs)
    lat = _tag_number(tags, ("GpsLatitude", "Latitude"), path, -90, 90, "deg")
    lon = _tag_number(tags, ("GpsLongitude", "GpsLongtitude", "Longitude"), path, -180, 180, "deg")
    h = _tag_number(tags, ("AbsoluteAltitude",), path, -validate.MAX_HEIGHT_M, validate.MAX_HEIGHT_M, "m")
    if lat is None or lon is None or h is None:
        g = exif_gps(segs, path)
        if g is None and (lat is None or lon is None):
            raise InputError("no position: neither drone-dji:GpsLatitude/GpsLongitude nor EXIF GPS", path,
                             field="GpsLatitude")
        if g is not None:
            lat = lat if lat is not None else validate.in_range(g[0], -90, 90, path, None, "GPSLatitude", "deg")
            lon = lon if lon is not None else validate.in_range(g[1], -180, 180, path, None, "GPSLongitude", "deg")
            h = h if h is not None else g[2]
        if h is None or not np.isfinite(h):
            raise InputError("no height: neither drone-dji:AbsoluteAltitude nor EXIF GPSAltitude", path,
                             field="AbsoluteAltitude")
        h = validate.in_range(h, -validate.MAX_HEIGHT_M, validate.MAX_HEIGHT_M, path, None, "GPSAltitude", "m")
    flag = _tag_number(tags, ("RtkFlag",), path, 0, 1000)
    std = [_tag_number(tags, (n,), path, 0, validate.MAX_HEIGHT_M, "m") for n in ("RtkStdLat", "RtkStdLon",
                                                                                    "RtkStdHgt")]

    def angles(prefix):
        v = [_tag_number(tags, (f"{prefix}{a}Degree",), path, -validate.MAX_ANGLE_DEG, validate.MAX_ANGLE_DEG,
                         "deg") for a in ("Roll", "Pitch", "Yaw")]
        return None if any(x is None for x in v) else tuple(v)
    return DjiPhoto(path.name, lat, lon, h + float(geoid_undulation_m), None if flag is None else int(flag),
                    None if any(s is None or s <= 0 for s in std) else tuple(std),
                    angles("Gimbal"), angles("Flight"), tags)


def rtk_class(flag: int | None) -> str:
    """'fixed', 'float', 'single' or 'none' from DJI's RtkFlag (50; 32-49; 16; anything else)."""
    if flag == 50:
        return "fixed"
    if flag is not None and 32 <= flag <= 49:
        return "float"
    if flag == 16:
        return "single"
    return "none"


def photo_sigma_m(photo: DjiPhoto) -> tuple[float, float, float]:
    """(sigma north, east, up) m of a photo's position: RtkStd* when given, else the RtkFlag default."""
    return photo.sigma_nev_m if photo.sigma_nev_m is not None else DEFAULT_SIGMA_M[rtk_class(photo.rtk_flag)]


def list_jpegs(folder: str | Path) -> list[Path]:
    """The JPEG files of a folder (not recursive), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder of images", folder, field="images")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in JPEG_SUFFIXES and p.is_file())
    if not files:
        raise InputError("no .jpg/.jpeg images in the folder", folder, field="images")
    return files


def dji_centres(images, crs: str, geoid_undulation_m: float = 0.0, angles: bool = False) -> EOP:
    """Camera centres of DJI JPEGs (a folder or a list of files) as an EOP in map CRS `crs` (X, Y, Z in its
    units, ellipsoidal heights), sigmas sX,sY,sZ from the photos (see `photo_sigma_m`); angles NaN, or with
    `angles` the PATB omega/phi/kappa (deg, grid axes) of the gimbal attitude (`gimbal_opk`) as approximations."""
    files = list_jpegs(images) if isinstance(images, (str, Path)) and Path(images).is_dir() else \
        [Path(p) for p in images]
    photos = [read_dji_photo(p, geoid_undulation_m) for p in files]
    grid = MapGrid(crs)
    if grid.crs.is_geographic:
        raise InputError(f"camera centres need a projected CRS (metres or feet), not the geographic {crs!r}",
                         field="crs")
    lat = np.array([p.lat for p in photos])
    lon = np.array([p.lon for p in photos])
    h = np.array([p.h for p in photos])
    xyz = grid.from_geodetic(lat, lon, h)
    unit = height_unit_factor(grid.crs)
    s_neu = np.array([photo_sigma_m(p) for p in photos])
    sig = np.full((len(photos), 6), np.nan)
    sig[:, 0], sig[:, 1], sig[:, 2] = s_neu[:, 1] / unit, s_neu[:, 0] / unit, s_neu[:, 2] / grid.z_unit_m
    opk = np.full((len(photos), 3), np.nan)
    if angles:
        rpy = np.array([p.gimbal_rpy_deg if p.gimbal_rpy_deg is not None else (np.nan,) * 3 for p in photos])
        ok = np.isfinite(rpy).all(axis=1)
        if ok.any():
            opk[ok] = gimbal_opk(rpy[ok], grid.convergence_deg(lat[ok], lon[ok]))
    names = np.array([p.name for p in photos], dtype=object)
    return EOP(names, xyz, opk, sig, None, None, None)


# the CV camera axes in DJI's gimbal frame (x along the optical axis at zero pitch, y right, z down):
# x_cam = gimbal y, y_cam = gimbal z, z_cam = gimbal x
R_CAM_TO_GIMBAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def gimbal_opk(rpy_deg: np.ndarray, convergence_deg) -> np.ndarray:
    """PATB omega, phi, kappa (deg, grid axes) of cameras from DJI gimbal roll, pitch, yaw (deg; NED, Z-Y-X as DJI's
    manuals state) and the meridian convergence at the cameras (deg): nadir (pitch -90) with yaw 0 is (0, 0, 0)."""
    rpy = np.asarray(rpy_deg, float).reshape(-1, 3)
    R_gimbal_to_ned = R_body_to_ned_from_rph(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    R_cam_to_grid = R_enu_to_grid(np.asarray(convergence_deg, float).reshape(-1)) @ R_NED_TO_ENU @ \
        R_gimbal_to_ned @ R_CAM_TO_GIMBAL
    return opk_from_R_cam_to_map(R_cam_to_grid)


def read_any_centres(path: str | Path, crs: str, geoid_undulation_m: float = 0.0) -> EOP:
    """Camera centres (`--gnss`) from a centres CSV (in `crs`), a folder of DJI JPEGs or one JPEG (converted into
    `crs`), recognised by what `path` is and holds."""
    p = Path(path)
    if p.is_dir():
        return dji_centres(p, crs, geoid_undulation_m)
    if is_jpeg(p):
        return dji_centres([p], crs, geoid_undulation_m)
    return read_centres(p)


def is_jpeg(path: str | Path) -> bool:
    """True when `path` is a file that starts like a JPEG (SOI marker)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(2) == b"\xff\xd8"
    except OSError:
        return False
