"""`dgcal export --calibration`: the mounting in Metashape / POSPac / Inertial Explorer / Pix4D conventions, each
read back to dgcal's lever arm and boresight (1e-6 m, 1e-6 deg), nominal mounts giving zero angles; and DG exports
from an SBET trajectory through the CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.calib.mounting.common import MountingResult
from dgcal.cli import main
from dgcal.fields.frames import R_CAM_TO_BODY_NADIR
from dgcal.fields.io.formats import write_events, write_trajectory
from dgcal.pos.ins.sbet import write_sbet_files
from dgcal.reports.exports.calibration import (CALIBRATION_FORMATS, R_cam_to_body_from_metashape_ypr,
                                               calibration_values, metashape_ypr_offset, read_calibration_export,
                                               write_calibration_exports)
from dgcal.reports.exports.eop import read_pix4d
from dgcal.sim.mounting import simulate_mounting


def _mount(R, lever=(0.31, -0.12, 0.25), delay=-0.014):
    return MountingResult("joint", np.asarray(lever, float), np.asarray(R, float), delay, np.zeros((7, 7)))


def _angle_deg(Ra, Rb):
    return float(np.degrees(Rotation.from_matrix(Ra.T @ Rb).magnitude()))


@pytest.mark.parametrize("seed", range(5))
def test_calibration_exports_read_back(tmp_path, seed):
    rng = np.random.default_rng(seed)
    R = R_CAM_TO_BODY_NADIR @ Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix()
    m = _mount(R, rng.normal(0, 0.3, 3))
    ref = rng.normal(0, 0.5, 3)
    paths = write_calibration_exports(tmp_path, m, CALIBRATION_FORMATS, ref)
    for fmt, p in paths.items():
        f, lever, R2, delay = read_calibration_export(p)
        assert f == fmt
        assert np.max(np.abs(lever - m.lever_arm_m)) < 1e-6
        assert _angle_deg(R2, R) < 1e-6
        assert abs(delay - m.delay_s) < 1e-9
    assert set(json.loads((tmp_path / "calibration_exports.json").read_text())) == set(CALIBRATION_FORMATS)


def test_nominal_nadir_mount_has_zero_boresight_everywhere():
    m = _mount(R_CAM_TO_BODY_NADIR, lever=(0.1, 0.2, 0.3))
    assert np.allclose(calibration_values(m, "pospac")["boresight_tx_ty_tz_deg"], 0, atol=1e-12)
    assert np.allclose(calibration_values(m, "inertial-explorer")["boresight_rx_ry_rz_deg"], 0, atol=1e-12)
    assert np.allclose(calibration_values(m, "metashape")["camera_orientation_offset_yaw_pitch_roll_deg"], 0,
                       atol=1e-12)
    ie = calibration_values(m, "inertial-explorer")
    assert np.allclose(ie["lever_arm_xyz_m"], [0.2, 0.1, -0.3])         # FRD (0.1, 0.2, 0.3) -> right, fwd, up
    ms = calibration_values(m, "metashape", reference_lever_arm_m=(0.1, 0.2, 0.3))
    assert np.allclose(ms["antenna_offset_xyz_m"], 0)                    # antenna at the camera


def test_single_axis_conventions():
    """A camera pitched 2 deg nose-up about the body y axis: POSPac's ty = +2; IE's rotation about its x (right)
    axis; Metashape's pitch about the camera x axis."""
    R = Rotation.from_euler("y", 2.0, degrees=True).as_matrix() @ R_CAM_TO_BODY_NADIR
    m = _mount(R)
    assert np.allclose(calibration_values(m, "pospac")["boresight_tx_ty_tz_deg"], [0, 2, 0], atol=1e-9)
    ie = calibration_values(m, "inertial-explorer")["boresight_rx_ry_rz_deg"]
    assert abs(abs(ie[0]) - 2.0) < 1e-9 and abs(ie[1]) < 1e-9 and abs(ie[2]) < 1e-9
    ypr = metashape_ypr_offset(R)
    assert np.allclose(ypr, [0, 2, 0], atol=1e-9)                      # nose-up: Metashape pitch +2
    assert _angle_deg(R_cam_to_body_from_metashape_ypr(ypr), R) < 1e-9


def test_export_cli_calibration_and_sbet_trajectory(tmp_path):
    """`dgcal export --calibration` writes every program's file; `dgcal export` takes an SBET as trajectory and
    gives the same EOPs as the CSV trajectory (1e-6 m, deg)."""
    sim = simulate_mounting(2, n_ground=16)
    m = MountingResult("truth", sim.lever_arm_m, sim.R_cam_to_body, sim.delay_s, np.zeros((7, 7)))
    (tmp_path / "mounting.json").write_text(json.dumps(m.to_json()))
    assert main(["export", "--mounting", str(tmp_path / "mounting.json"), "--calibration", "--out",
                 str(tmp_path / "cal")]) == 0
    for fmt in CALIBRATION_FORMATS:
        _, lever, R2, _ = read_calibration_export(next((tmp_path / "cal").glob(f"{fmt.replace('-', '_')}*.txt")))
        assert np.max(np.abs(lever - sim.lever_arm_m)) < 1e-6 and _angle_deg(R2, sim.R_cam_to_body) < 1e-6
    tr, ev = sim.mapping.traj, sim.mapping.events
    write_trajectory(tmp_path / "traj.csv", tr)
    write_events(tmp_path / "events.csv", ev)
    write_sbet_files(tmp_path / "sbet_map.out", tr)
    outs = {}
    for name, traj in (("csv", "traj.csv"), ("sbet", "sbet_map.out")):
        assert main(["export", "--mounting", str(tmp_path / "mounting.json"), "--trajectory", str(tmp_path / traj),
                     "--events", str(tmp_path / "events.csv"), "--crs", sim.crs, "--formats", "pix4d", "--out",
                     str(tmp_path / name)]) == 0
        outs[name] = read_pix4d(tmp_path / name / "pix4d_external_orientation.txt")
    assert np.max(np.abs(outs["csv"].xyz - outs["sbet"].xyz)) < 1e-3          # CSV trajectory rounds to 0.1 mm
    assert np.max(np.abs((outs["csv"].opk - outs["sbet"].opk + 180) % 360 - 180)) < 1e-5
