"""EOP exports (and readers, for round trips) to mapping software: COLMAP text model, Pix4D external
orientation file, Metashape OPK CSV, ODM `geo.txt`, and dgcal's eop.csv.

Angles: Pix4D and Metashape files carry PATB omega/phi/kappa in degrees exactly as dgcal's EOP file
(M = Rx(omega) Ry(phi) Rz(kappa) from photo axes x right, y up, z back to the map CRS axes), Pix4D's own
definition (support.pix4d.com art. 202559089) and Metashape's for its "Omega, Phi, Kappa" rotation angles; the
Pix4D header is Pix4D's own `imageName X Y Z Omega Phi Kappa`.
ODM geo.txt carries yaw, pitch, roll, which ODM turns into omega/phi/kappa with opendm/photo.py `compute_opk`
(copied here as `odm_opk_from_ypr`) and OpenSfM into the camera rotation in the local level frame
(opensfm geometry.rotation_from_opk: the PATB matrix, world East, North, Up). ODM's comments mean yaw 0 = image
top to north, pitch 0 = nadir, but `compute_opk` builds its "NED to world" matrix from the ECEF north vector and
ECEF (0, 0, -1), so the angles of that meaning come out as other omega/phi/kappa (for a level camera the yaw it
needs is the heading + the longitude + 90 deg, - 90 deg south of the equator).
`write_odm_geo` therefore writes the yaw/pitch/roll that ODM's own formula turns into the camera's true
omega/phi/kappa (solved per image by Newton's method, 1e-10 deg) in the local East/North/Up frame at the
camera (the EOP's grid angles turned by the meridian convergence); `read_odm_geo` reads them back the way
ODM does.
COLMAP: a map grid is not a Cartesian frame (scale factor, convergence), so the model is written in the
block's local ENU frame (`colmap/georef.json` names its origin and the map CRS); images.txt holds
world-to-camera quaternions (w, x, y, z) and translations of the CV camera frame, as COLMAP expects.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.camera.files import colmap_cameras_txt_string
from dgcal.fields.crs import LocalENU, MapGrid, geodetic_to_ecef, parse_crs
from dgcal.fields.frames import R_ENU_TO_NED, R_photo_to_map_from_opk, opk_from_R_photo_to_map
from dgcal.fields.io.gcp_files import odm_crs_to_pyproj
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.formats import EOP, write_eop
from dgcal.fields.io.text_files import read_text
from dgcal.fields.pose import Poses
from dgcal.fields.world import World

FORMATS = ("colmap", "pix4d", "metashape", "odm", "eop")


# --- COLMAP --------------------------------------------------------------------------------------
def write_colmap(out_dir: Path, eop: EOP, grid: MapGrid, camera, points_map: dict | None = None,
                 observations: list | None = None) -> World:
    """Write cameras.txt, images.txt, points3D.txt and georef.json (local ENU frame at the block centre).

    `points_map`: optional {id: map xyz}; `observations`: optional [(image, id, x, y)] linking them."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    world = World.at_map_points(grid, eop.xyz)
    poses = world.eop_to_poses(eop.xyz, eop.opk)
    cams_txt, err = colmap_cameras_txt_string(camera, 1)
    pid = {}
    pts_world = None
    if points_map:
        keys = list(points_map)
        pid = {k: j + 1 for j, k in enumerate(keys)}
        pts_world = world.to_world(np.array([points_map[k] for k in keys], float))
    obs_by_image: dict[str, list] = {}
    tracks: dict[int, list] = {}
    for im, i, x, y in (observations or []):
        if str(i) in pid:
            lst = obs_by_image.setdefault(str(im), [])
            lst.append((x, y, pid[str(i)]))
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {len(eop.image)}"]
    for k, name in enumerate(eop.image):
        R_world_to_cam, t_cam = poses.R_world_to_cam[k], poses.t_cam[k]
        q = Rotation.from_matrix(R_world_to_cam).as_quat()  # x, y, z, w
        lines.append(" ".join([str(k + 1)] + [repr(float(v)) for v in (q[3], q[0], q[1], q[2])]
                              + [repr(float(v)) for v in t_cam] + ["1", str(name)]))
        p2d = obs_by_image.get(str(name), [])
        # COLMAP pixels have their origin at the top-left corner of the top-left pixel
        lines.append(" ".join(f"{float(x) + 0.5!r} {float(y) + 0.5!r} {p}" for x, y, p in p2d))
        for j, (_, _, p) in enumerate(p2d):
            tracks.setdefault(p, []).append((k + 1, j))
    pts_lines = ["# 3D point list with one line of data per point:",
                 "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    if pts_world is not None:
        for k, key in enumerate(pid):
            p = pid[key]
            tr = tracks.get(p, [])
            if not tr:
                continue  # COLMAP cannot load a point without a track
            pts_lines.append(" ".join([str(p)] + [repr(float(v)) for v in pts_world[k]] + ["255", "0", "0", "0"]
                                      + [f"{a} {b}" for a, b in tr]))
    with atomic_write(out_dir / "cameras.txt") as fh:
        fh.write(cams_txt)
    with atomic_write(out_dir / "images.txt") as fh:
        fh.write("\n".join(lines) + "\n")
    with atomic_write(out_dir / "points3D.txt") as fh:
        fh.write("\n".join(pts_lines) + "\n")
    with atomic_write(out_dir / "georef.json") as fh:
        json.dump({"frame": "local ENU (East, North, Up, metres) tangent at the origin",
                   "origin_lat_lon_h": [world.enu.lat0, world.enu.lon0, world.enu.h0],
                   "map_crs": grid.crs.to_string(), "camera_conversion_max_error_px": float(err),
                   "point_ids": {str(k): v for k, v in pid.items()}}, fh, indent=2)
    return world


def read_colmap(in_dir: Path) -> tuple[EOP, MapGrid]:
    """EOPs in the map CRS from a COLMAP text model written by `write_colmap` (georef.json needed)."""
    in_dir = Path(in_dir)
    gpath = in_dir / "georef.json"
    try:
        g = json.loads(read_text(gpath))
        lat0, lon0, h0 = g["origin_lat_lon_h"]
        crs = g["map_crs"]
    except (KeyError, TypeError, ValueError, RecursionError) as exc:
        raise InputError(f"cannot read georef.json ({type(exc).__name__}: {' '.join(str(exc).split())[:80]})",
                         gpath) from None
    lat0 = validate.in_range(lat0, -90.0, 90.0, gpath, None, "origin_lat_lon_h")
    lon0 = validate.in_range(lon0, -360.0, 360.0, gpath, None, "origin_lat_lon_h")
    h0 = validate.in_range(h0, -validate.MAX_HEIGHT_M, validate.MAX_HEIGHT_M, gpath, None, "origin_lat_lon_h")
    if not isinstance(crs, str):
        raise InputError("must be a CRS text", gpath, field="map_crs")
    grid = MapGrid(parse_crs(crs, str(gpath)))
    world = World(grid, LocalENU(lat0, lon0, h0))
    names, R_world_to_cam, t_cam = [], [], []
    path = in_dir / "images.txt"
    rows = [(n, ln) for n, ln in enumerate(read_text(path).splitlines(), 1) if not ln.startswith("#")]
    for n, ln in rows[0::2]:
        tok = ln.split()
        if len(tok) < 10:
            raise InputError("an image line needs IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", path, n)
        qw, qx, qy, qz = (validate.in_range(v, -1e3, 1e3, path, n, k) for v, k in zip(tok[1:5], ("QW", "QX", "QY",
                                                                                                  "QZ")))
        tx, ty, tz = (validate.in_range(v, -validate.MAX_COORDINATE_M, validate.MAX_COORDINATE_M, path, n, k)
                      for v, k in zip(tok[5:8], ("TX", "TY", "TZ")))
        if not 0.5 < np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz) < 2.0:
            raise InputError("QW QX QY QZ is not a unit quaternion", path, n, "QW")
        names.append(" ".join(tok[9:]))
        R_world_to_cam.append(Rotation.from_quat([qx, qy, qz, qw]).as_matrix())
        t_cam.append([tx, ty, tz])
    xyz, opk, _ = world.poses_to_eop(Poses.from_R_t(np.array(R_world_to_cam), np.array(t_cam)))
    return EOP(np.array(names, dtype=object), xyz, opk), grid


# --- Pix4D, Metashape, ODM -----------------------------------------------------------------------
PIX4D_HEADER = "imageName X Y Z Omega Phi Kappa"   # as Pix4D writes its calibrated_external_camera_parameters.txt


def write_pix4d(path: Path, eop: EOP) -> None:
    """Pix4D external orientation file (`imageName X Y Z Omega Phi Kappa`, space separated, degrees)."""
    with atomic_write(path) as fh:
        fh.write(PIX4D_HEADER + "\n")
        for i in range(len(eop.image)):
            fh.write(f"{eop.image[i]} " + " ".join(f"{v:.8f}" for v in eop.xyz[i]) + " "
                     + " ".join(f"{v:.10f}" for v in eop.opk[i]) + "\n")


_ROW_FIELDS = ("X", "Y", "Z", "omega", "phi", "kappa", "sX", "sY", "sZ", "somega", "sphi", "skappa")
_ROW_LIMITS = (validate.MAX_COORDINATE_M,) * 3 + (validate.MAX_ANGLE_DEG,) * 3 + (validate.MAX_COORDINATE_M,) * 6


def _read_rows(path: Path, sep: str | None, skip: int, ncols: int, what: str):
    path = Path(path)
    text = read_text(path)
    names, vals = [], []
    for n, ln in enumerate(text.splitlines(), 1):
        if n <= skip or not ln.strip() or ln.lstrip().startswith("#"):
            continue
        tok = [t.strip() for t in (ln.split(sep) if sep else ln.split())]
        if len(tok) < ncols + 1:
            raise InputError(f"a {what} line needs an image name and {ncols} numbers", path, n)
        row = [validate.in_range(v, -lim, lim, path, n, k)
               for v, k, lim in zip(tok[1:ncols + 1], _ROW_FIELDS, _ROW_LIMITS)]
        vals.append(row)
        names.append(tok[0])
    v = np.array(vals, float).reshape(-1, ncols)
    return np.array(names, dtype=object), v


def read_pix4d(path: Path) -> EOP:
    """EOPs from a Pix4D external orientation file."""
    names, v = _read_rows(path, None, 1, 6, "Pix4D orientation")
    return EOP(names, v[:, :3], v[:, 3:6])


def write_metashape(path: Path, eop: EOP) -> None:
    """Metashape reference CSV with omega/phi/kappa (Label,X,Y,Z,Omega,Phi,Kappa[,SX,SY,SZ,SOmega,SPhi,SKappa])."""
    has = eop.sigma is not None
    with atomic_write(path) as fh:
        fh.write("#Label,X,Y,Z,Omega,Phi,Kappa" + (",SX,SY,SZ,SOmega,SPhi,SKappa" if has else "") + "\n")
        for i in range(len(eop.image)):
            row = [str(eop.image[i])] + [f"{v:.8f}" for v in eop.xyz[i]] + [f"{v:.10f}" for v in eop.opk[i]]
            if has:
                row += [f"{v:.6f}" for v in eop.sigma[i, :3]] + [f"{v:.8f}" for v in eop.sigma[i, 3:]]
            fh.write(",".join(row) + "\n")


def read_metashape(path: Path) -> EOP:
    """EOPs from a Metashape OPK reference CSV written by `write_metashape`."""
    names, v = _read_rows(path, ",", 0, 6, "Metashape reference")
    return EOP(names, v[:, :3], v[:, 3:6])


_CBB = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # ODM: image axes -> body (swap X/Y, flip Z)


def _odm_cen(lat_deg: np.ndarray, lon_deg: np.ndarray, alt: np.ndarray) -> np.ndarray:
    """ODM's 'NED to world' matrices (N,3,3): columns the ECEF north vector (a 1e-7 deg latitude step),
    (0,0,-1) x north, and (0,0,-1), exactly as opendm/photo.py compute_opk forms them."""
    d = 1e-7
    xnp = geodetic_to_ecef(lat_deg + d, lon_deg, alt) - geodetic_to_ecef(lat_deg - d, lon_deg, alt)
    xnp = xnp / np.linalg.norm(xnp, axis=-1, keepdims=True)
    znp = np.broadcast_to(np.array([0.0, 0.0, -1.0]), xnp.shape)
    ynp = np.cross(znp, xnp)
    return np.stack([xnp, ynp, znp], axis=-1)


def _odm_cnb(ypr_deg: np.ndarray) -> np.ndarray:
    """ODM's yaw/pitch/roll matrix Rz(yaw) Ry(pitch) Rx(roll), (N,3,3)."""
    y, p, r = np.radians(ypr_deg).T
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    return np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                     np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], axis=-2)


def odm_opk_from_ypr(lat_deg, lon_deg, alt_m, ypr_deg) -> np.ndarray:
    """Omega, phi, kappa (deg) that ODM/OpenSfM compute from geo.txt yaw/pitch/roll (deg) at a camera's
    latitude, longitude (deg) and altitude (opendm/photo.py compute_opk, vectorised); (N,3)."""
    lat, lon, alt = (np.atleast_1d(np.asarray(v, float)) for v in (lat_deg, lon_deg, alt_m))
    ceb = _odm_cen(lat, lon, alt) @ _odm_cnb(np.atleast_2d(ypr_deg)) @ _CBB
    return np.degrees(np.column_stack([np.arctan2(-ceb[:, 1, 2], ceb[:, 2, 2]),
                                       np.arcsin(np.clip(ceb[:, 0, 2], -1.0, 1.0)),
                                       np.arctan2(-ceb[:, 0, 1], ceb[:, 0, 0])]))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


def odm_ypr_for_opk(lat_deg, lon_deg, alt_m, opk_enu_deg) -> np.ndarray:
    """The geo.txt yaw/pitch/roll (deg) that ODM's `odm_opk_from_ypr` turns into `opk_enu_deg` (PATB, local
    East/North/Up at the camera); Newton's method from the attitude a true NED-to-ENU matrix would give."""
    lat, lon, alt = (np.atleast_1d(np.asarray(v, float)) for v in (lat_deg, lon_deg, alt_m))
    target = np.atleast_2d(np.asarray(opk_enu_deg, float))
    M = R_photo_to_map_from_opk(target[:, 0], target[:, 1], target[:, 2]).reshape(-1, 3, 3)
    cnb0 = R_ENU_TO_NED @ M @ _CBB.T
    ypr = np.column_stack([np.degrees(np.arctan2(cnb0[:, 1, 0], cnb0[:, 0, 0])),
                           np.degrees(-np.arcsin(np.clip(cnb0[:, 2, 0], -1, 1))),
                           np.degrees(np.arctan2(cnb0[:, 2, 1], cnb0[:, 2, 2]))])
    h = 1e-6
    for _ in range(30):
        f = _wrap(odm_opk_from_ypr(lat, lon, alt, ypr) - target)
        if np.max(np.abs(f)) < 1e-11:
            break
        J = np.empty((len(ypr), 3, 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = h
            J[:, :, j] = _wrap(odm_opk_from_ypr(lat, lon, alt, ypr + d) - odm_opk_from_ypr(lat, lon, alt, ypr - d)) \
                / (2 * h)
        ypr = ypr - np.linalg.solve(J, f[:, :, None])[:, :, 0]
    f = _wrap(odm_opk_from_ypr(lat, lon, alt, ypr) - target)
    if np.max(np.abs(f)) > 1e-8:
        k = int(np.argmax(np.max(np.abs(f), axis=1)))
        raise InputError(f"no ODM yaw/pitch/roll gives omega/phi/kappa {target[k].round(6).tolist()} at latitude "
                         f"{lat[k]:.4f} (ODM's conversion degenerates near the equator)", field="formats")
    ypr[:, 0] = np.mod(ypr[:, 0], 360.0)
    return ypr


def _grid_opk_to_enu(grid: MapGrid, xyz: np.ndarray, opk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(geodetic lat, lon, h (N,3); omega/phi/kappa in the local ENU frame at each camera (N,3), deg)."""
    geo = grid.to_geodetic(xyz)
    M_grid = R_photo_to_map_from_opk(opk[:, 0], opk[:, 1], opk[:, 2]).reshape(-1, 3, 3)
    R_enu_to_grid = grid.R_enu_to_grid_at(xyz).reshape(-1, 3, 3)
    return geo, opk_from_R_photo_to_map(np.swapaxes(R_enu_to_grid, 1, 2) @ M_grid).reshape(-1, 3)


def write_odm_geo(path: Path, eop: EOP, grid: MapGrid) -> None:
    """ODM geo.txt: the CRS on the first line, then `image x y z yaw pitch roll [horz_acc vert_acc]` in ODM's
    convention (see the module docstring: the yaw/pitch/roll ODM turns into the EOP's camera rotation)."""
    epsg = grid.crs.to_epsg()
    head = f"EPSG:{epsg}" if epsg else grid.crs.to_proj4()
    has = eop.sigma is not None
    # the coordinates as written: ODM differences a 1e-7 deg latitude step, so its angles change by ~1e-6 deg
    # with the last digits of the position; solve at the very coordinates ODM will read
    xyz = np.array([[float(f"{v:.8f}") for v in row] for row in np.asarray(eop.xyz, float)]).reshape(-1, 3)
    geo, opk_enu = _grid_opk_to_enu(grid, xyz, np.asarray(eop.opk, float))
    ypr = odm_ypr_for_opk(geo[:, 0], geo[:, 1], geo[:, 2], opk_enu) if len(eop.image) else np.zeros((0, 3))
    with atomic_write(path) as fh:
        fh.write(head + "\n")
        for i in range(len(eop.image)):
            row = [str(eop.image[i])] + [f"{v:.8f}" for v in eop.xyz[i]] + [f"{v:.10f}" for v in ypr[i]]
            if has:
                row += [f"{np.hypot(eop.sigma[i, 0], eop.sigma[i, 1]):.4f}", f"{eop.sigma[i, 2]:.4f}"]
            fh.write(" ".join(row) + "\n")


def read_odm_geo(path: Path) -> tuple[EOP, MapGrid]:
    """EOPs (grid omega/phi/kappa) and the CRS from an ODM geo.txt, its yaw/pitch/roll read the way ODM reads them
    (`odm_opk_from_ypr` in the local East/North/Up frame, turned to grid axes by the meridian convergence)."""
    path = Path(path)
    lines = read_text(path).splitlines()
    if not lines:
        raise InputError("empty geo.txt: the first line must be the CRS", path, 1)
    first = lines[0].strip()
    crs = parse_crs(odm_crs_to_pyproj(first), f"{path}:1")
    names, v = _read_rows(path, None, 1, 6, "geo.txt")
    grid = MapGrid(crs)
    if not len(names):
        return EOP(names, v[:, :3], v[:, 3:6]), grid
    geo = grid.to_geodetic(v[:, :3])
    if not np.all(np.isfinite(geo)):
        k = int(np.flatnonzero(~np.all(np.isfinite(geo), axis=1))[0])
        raise InputError(f"coordinates {v[k, :3].tolist()} are not valid in {first}", path, field="x")
    opk_enu = odm_opk_from_ypr(geo[:, 0], geo[:, 1], geo[:, 2], v[:, 3:6])
    M_enu = R_photo_to_map_from_opk(opk_enu[:, 0], opk_enu[:, 1], opk_enu[:, 2]).reshape(-1, 3, 3)
    opk = opk_from_R_photo_to_map(grid.R_enu_to_grid_at(v[:, :3]).reshape(-1, 3, 3) @ M_enu).reshape(-1, 3)
    return EOP(names, v[:, :3], opk), grid


def export_all(out_dir: Path, eop: EOP, grid: MapGrid, camera=None, formats=FORMATS, points_map=None,
               observations=None) -> dict:
    """Write the requested formats under `out_dir`; returns {format: path}."""
    out_dir = Path(out_dir)
    paths = {}
    for f in formats:
        if f == "colmap":
            if camera is None:
                raise InputError("the COLMAP export needs a camera (--camera)", field="camera")
            write_colmap(out_dir / "colmap", eop, grid, camera, points_map, observations)
            paths[f] = out_dir / "colmap"
        elif f == "pix4d":
            write_pix4d(out_dir / "pix4d_external_orientation.txt", eop)
            paths[f] = out_dir / "pix4d_external_orientation.txt"
        elif f == "metashape":
            write_metashape(out_dir / "metashape_opk.csv", eop)
            paths[f] = out_dir / "metashape_opk.csv"
        elif f == "odm":
            write_odm_geo(out_dir / "geo.txt", eop, grid)
            paths[f] = out_dir / "geo.txt"
        elif f == "eop":
            write_eop(out_dir / "eop.csv", eop)
            paths[f] = out_dir / "eop.csv"
        else:
            raise InputError(f"unknown export format {f!r} (one of {', '.join(FORMATS)})", field="formats")
    return paths


def export_formats(requested: tuple[str, ...] | None, have_camera: bool) -> list[str]:
    """The export formats to write: `requested` (lower-cased, checked), or every format when None, without
    COLMAP when there is no camera; an explicit COLMAP without a camera is an input error."""
    if requested is None:
        return [f for f in FORMATS if have_camera or f != "colmap"]
    formats = [f.strip().lower() for f in requested if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputError(f"unknown format {bad[0]!r} (one of {', '.join(FORMATS)})", field="formats")
    if "colmap" in formats and not have_camera:
        raise InputError("the COLMAP export needs --camera", field="camera")
    return formats


def write_dg_exports(out_dir: Path, flight, formats: tuple[str, ...] | None = None) -> dict:
    """`dgcal export`'s files: the DG EOPs of `flight` (dgcal.calib.dg.eop.DgFlight) in `formats` (see
    `export_formats`) under `out_dir`; returns {format: path}."""
    return export_all(out_dir, flight.eop, flight.grid, flight.camera,
                      export_formats(formats, flight.camera is not None))
