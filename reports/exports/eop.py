"""EOP exports (and readers, for round trips) to mapping software: COLMAP text model, Pix4D external
orientation file, Metashape OPK CSV, ODM `geo.txt`, and dgcal's eop.csv.

Angles: Pix4D, Metashape and ODM files carry PATB omega/phi/kappa in degrees exactly as dgcal's EOP file
(M = Rx(omega) Ry(phi) Rz(kappa) from photo axes x right, y up, z back to the map CRS axes).
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
from dgcal.fields.crs import LocalENU, MapGrid, parse_crs
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, write_eop
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
        R_w2c, t = poses.R_world_to_cam[k], poses.t_cam[k]
        q = Rotation.from_matrix(R_w2c).as_quat()  # x, y, z, w
        lines.append(" ".join([str(k + 1)] + [repr(float(v)) for v in (q[3], q[0], q[1], q[2])]
                              + [repr(float(v)) for v in t] + ["1", str(name)]))
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
    try:
        g = json.loads((in_dir / "georef.json").read_text())
        lat0, lon0, h0 = g["origin_lat_lon_h"]
        grid = MapGrid(g["map_crs"])
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"cannot read georef.json ({exc})", in_dir / "georef.json") from None
    world = World(grid, LocalENU(lat0, lon0, h0))
    names, R, t = [], [], []
    path = in_dir / "images.txt"
    rows = [(n, ln) for n, ln in enumerate(path.read_text().splitlines(), 1) if not ln.startswith("#")]
    for n, ln in rows[0::2]:
        tok = ln.split()
        if len(tok) < 10:
            raise InputError("an image line needs IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", path, n)
        try:
            qw, qx, qy, qz, tx, ty, tz = (float(v) for v in tok[1:8])
        except ValueError:
            raise InputError("quaternion and translation must be numbers", path, n, "QW") from None
        names.append(" ".join(tok[9:]))
        R.append(Rotation.from_quat([qx, qy, qz, qw]).as_matrix())
        t.append([tx, ty, tz])
    xyz, opk, _ = world.poses_to_eop(Poses.from_R_t(np.array(R), np.array(t)))
    return EOP(np.array(names, dtype=object), xyz, opk), grid


# --- Pix4D, Metashape, ODM -----------------------------------------------------------------------
def write_pix4d(path: Path, eop: EOP) -> None:
    """Pix4D external orientation file (`imageName X Y Z omega phi kappa`, space separated, degrees)."""
    with atomic_write(path) as fh:
        fh.write("imageName X Y Z omega phi kappa\n")
        for i in range(len(eop.image)):
            fh.write(f"{eop.image[i]} " + " ".join(f"{v:.8f}" for v in eop.xyz[i]) + " "
                     + " ".join(f"{v:.10f}" for v in eop.opk[i]) + "\n")


def _read_rows(path: Path, sep: str | None, skip: int, ncols: int, what: str):
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"cannot read {what} ({exc.strerror})", path) from None
    names, vals = [], []
    for n, ln in enumerate(text.splitlines(), 1):
        if n <= skip or not ln.strip() or ln.lstrip().startswith("#"):
            continue
        tok = [t.strip() for t in (ln.split(sep) if sep else ln.split())]
        if len(tok) < ncols + 1:
            raise InputError(f"a {what} line needs an image name and {ncols} numbers", path, n)
        try:
            vals.append([float(v) for v in tok[1:ncols + 1]])
        except ValueError:
            raise InputError("not a number", path, n, "X") from None
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


def write_odm_geo(path: Path, eop: EOP, grid: MapGrid) -> None:
    """ODM geo.txt: the CRS on the first line, then `image x y z omega phi kappa [horz_acc vert_acc]`."""
    epsg = grid.crs.to_epsg()
    head = f"EPSG:{epsg}" if epsg else grid.crs.to_proj4()
    has = eop.sigma is not None
    with atomic_write(path) as fh:
        fh.write(head + "\n")
        for i in range(len(eop.image)):
            row = [str(eop.image[i])] + [f"{v:.8f}" for v in eop.xyz[i]] + [f"{v:.10f}" for v in eop.opk[i]]
            if has:
                row += [f"{np.hypot(eop.sigma[i, 0], eop.sigma[i, 1]):.4f}", f"{eop.sigma[i, 2]:.4f}"]
            fh.write(" ".join(row) + "\n")


def read_odm_geo(path: Path) -> tuple[EOP, MapGrid]:
    """EOPs and the CRS from an ODM geo.txt."""
    path = Path(path)
    try:
        first = path.read_text().splitlines()[0].strip()
    except (OSError, IndexError):
        raise InputError("cannot read the CRS line of geo.txt", path, 1) from None
    crs = parse_crs(first, f"{path}:1")
    names, v = _read_rows(path, None, 1, 6, "geo.txt")
    return EOP(names, v[:, :3], v[:, 3:6]), MapGrid(crs)


def export_all(out_dir: Path, eop: EOP, grid: MapGrid, camera=None, formats=FORMATS, points_map=None,
               observations=None) -> dict:
    """Write the requested formats under `out_dir`; returns {format: path}."""
    out_dir = Path(out_dir)
    paths = {}
    for f in formats:
        if f == "colmap":
            if camera is None:
                raise InputError("the COLMAP export needs a camera (--camera)", field="--camera")
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
            raise InputError(f"unknown export format {f!r} (one of {', '.join(FORMATS)})", field="--formats")
    return paths


def export_formats(requested: tuple[str, ...] | None, have_camera: bool) -> list[str]:
    """The export formats to write: `requested` (lower-cased, checked), or every format when None, without
    COLMAP when there is no camera; an explicit COLMAP without a camera is an input error."""
    if requested is None:
        return [f for f in FORMATS if have_camera or f != "colmap"]
    formats = [f.strip().lower() for f in requested if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputError(f"unknown format {bad[0]!r} (one of {', '.join(FORMATS)})", field="--formats")
    if "colmap" in formats and not have_camera:
        raise InputError("the COLMAP export needs --camera", field="--camera")
    return formats


def write_dg_exports(out_dir: Path, flight, formats: tuple[str, ...] | None = None) -> dict:
    """`dgcal export`'s files: the DG EOPs of `flight` (dgcal.calib.dg.eop.DgFlight) in `formats` (see
    `export_formats`) under `out_dir`; returns {format: path}."""
    return export_all(out_dir, flight.eop, flight.grid, flight.camera,
                      export_formats(formats, flight.camera is not None))
