"""ISO (one-step integrated sensor orientation): mounting from image measurements + GCPs + POS in one adjustment."""
import numpy as np
import pytest

from dgcal.fields.pose import so3_log
from dgcal.calib.mounting.integrated import calibrate_iso
from dgcal.cli import main
from dgcal.fields.crs import MapGrid
from dgcal.sim.mounting import simulate_mounting, write_mounting_sim


@pytest.fixture(scope="module")
def sim():
    return simulate_mounting(21)


def test_iso_recovers_truth_with_honest_sigmas(sim):
    c = sim.calibration
    r = calibrate_iso(c.eop, MapGrid(sim.crs), c.traj, c.events, c.measurements, sim.ground, sim.camera)
    e = np.r_[r.delay_s - sim.delay_s, r.lever_arm_m - sim.lever_arm_m, so3_log(r.R_cam_to_body @ sim.R_cam_to_body.T)]
    assert abs(e[0]) < 0.002 and np.all(np.abs(e[1:4]) < 0.03) and np.all(np.degrees(np.abs(e[4:])) < 0.02)
    assert np.all(np.abs(e) < 3 * r.sigmas)
    assert 0.8 < r.extra["sigma0"] < 1.2
    assert 0.35 < r.extra["image_rms_px"] < 0.6  # pixel noise 0.5 px
    assert r.extra["n_control_points"] >= 3 and r.extra["n_tie_points"] > 0


def test_iso_cli(sim, tmp_path):
    write_mounting_sim(sim, tmp_path / "d")
    c = tmp_path / "d" / "calibration"
    rc = main(["mount", "--method", "iso", "--eop", str(c / "eop.csv"), "--crs", sim.crs, "--trajectory",
               str(c / "trajectory.csv"), "--events", str(c / "events.csv"), "--measurements",
               str(c / "measurements.csv"), "--gcp", str(tmp_path / "d" / "ground.csv"), "--camera",
               str(tmp_path / "d" / "camera.json"), "--out", str(tmp_path / "iso")])
    assert rc == 0
    import json
    j = json.loads((tmp_path / "iso" / "mounting.json").read_text())
    assert j["method"] == "iso" and abs(j["delay_s"] - sim.delay_s) < 0.002


def test_iso_refines_intrinsics(sim):
    c = sim.calibration
    cam0 = sim.camera.copy()
    cam0.params[0] += 6.0  # focal length off by 6 px (0.2 %)
    cam0.params[1] -= 4.0
    r = calibrate_iso(c.eop, MapGrid(sim.crs), c.traj, c.events, c.measurements, sim.ground, cam0,
                      refine_intrinsics=("f", "cx", "cy"))
    for k, i in (("f", 0), ("cx", 1), ("cy", 2)):
        err = r.extra["intrinsics"][k] - sim.camera.params[i]
        assert abs(err) < 3 * r.extra["intrinsics_sigma"][k] + 0.05, (k, err)
    assert abs(r.delay_s - sim.delay_s) < 0.002


def test_iso_pos_common_mode_sigmas_honest():
    """POS errors common to the whole flight: with pos_common_fraction=1 the mounting sigmas match the errors,
    with 0 (independent POS errors per photo) they are several times too small."""
    cal = {"pos_common_fraction": 1.0, "pos_sigma": (0.01, 0.01, 0.015, 0.01, 0.01, 0.03)}
    z1, z0 = [], []
    for seed in range(3):
        s = simulate_mounting(seed, calibration=cal)
        c = s.calibration
        r = calibrate_iso(c.eop, MapGrid(s.crs), c.traj, c.events, c.measurements, s.ground, s.camera,
                          pos_common_fraction=1.0)
        e = np.r_[r.delay_s - s.delay_s, r.lever_arm_m - s.lever_arm_m,
                  so3_log(r.R_cam_to_body @ s.R_cam_to_body.T)]
        z1.append(e / r.sigmas)
        z0.append(e / np.sqrt(np.diag(np.array(r.extra["covariance_random"]))))
        assert r.extra["pos_common_fraction"] == 1.0
    # on the calibration flight itself the common part is carried by the POS: only the random part is used
    assert np.allclose(r.covariance_for_flight(c.eop.image), np.array(r.extra["covariance_random"]))
    assert np.allclose(r.covariance_for_flight(["elsewhere"]), r.cov)
    assert np.abs(np.array(r.per_epoch["residual_rotation_deg"])).max() < 0.2
    rms1, rms0 = np.sqrt(np.mean(np.square(z1))), np.sqrt(np.mean(np.square(z0)))
    assert 0.5 < rms1 < 1.5, rms1
    assert rms0 > 2.5, rms0
    # the boresight cannot be known better than the common POS attitude error
    assert np.all(np.degrees(r.sigmas[4:]) > 0.9 * np.array([0.01, 0.01, 0.03]))


def test_iso_rejects_bad_pos_common_fraction(sim):
    from dgcal.fields.errors import InputError
    c = sim.calibration
    with pytest.raises(InputError, match="pos_common_fraction"):
        calibrate_iso(c.eop, MapGrid(sim.crs), c.traj, c.events, c.measurements, sim.ground, sim.camera,
                      pos_common_fraction=1.5)


def test_iso_rejects_one_wrong_pixel(sim):
    import copy
    c = sim.calibration
    clean = calibrate_iso(c.eop, MapGrid(sim.crs), c.traj, c.events, c.measurements, sim.ground, sim.camera)
    meas = copy.deepcopy(c.measurements)
    k = len(meas.id) // 2
    meas.xy[k] += [6.0, -5.0]                     # one measurement 8 px off
    r = calibrate_iso(c.eop, MapGrid(sim.crs), c.traj, c.events, meas, sim.ground, sim.camera)
    rej = r.extra["rejected_observations"]
    assert [(x["image"], x["id"]) for x in rej] == [(str(meas.image[k]), str(meas.id[k]))]
    assert np.all(np.abs(r.lever_arm_m - clean.lever_arm_m) < 3 * clean.sigmas[1:4])
    assert abs(r.delay_s - clean.delay_s) < 3 * clean.sigmas[0]
    assert clean.extra["rejected_observations"] == []
