"""dgcal's public Python API: the entry points a user or a script calls, independent of where modules live.

    from dgcal.api import read_camera, calibrate_camera, triangulate, run_pos, calibrate_mounting, dg_eop

Every name here is re-exported by the package itself (`from dgcal import triangulate` works and imports
lazily). Names are added here, never moved or removed; the modules behind them may change.
Frames and units: docs/conventions.md.
"""
from __future__ import annotations

from dgcal.bundle.triangulation import TriangulationOptions, TriangulationResult, triangulate
from dgcal.calib.camera.files import read_camera, read_camera_with_error, write_camera
from dgcal.calib.camera.models import CameraModel, Fraser7, OpenCV8, model_class
from dgcal.calib.dg.accuracy import check_points_dg
from dgcal.calib.dg.eop import dg_eop
from dgcal.calib.dg.single_image import georeference
from dgcal.calib.mounting.common import MountingResult, read_mounting_json
from dgcal.calib.mounting.methods import METHODS, calibrate_mounting
from dgcal.calib.selfcal.calibration import CameraCalibration, calibrate_camera
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import (EOP, Events, Measurements, Points, Trajectory, read_eop, read_events,
                                     read_measurements, read_points, read_trajectory, write_eop, write_events,
                                     write_measurements, write_points, write_trajectory)
from dgcal.fields.io.gcp_files import read_any_measurements, read_any_points
from dgcal.fields.pose import Poses
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.spp import SppOptions, spp
from dgcal.pos.events import read_any_events, read_mrk, read_utc_events
from dgcal.pos.gnss.solution_files import (GnssSolution, read_gnss_solution, read_nmea_gga, read_rtklib_pos,
                                           write_rtklib_pos)
from dgcal.pos.ins.error_model import read_imu_datasheet
from dgcal.pos.ins.imu_data import ImuData, read_imu_csv, read_imu_text, read_kf_gins
from dgcal.pos.ins.imu_formats import ImuFormat, imu_format, read_imu
from dgcal.pos.ins.sbet import read_any_trajectory, read_sbet, write_sbet_files
from dgcal.pos.ins.time_tags import read_time_tag
from dgcal.pos.ins.ulog import read_ulog_camera_capture, read_ulog_imu
from dgcal.pos.ros_bags import read_rosbag_imu, read_rosbag_navsatfix
from dgcal.pos.ins.interpolate import interpolate_trajectory
from dgcal.pos.lowcost.sync import synchronise
from dgcal.pos.lowcost.ukf import run_ukf
from dgcal.pos.gnss.spp_mode import SppModeOptions
from dgcal.pos.gnss_ins import PosResult
from dgcal.pos.mode_options import InsModeOptions, PpkModeOptions, UkfModeOptions
from dgcal.pos.pipeline import run_pos
from dgcal.reports.exports.calibration import read_calibration_export, write_calibration_exports
from dgcal.reports.exports.eop import (export_all, read_colmap, read_metashape, read_odm_geo, read_pix4d,
                                       write_colmap, write_metashape, write_odm_geo, write_pix4d)
from dgcal.sim.campaign import simulate_campaign

__all__ = [
    # files and frames
    "InputError", "MapGrid", "LocalENU", "Poses",
    "Points", "Measurements", "Trajectory", "Events", "EOP",
    "read_points", "write_points", "read_measurements", "write_measurements", "read_trajectory",
    "write_trajectory", "read_events", "write_events", "read_eop", "write_eop",
    "read_any_points", "read_any_measurements",
    # cameras
    "CameraModel", "Fraser7", "OpenCV8", "model_class", "read_camera", "read_camera_with_error", "write_camera",
    "CameraCalibration", "calibrate_camera",
    # aerial triangulation
    "TriangulationOptions", "TriangulationResult", "triangulate",
    # POS
    "ImuData", "read_imu_csv", "read_imu_text", "read_kf_gins", "read_rinex_obs", "read_rinex_nav",
    "SppOptions", "spp", "SppModeOptions", "PpkModeOptions", "InsModeOptions", "UkfModeOptions", "PosResult",
    "run_pos", "interpolate_trajectory", "run_ukf", "synchronise",
    "ImuFormat", "imu_format", "read_imu", "read_time_tag", "read_ulog_imu", "read_ulog_camera_capture",
    "read_rosbag_imu", "read_rosbag_navsatfix",
    "read_imu_datasheet", "GnssSolution", "read_gnss_solution", "read_rtklib_pos", "write_rtklib_pos",
    "read_nmea_gga", "read_any_events", "read_mrk", "read_utc_events", "read_sbet", "write_sbet_files",
    "read_any_trajectory",
    # system calibration and DG
    "METHODS", "MountingResult", "calibrate_mounting", "read_mounting_json", "dg_eop", "check_points_dg",
    "georeference",
    # exports
    "export_all", "write_colmap", "read_colmap", "write_pix4d", "read_pix4d", "write_metashape", "read_metashape",
    "write_odm_geo", "read_odm_geo", "write_calibration_exports", "read_calibration_export",
    # simulation
    "simulate_campaign",
]
