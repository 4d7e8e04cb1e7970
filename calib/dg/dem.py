"""Digital elevation models from GeoTIFF (tifffile + the GeoTIFF tags), bilinear heights in the DEM's map CRS.

Georeferencing tags read: ModelPixelScale (33550) + ModelTiepoint (33922), or ModelTransformation (34264);
GeoKeyDirectory (34735) for the EPSG code (ProjectedCSType 3072 / GeographicType 2048) and the raster type
(GTRasterType 1025: PixelIsArea, the default, or PixelIsPoint); GDAL_NODATA (42113). The affine maps
pixel centres: with PixelIsArea the tiepoint refers to the corner of pixel (0, 0), so the centre of pixel
(col, row) is at x0 + (col + 0.5) dx, y0 - (row + 0.5) dy.
Heights are whatever the file holds (ellipsoidal in dgcal unless said otherwise).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile

from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate

_PIXEL_SCALE, _TIEPOINT, _TRANSFORM, _GEOKEYS, _NODATA = 33550, 33922, 34264, 34735, 42113
_KEY_RASTER, _KEY_GEOG, _KEY_PROJ = 1025, 2048, 3072
MAX_DEM_SAMPLES = 400_000_000    # 20 000 x 20 000 heights: larger is a damaged header, not a DEM


@dataclass
class Dem:
    """A height grid: `heights[row, col]` (m) with pixel centres at `A @ [col, row, 1]` = map (x, y).

    A: (2,3) affine pixel-centre -> map coordinates; crs: pyproj-readable text or None; NaN = no data."""

    heights: np.ndarray
    A: np.ndarray
    crs: str | None = None
    path: Path | None = None

    def pixel_of(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (col, row) of map points."""
        M = np.vstack([self.A, [0.0, 0.0, 1.0]])
        Mi = np.linalg.inv(M)
        x, y = np.asarray(x, float), np.asarray(y, float)
        return Mi[0, 0] * x + Mi[0, 1] * y + Mi[0, 2], Mi[1, 0] * x + Mi[1, 1] * y + Mi[1, 2]

    def height(self, x, y) -> np.ndarray:
        """Bilinear height (m) at map points (same shape as x); NaN outside the grid or next to no-data."""
        c, r = self.pixel_of(x, y)
        H = self.heights
        nr, nc = H.shape
        c0 = np.floor(c).astype(int)
        r0 = np.floor(r).astype(int)
        ok = (c >= 0) & (r >= 0) & (c <= nc - 1) & (r <= nr - 1)
        c0 = np.clip(c0, 0, max(nc - 2, 0))
        r0 = np.clip(r0, 0, max(nr - 2, 0))
        fc, fr = c - c0, r - r0
        c1, r1 = np.minimum(c0 + 1, nc - 1), np.minimum(r0 + 1, nr - 1)
        h = (H[r0, c0] * (1 - fc) * (1 - fr) + H[r0, c1] * fc * (1 - fr) + H[r1, c0] * (1 - fc) * fr
             + H[r1, c1] * fc * fr)
        return np.where(ok, h, np.nan)

    def gradient(self, x, y, step: float | None = None) -> np.ndarray:
        """Surface slope (dh/dx, dh/dy) at map points by central differences of `height`; (...,2)."""
        s = step if step is not None else 0.5 * float(np.hypot(*self.A[:, 0]))
        x, y = np.asarray(x, float), np.asarray(y, float)
        return np.stack([(self.height(x + s, y) - self.height(x - s, y)) / (2 * s),
                         (self.height(x, y + s) - self.height(x, y - s)) / (2 * s)], axis=-1)


def _geokeys(tags) -> dict[int, object]:
    if _GEOKEYS not in tags:
        return {}
    k = np.asarray(tags[_GEOKEYS], int).ravel()
    out = {}
    for i in range(1, min(int(k[3]), len(k) // 4 - 1) + 1):
        key, loc, count, val = k[4 * i:4 * i + 4]
        if loc == 0:
            out[int(key)] = int(val)
    return out


def read_geotiff_dem(path: str | Path, band: int = 0) -> Dem:
    """A DEM from a single-band (or the `band`th) GeoTIFF; errors name the file and the missing tag."""
    path = Path(path)
    if not path.is_file():
        raise InputError("DEM file not found", path)
    try:
        with tifffile.TiffFile(path) as tf:
            if not tf.pages:
                raise InputError("a TIFF without images", path)
            page = tf.pages[0]
            n = int(np.prod(page.shape)) if page.shape else 0
            if not 0 < n <= MAX_DEM_SAMPLES:
                raise InputError(f"implausible DEM size {page.shape} (1 to {MAX_DEM_SAMPLES} samples)", path)
            tags = {t.code: t.value for t in page.tags.values()}
            data = page.asarray()
            keys = _geokeys(tags)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - tifffile parses users' bytes: whatever it trips on, the file is bad
        raise InputError(f"not a readable TIFF ({type(e).__name__}: {' '.join(str(e).split())[:100]})", path) \
            from None
    if data.ndim == 3:
        data = data[..., band] if data.shape[-1] < data.shape[0] else data[band]
    if data.ndim != 2 or not np.issubdtype(data.dtype, np.number):
        raise InputError(f"a DEM must be one band of numbers, not {data.shape} {data.dtype}", path)
    H = np.asarray(data, float)
    pixel_is_point = keys.get(_KEY_RASTER, 1) == 2
    try:
        if _TRANSFORM in tags:
            T = np.asarray(tags[_TRANSFORM], float).reshape(4, 4)
            A = np.array([[T[0, 0], T[0, 1], T[0, 3]], [T[1, 0], T[1, 1], T[1, 3]]])
        elif _PIXEL_SCALE in tags and _TIEPOINT in tags:
            sx, sy = np.asarray(tags[_PIXEL_SCALE], float)[:2]
            tp = np.asarray(tags[_TIEPOINT], float)[:6]
            i, j, x, y = tp[0], tp[1], tp[3], tp[4]
            A = np.array([[sx, 0.0, x - i * sx], [0.0, -sy, y + j * sy]])
        else:
            raise InputError("no georeferencing (ModelPixelScale+ModelTiepoint or ModelTransformation tag)", path,
                             field="GeoTIFF tags")
    except (TypeError, ValueError, IndexError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError("unreadable georeferencing tags", path, field="GeoTIFF tags") from None
    validate.values_in_range(A.ravel(), -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, path, "GeoTIFF tags")
    if abs(np.linalg.det(A[:, :2])) < 1e-12:
        raise InputError("the pixel size is zero (a singular georeferencing)", path, field="GeoTIFF tags")
    if not pixel_is_point:  # the affine refers to pixel corners; move it to pixel centres
        A[:, 2] += 0.5 * A[:, 0] + 0.5 * A[:, 1]
    if _NODATA in tags:
        try:
            nd = float(str(tags[_NODATA]).strip("\x00 "))
            H[H == nd] = np.nan
        except ValueError:
            raise InputError(f"bad GDAL_NODATA value {str(tags[_NODATA])[:40]!r}", path, field="GDAL_NODATA") \
                from None
    H[~np.isfinite(H)] = np.nan
    if np.any(np.abs(H[np.isfinite(H)]) > validate.MAX_HEIGHT_M):
        raise InputError(f"heights beyond +-{validate.MAX_HEIGHT_M:g} m (a no-data value without GDAL_NODATA?)",
                         path)
    epsg = keys.get(_KEY_PROJ) or keys.get(_KEY_GEOG)
    crs = f"EPSG:{epsg}" if epsg and epsg != 32767 and 0 < epsg < 10 ** 6 else None
    return Dem(H, A, crs, path)


def write_geotiff_dem(path: str | Path, dem: Dem, epsg: int | None = None, nodata: float = -9999.0) -> None:
    """Write a DEM as a float32 GeoTIFF (PixelIsArea, north-up affine only) with EPSG and GDAL_NODATA tags."""
    A = np.asarray(dem.A, float)
    if A[0, 1] != 0 or A[1, 0] != 0:
        raise ValueError("only north-up DEMs can be written with pixel scale + tiepoint")
    sx, sy = A[0, 0], -A[1, 1]
    x0, y0 = A[0, 2] - 0.5 * sx, A[1, 2] + 0.5 * sy  # corner of pixel (0, 0)
    code = epsg
    if code is None and dem.crs and dem.crs.upper().startswith("EPSG:"):
        code = int(dem.crs.split(":")[1])
    keys = [1, 1, 0, 2, 1024, 0, 1, 1, _KEY_RASTER, 0, 1, 1]
    if code:
        geographic = 4000 <= code < 5000
        keys[3] = 3
        keys[6] = 2 if geographic else 1
        keys += [_KEY_GEOG if geographic else _KEY_PROJ, 0, 1, code]
    extratags = [(_PIXEL_SCALE, "d", 3, (sx, sy, 0.0), False),
                 (_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, x0, y0, 0.0), False),
                 (_GEOKEYS, "H", len(keys), tuple(keys), False),
                 (_NODATA, "s", 0, f"{nodata:g}", False)]
    H = np.where(np.isfinite(dem.heights), dem.heights, nodata).astype(np.float32)
    with atomic_write(path, "wb") as fh:
        tifffile.imwrite(fh, H, extratags=extratags)
