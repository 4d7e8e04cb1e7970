"""System calibration (lever arm, boresight, exposure delay of `dgcal mount`) in the conventions of the programs
that apply it: Metashape's GPS/INS offset, Applanix POSPac MMS, NovAtel Inertial Explorer, Pix4D.

dgcal's own convention (docs/conventions.md): lever arm `l_b` = IMU origin -> camera perspective centre in the
body frame (FRD), m; boresight `R_cam_to_body` (CV camera axes x right, y down, z forward); delay = t_exposure -
t_event. Every export writes the values with the frame they are in; `read_calibration_export` reads any of the
files back into dgcal's convention (round trip exact to the printed digits: 1e-9 m, 1e-10 deg).

- POSPac MMS (Applanix): "reference to sensor" lever arm in the IMU/vehicle frame x forward, y right, z down
  (the same as dgcal's FRD); the sensor frame of a nominal nadir camera is aligned with it: x = top of the image
  (-y_cv), y = right (x_cv), z = viewing direction (z_cv); boresight angles (tx, ty, tz) = roll, pitch, heading
  (Z-Y-X) of the sensor frame in the vehicle frame: R_sensor_to_vehicle = Rz(tz) Ry(ty) Rx(tx) (deg and arc
  minutes), Applanix's mounting angles (POS MV V4 User Guide sec. 2-49/2-50: clockwise = +z, bow up = +y, port
  down = -x).
- Inertial Explorer (NovAtel Waypoint): vehicle frame x right, y forward, z up (RFU, IE's body frame, attitude
  Rz(-heading) Rx(pitch) Ry(roll)): lever arm IMU -> camera in it. IE's Boresight Settings > Axes selects the
  image system; its default, the conventional frame, is x forward, y left, z up. This file assumes instead the
  image system x right, y forward (image top), z up: the camera's photogrammetric axes (x right, y image top,
  z back) of a nadir camera with the image top forward; choose that Axes setting in IE. Boresight (rx, ry, rz)
  with R_camera_to_vehicle = Rz(rz) Ry(ry) Rx(rx) (deg), zero for the nominal mount. IE's boresight equations
  (Waypoint manual, appendix Boresight equations) were not available as text: check the angles once against IE's
  Solve Boresight on the calibration flight.
- Metashape (Reference settings / Camera Calibration > GPS/INS Offset): antenna offset = the position reference
  point (GNSS antenna, or the IMU when an IMU trajectory is imported) relative to the camera centre in the
  camera frame (x right, y down, z forward), m; camera orientation offset (yaw, pitch, roll) = the camera's
  Metashape yaw/pitch/roll on a level platform heading north: R_cam_to_body = R_ENU_TO_NED ypr2mat(yaw, pitch,
  roll) diag(1, -1, -1) with Metashape's ypr2mat = Rz(-yaw) Rx(pitch) Ry(roll) (x right, y forward, z up), deg:
  yaw +90 turns the image top to the right (clockwise, as a heading), pitch +90 looks forward, roll is right
  wing down; the reference rotation angles must be imported as yaw/pitch/roll.
- Pix4D (camera rig relatives / Image Properties Editor "lever arm"): the antenna or IMU relative to the camera
  in the camera frame (x right, y down, z forward) as Metashape, boresight as the PATB omega/phi/kappa of the
  photogrammetric camera (x right, y up, z back) in the body FRD frame: R_photo_to_body = Rx(om) Ry(ph) Rz(ka).
These conventions follow the programs' manuals as dgcal reads them; they are checked by round trips here, not
against files written by those programs (none is public).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dgcal.calib.mounting.common import MountingResult
from dgcal.fields.errors import InputError
from dgcal.fields.frames import R_CAM_TO_BODY_NADIR, R_CV_TO_PHOTO, R_ENU_TO_NED
from dgcal.fields.io import validate
from dgcal.fields.io.csv_tables import atomic_write
from dgcal.fields.io.text_files import read_text

CALIBRATION_FORMATS = ("metashape", "pospac", "inertial-explorer", "pix4d")
ARCMIN_PER_DEG = 60.0
R_FRD_TO_RFU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # vehicle FRD -> IE's RFU
R_CV_TO_APPLANIX = R_CAM_TO_BODY_NADIR        # CV camera -> POSPac sensor frame (x top of image, y right, z view)
R_CV_TO_IE = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])   # CV -> x right, y top, z back


def _zyx(R: np.ndarray) -> np.ndarray:
    """(rx, ry, rz) deg with R = Rz(rz) Ry(ry) Rx(rx)."""
    z, y, x = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)
    return np.array([x, y, z])


def _R_zyx(a) -> np.ndarray:
    """Rz(a[2]) Ry(a[1]) Rx(a[0]) from degrees."""
    return Rotation.from_euler("ZYX", [a[2], a[1], a[0]], degrees=True).as_matrix()


def metashape_ypr_offset(R_cam_to_body: np.ndarray) -> np.ndarray:
    """Metashape camera orientation offset (yaw, pitch, roll deg): R_cam_to_body = R_ENU_TO_NED Rz(-yaw) Rx(pitch)
    Ry(roll) diag(1, -1, -1), Metashape's ypr2mat in a level north-facing body (x right, y forward, z up)."""
    R_ypr = R_ENU_TO_NED.T @ np.asarray(R_cam_to_body, float) @ R_CV_TO_PHOTO
    mz, x, y = Rotation.from_matrix(R_ypr).as_euler("ZXY", degrees=True)
    return np.array([-mz, x, y])


def R_cam_to_body_from_metashape_ypr(ypr) -> np.ndarray:
    """Inverse of `metashape_ypr_offset`."""
    yaw, pitch, roll = (float(v) for v in ypr)
    return R_ENU_TO_NED @ Rotation.from_euler("ZXY", [-yaw, pitch, roll], degrees=True).as_matrix() @ R_CV_TO_PHOTO


def calibration_values(mount: MountingResult, fmt: str, reference_lever_arm_m=(0.0, 0.0, 0.0)) -> dict:
    """The numbers `fmt` asks for, in its frames (see the module docstring); `reference_lever_arm_m` = IMU ->
    the position reference point (GNSS antenna) in body FRD, m, for the camera-frame offsets of Metashape/Pix4D."""
    l_b = np.asarray(mount.lever_arm_m, float)
    R_cam_to_body = np.asarray(mount.R_cam_to_body, float)
    ref = np.asarray(reference_lever_arm_m, float)
    out = {"format": fmt, "delay_s": float(mount.delay_s), "method": mount.method}
    if fmt == "pospac":
        b = _zyx(R_cam_to_body @ R_CV_TO_APPLANIX.T)
        out.update(lever_arm_xyz_m=l_b.tolist(), frame="vehicle x forward, y right, z down",
                   boresight_tx_ty_tz_deg=b.tolist(), boresight_tx_ty_tz_arcmin=(b * ARCMIN_PER_DEG).tolist())
    elif fmt == "inertial-explorer":
        R_ie_cam_to_rfu = R_FRD_TO_RFU @ R_cam_to_body @ R_CV_TO_IE.T
        out.update(lever_arm_xyz_m=(R_FRD_TO_RFU @ l_b).tolist(), frame="vehicle x right, y forward, z up",
                   image_axes_setting="x right, y forward, z up (not IE's default conventional frame x forward, "
                                      "y left, z up)",
                   boresight_rx_ry_rz_deg=_zyx(R_ie_cam_to_rfu).tolist())
    elif fmt == "metashape":
        out.update(antenna_offset_xyz_m=(R_cam_to_body.T @ (ref - l_b)).tolist(),
                   frame="camera x right, y down, z forward",
                   camera_orientation_offset_yaw_pitch_roll_deg=metashape_ypr_offset(R_cam_to_body).tolist(),
                   reference_lever_arm_body_m=ref.tolist())
    elif fmt == "pix4d":
        R_photo_to_body = R_cam_to_body @ R_CV_TO_PHOTO.T
        opk = Rotation.from_matrix(R_photo_to_body).as_euler("XYZ", degrees=True)
        out.update(lever_arm_xyz_m=(R_cam_to_body.T @ (ref - l_b)).tolist(), frame="camera x right, y down, z forward",
                   boresight_omega_phi_kappa_deg=opk.tolist(), reference_lever_arm_body_m=ref.tolist())
    else:
        raise InputError(f"unknown calibration format {fmt!r} (one of {', '.join(CALIBRATION_FORMATS)})",
                         field="calibration_formats")
    return out


FILE_NAMES = {"metashape": "metashape_gps_ins_offset.txt", "pospac": "pospac_lever_arm_boresight.txt",
              "inertial-explorer": "inertial_explorer_lever_arm_boresight.txt",
              "pix4d": "pix4d_lever_arm_boresight.txt"}


def write_calibration_export(path: Path, mount: MountingResult, fmt: str, reference_lever_arm_m=(0, 0, 0)) -> dict:
    """Write one program's values as `key: numbers` lines under a `#` header naming the frames; returns them."""
    v = calibration_values(mount, fmt, reference_lever_arm_m)
    doc = __doc__.split("\n- ")
    head = next((d for d in doc if d.lower().startswith({"pospac": "pospac", "inertial-explorer": "inertial",
                                                          "metashape": "metashape", "pix4d": "pix4d"}[fmt])), "")
    with atomic_write(path) as fh:
        fh.write(f"# dgcal mounting ({mount.method}) for {fmt}\n")
        for ln in " ".join(head.split()).split(". "):
            fh.write(f"# {ln.strip().rstrip('.')}\n")
        for k, val in v.items():
            if isinstance(val, list):
                fh.write(f"{k}: " + " ".join(f"{x:.10f}" for x in val) + "\n")
            elif isinstance(val, float):
                fh.write(f"{k}: {val:.9f}\n")
            else:
                fh.write(f"{k}: {val}\n")
    return v


def write_calibration_exports(out_dir: Path, mount: MountingResult, formats=CALIBRATION_FORMATS,
                              reference_lever_arm_m=(0.0, 0.0, 0.0)) -> dict:
    """Every requested program's file under `out_dir` plus `calibration_exports.json`; returns {format: path}."""
    out_dir = Path(out_dir)
    paths, values = {}, {}
    for f in formats:
        p = out_dir / FILE_NAMES.get(f, "x")
        values[f] = write_calibration_export(p, mount, f, reference_lever_arm_m)
        paths[f] = p
    with atomic_write(out_dir / "calibration_exports.json") as fh:
        json.dump(values, fh, indent=2)
    return paths


def read_calibration_export(path: Path) -> tuple[str, np.ndarray, np.ndarray, float]:
    """(format, lever arm IMU -> camera body FRD m, R_cam_to_body, delay s) from a file of
    `write_calibration_export` (for Metashape/Pix4D the file's reference_lever_arm_body_m is used)."""
    path = Path(path)
    text = read_text(path)
    kv: dict[str, str] = {}
    lines: dict[str, int] = {}
    for n, ln in enumerate(text.splitlines(), 1):
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        m = re.match(r"^\s*([\w-]+)\s*:\s*(.*)$", ln)
        if m is None:
            raise InputError("expected 'key: values'", path, n)
        kv[m.group(1)], lines[m.group(1)] = m.group(2).strip(), n

    def vec(key: str, n: int = 3) -> np.ndarray:
        if key not in kv:
            raise InputError("missing", path, field=key)
        parts = kv[key].split()
        if len(parts) != n:
            raise InputError(f"expected {n} finite numbers", path, lines[key], key)
        lim = validate.MAX_DELAY_S if key == "delay_s" else validate.MAX_LEVER_ARM_M if "lever" in key or \
            "offset_xyz" in key else validate.MAX_ANGLE_DEG
        return np.array([validate.in_range(x, -lim, lim, path, lines[key], key) for x in parts])
    fmt = kv.get("format", "")
    delay = float(vec("delay_s", 1)[0])
    if fmt == "pospac":
        return fmt, vec("lever_arm_xyz_m"), _R_zyx(vec("boresight_tx_ty_tz_deg")) @ R_CV_TO_APPLANIX, delay
    if fmt == "inertial-explorer":
        R_cam_to_body = R_FRD_TO_RFU.T @ _R_zyx(vec("boresight_rx_ry_rz_deg")) @ R_CV_TO_IE
        return fmt, R_FRD_TO_RFU.T @ vec("lever_arm_xyz_m"), R_cam_to_body, delay
    if fmt == "metashape":
        R_cam_to_body = R_cam_to_body_from_metashape_ypr(vec("camera_orientation_offset_yaw_pitch_roll_deg"))
        lever = vec("reference_lever_arm_body_m") - R_cam_to_body @ vec("antenna_offset_xyz_m")
        return fmt, lever, R_cam_to_body, delay
    if fmt == "pix4d":
        R_photo_to_body = Rotation.from_euler("XYZ", vec("boresight_omega_phi_kappa_deg"), degrees=True).as_matrix()
        R_cam_to_body = R_photo_to_body @ R_CV_TO_PHOTO
        return fmt, vec("reference_lever_arm_body_m") - R_cam_to_body @ vec("lever_arm_xyz_m"), R_cam_to_body, delay
    raise InputError(f"unknown format {fmt!r}", path, lines.get("format"), "format")
