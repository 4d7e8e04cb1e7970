"""Mounting calibration (traditional, proposed) on simulated flights: accuracy, honest sigmas, frames, robustness."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.calib.mounting.methods import calibrate_mounting, prepare_epochs
from dgcal.fields.pose import Poses, so3_log
from dgcal.calib.mounting.observability import observability_warnings
from dgcal.fields.crs import LocalENU, MapGrid
from dgcal.fields.io.formats import EOP, Trajectory
from dgcal.fields.world import World
from dgcal.sim.mounting import simulate_mounting


@pytest.fixture(scope="module")
def sim():
    return simulate_mounting(1)


def _errors(res, sim):
    """Estimate - truth as [delay, lever(3), boresight body-axes rotation(3) rad]."""
    d = so3_log(res.R_cam_to_body @ sim.R_cam_to_body.T)
    return np.r_[res.delay_s - sim.delay_s, res.lever_arm_m - sim.lever_arm_m, d]


def test_block_world_round_trips():
    world = World(MapGrid("EPSG:32651"), LocalENU(23.0, 120.3, 30.0))
    rng = np.random.default_rng(0)
    p_world = rng.uniform(-3000, 3000, (20, 3))
    R = Rotation.random(20, random_state=1).as_matrix()
    xyz, opk, _ = world.poses_to_eop(Poses.from_cam_to_world(R, p_world))
    back = world.eop_to_poses(xyz, opk)
    p2, R2 = back.C_world, back.R_cam_to_world
    assert np.max(np.abs(p2 - p_world)) < 1e-6
    assert np.max(np.abs(R2 - R)) < 1e-9
    v = rng.normal(0, 20, (20, 3))
    lat, lon, h, v_ned, rph = world.world_to_pos(p_world, v, R)
    p3, v3, R3 = world.pos_to_world(lat, lon, h, v_ned, rph)
    assert np.max(np.abs(p3 - p_world)) < 1e-6 and np.max(np.abs(v3 - v)) < 1e-9 and np.max(np.abs(R3 - R)) < 1e-9


def test_block_world_handles_convergence():
    """A nadir camera with its top to TRUE north west of the UTM central meridian: its top points east of grid
    north (convergence < 0), i.e. a clockwise kappa equal to the convergence."""
    grid = MapGrid("EPSG:32651")
    world = World(grid, LocalENU(23.0, 120.3, 30.0))
    R_cam_to_enu = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # x east, y south (image down), z down
    xyz, opk, _ = world.poses_to_eop(Poses.from_cam_to_world(R_cam_to_enu[None], np.zeros((1, 3))))
    conv = float(grid.convergence_deg(23.0, 120.3))
    assert abs(conv) > 0.9  # 2.7 deg west of 123 E
    assert np.allclose(opk[0, :2], 0, atol=1e-6)
    assert conv < 0 and abs(opk[0, 2] - conv) < 1e-6
    # and the sign: grid axes are true axes rotated by the convergence about Up
    from dgcal.fields.frames import R_cam_to_map_from_opk, R_enu_to_grid
    assert np.allclose(R_cam_to_map_from_opk(*opk[0]), R_enu_to_grid(conv) @ R_cam_to_enu, atol=1e-6)


def test_proposed_recovers_truth_within_tolerance_and_sigma(sim):
    c = sim.calibration
    res = calibrate_mounting(c.eop, MapGrid(sim.crs), c.traj, c.events, "proposed")
    err = _errors(res, sim)
    s = res.sigmas
    assert abs(err[0]) < 0.002
    assert np.all(np.abs(err[1:4]) < 0.03)
    assert np.all(np.degrees(np.abs(err[4:])) < 0.02)
    assert np.all(np.abs(err) < 3 * s)
    assert 0.7 < res.extra["sigma0"] < 1.4
    j = res.to_json()
    assert np.allclose(np.array(j["boresight_R_cam_to_body"]) @ np.array(j["boresight_R_cam_to_body"]).T, np.eye(3))
    assert len(j["lever_arm_sigma_m"]) == 3 and len(j["boresight_sigma_deg"]) == 3 and j["delay_sigma_s"] > 0


def test_traditional_absorbs_the_delay_into_the_lever_arm(sim):
    """Seed 003 Fig. 22: with delay -0.14 s at ~30 m/s, the traditional lever arm is off by metres along track."""
    c = sim.calibration
    res = calibrate_mounting(c.eop, MapGrid(sim.crs), c.traj, c.events, "traditional")
    assert res.delay_s == 0.0
    err = res.lever_arm_m - sim.lever_arm_m
    assert 3.0 < -err[0] < 5.0  # ~ mean forward speed x delay
    assert abs(err[1]) < 0.5
    assert len(res.per_epoch["lever_arm_m"]) == len(c.eop.image)
    # the traditional per-epoch spread reflects the two ground speeds
    assert np.std(np.array(res.per_epoch["lever_arm_m"])[:, 0]) > 0.3


def test_sigmas_are_honest_over_seeds():
    """The simulator's POS errors here are independent between photos (its default): told so (F = 0), the joint
    method's sigmas match the errors; the default F = 1 (a smoother's errors are common to the flight) would be
    conservative on such data."""
    z = []
    for seed in (11, 12, 13, 14):
        s = simulate_mounting(seed)
        c = s.calibration
        res = calibrate_mounting(c.eop, MapGrid(s.crs), c.traj, c.events, "proposed", pos_common_fraction=0.0)
        z.append(_errors(res, s) / res.sigmas)
    z = np.array(z)
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.6 < rms < 1.5, rms
    assert np.max(np.abs(z)) < 4.0


def test_events_at_trajectory_file_works(sim):
    """`--trajectory` may be the events.csv of `dgcal pos` (one row per event, no angular rate)."""
    c = sim.calibration
    world, ep = prepare_epochs(c.eop, MapGrid(sim.crs), c.traj, c.events)
    lat, lon, h, v_ned, rph = world.world_to_pos(ep.pos.r_imu_world, ep.pos.v_world, ep.pos.R_body_to_world)
    ev_traj = Trajectory(ep.t_event, lat, lon, h, v_ned, rph, np.tile(c.traj.sigma[0], (len(lat), 1)),
                         image=ep.image)
    res = calibrate_mounting(c.eop, MapGrid(sim.crs), ev_traj, c.events, "proposed")
    assert any("angular rate" in w for w in res.warnings)
    err = _errors(res, sim)
    assert abs(err[0]) < 0.004 and np.all(np.abs(err[1:4]) < 0.1)


def test_missing_images_are_skipped_and_listed(sim):
    c = sim.calibration
    keep = np.ones(len(c.eop.image), bool)
    keep[[3, 7]] = False
    eop = EOP(c.eop.image[keep], c.eop.xyz[keep], c.eop.opk[keep], c.eop.sigma[keep])
    eop.image = np.r_[eop.image[:-1], np.array(["EXTRA.JPG"], dtype=object)]
    res = calibrate_mounting(eop, MapGrid(sim.crs), c.traj, c.events, "proposed")
    sk = res.extra["skipped_images"]
    assert sk["no_eop"] == sorted([str(c.eop.image[3]), str(c.eop.image[7]), str(c.eop.image[-1])])
    assert sk["no_event"] == ["EXTRA.JPG"]
    assert any("without an EOP" in w for w in res.warnings)


def test_outlier_epoch_is_rejected(sim):
    c = sim.calibration
    eop = EOP(c.eop.image.copy(), c.eop.xyz.copy(), c.eop.opk.copy(), c.eop.sigma.copy())
    eop.xyz[10] += [2.0, -1.0, 0.5]
    eop.opk[20, 2] += 0.5
    res = calibrate_mounting(eop, MapGrid(sim.crs), c.traj, c.events, "proposed")
    assert str(eop.image[10]) in res.rejected and str(eop.image[20]) in res.rejected
    assert abs(res.delay_s - sim.delay_s) < 0.002


def test_one_heading_one_height_warns():
    s = simulate_mounting(3, calibration=dict(heights=(300.0,), n_strips=1, length_m=1500.0))
    c = s.calibration
    _, ep = prepare_epochs(c.eop, MapGrid(s.crs), c.traj, c.events)
    w = " ".join(observability_warnings(ep))
    assert "one heading" in w and "one flying height" in w
    s2 = simulate_mounting(3)
    _, ep2 = prepare_epochs(s2.calibration.eop, MapGrid(s2.crs), s2.calibration.traj, s2.calibration.events)
    w2 = " ".join(observability_warnings(ep2))
    assert "one heading" not in w2 and "one flying height" not in w2


def test_too_few_epochs_is_an_input_error(sim):
    from dgcal.fields.errors import InputError
    c = sim.calibration
    eop = EOP(c.eop.image[:2], c.eop.xyz[:2], c.eop.opk[:2], c.eop.sigma[:2])
    with pytest.raises(InputError, match="at least 3"):
        calibrate_mounting(eop, MapGrid(sim.crs), c.traj, c.events, "proposed")


@pytest.mark.parametrize("crs", ["EPSG:4326", "EPSG:3826"])
def test_other_map_crs(crs):
    """Geographic EOPs (degrees, sigmas in metres) and Taiwan's TM2 (TWD97) give the same calibration."""
    s = simulate_mounting(1, crs=crs)
    c = s.calibration
    res = calibrate_mounting(c.eop, MapGrid(crs), c.traj, c.events, "proposed")
    err = _errors(res, s)
    assert np.all(np.abs(err) < 3 * res.sigmas) and 0.7 < res.extra["sigma0"] < 1.4


def test_common_mode_pos_errors_need_the_common_fraction():
    """A smoother's POS errors partly repeat in every photo (bias-driven tilt, GNSS biases): treated as
    independent, the sigmas are too small; with pos_common_fraction they cover the errors again."""
    from dgcal.calib.mounting.methods import calibrate_mounting
    z_indep, z_common = [], []
    for seed in range(6):
        s = simulate_mounting(seed, calibration={"pos_common_fraction": 1.0,
                                                 "pos_sigma": (0.01, 0.01, 0.015, 0.01, 0.01, 0.03)})
        c = s.calibration
        for frac, out in ((0.0, z_indep), (1.0, z_common)):
            res = calibrate_mounting(c.eop, MapGrid(s.crs), c.traj, c.events, "proposed", pos_common_fraction=frac)
            out.append(_errors(res, s) / res.sigmas)
    rms_indep = float(np.sqrt(np.mean(np.square(z_indep))))
    rms_common = float(np.sqrt(np.mean(np.square(z_common))))
    assert rms_indep > 1.6, rms_indep
    assert 0.6 < rms_common < 1.4, rms_common


def test_dg_covariance_counts_the_common_mode_once_on_the_calibration_flight():
    from dgcal.calib.mounting.common import MountingResult
    s = simulate_mounting(2, calibration={"pos_common_fraction": 1.0})
    c = s.calibration
    res = calibrate_mounting(c.eop, MapGrid(s.crs), c.traj, c.events, "proposed", pos_common_fraction=1.0)
    back = MountingResult.from_json(res.to_json())  # what `dgcal check` reads
    own = list(c.events.image[:5])
    cov_own = back.covariance_for_flight(own)
    assert np.all(np.diag(cov_own) < np.diag(back.cov))  # the random part only
    np.testing.assert_allclose(cov_own, np.array(res.extra["covariance_random"]))
    np.testing.assert_allclose(back.covariance_for_flight(["another_flight.jpg"]), back.cov)


def test_joint_residual_jacobian_equals_central_differences(sim):
    """The joint method's analytic Jacobian (delay through the POS rate and velocity, lever arm, boresight through
    the SO(3) Jacobians) against central differences of its residuals, away from the solution."""
    from dgcal.calib.mounting.joint import residual_jacobian, residuals
    c = sim.calibration
    _, ep = prepare_epochs(c.eop, MapGrid(sim.crs), c.traj, c.events)
    R_hat = Rotation.from_euler("xyz", [1.5, -2.0, 91.0], degrees=True).as_matrix()
    x = np.array([-0.09, 0.3, -0.2, 0.15, 0.02, -0.03, 0.05])
    J = residual_jacobian(ep, x, R_hat)
    num = np.empty_like(J)
    for j in range(7):
        h = np.zeros(7)
        h[j] = 1e-6
        num[:, :, j] = (residuals(ep, x + h, R_hat) - residuals(ep, x - h, R_hat)) / 2e-6
    assert np.abs(J).max() > 1.0                     # not all zeros: the test compares something
    np.testing.assert_allclose(J, num, atol=2e-7 * np.abs(J).max())
