"""Unit tests of the smoother's pieces: frames, factor conventions, preintegration splitting, covariances."""
from __future__ import annotations

import numpy as np
import pytest

import gtsam  # a required dependency: missing is an error, not a skip

from dgcal.fields.constants import C_LIGHT  # noqa: E402
from dgcal.pos.gnss.observations import GnssEpoch  # noqa: E402
from dgcal.pos.ins.nav_frame import NavFrame  # noqa: E402
from dgcal.pos.smoother.factors import CLK, DRIFT, V, X, ZERO, doppler_factors, pseudorange_factors  # noqa: E402


def test_nav_frame_round_trip_and_curvature():
    f = NavFrame(35.3, 139.5, 40.0)
    p = np.array([[100.0, -250.0, -120.0], [1000.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert np.allclose(f.from_ecef(f.to_ecef(p)), p, atol=1e-6)
    R = f.R_nav_to_local_ned(p)
    assert np.allclose(R[2], np.eye(3), atol=1e-12)
    # 1 km north: local level tilts by d/R about east
    ang = np.degrees(np.arccos(np.clip((np.trace(R[1]) - 1) / 2, -1, 1)))
    assert ang == pytest.approx(np.degrees(1000.0 / 6.36e6), rel=0.02)


def _epoch(frame, p_ant_nav, v_ant_nav, clk_s, drift, rng):
    """A hand-built GnssEpoch (corrected-pseudorange convention of dgcal.pos.gnss.observations) for 6 satellites."""
    r = frame.to_ecef(p_ant_nav)
    v_r = v_ant_nav @ frame.R_nav_to_ecef.T
    n = 6
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.5
    sat = r + d / np.linalg.norm(d, axis=1, keepdims=True) * 2.2e7
    vs = rng.normal(0, 2000, (n, 3))
    rho = np.linalg.norm(sat - r, axis=1)
    e = (sat - r) / rho[:, None]
    system = np.array(["G", "G", "G", "E", "E", "E"])
    cb = np.where(system == "G", clk_s["G"], clk_s["E"])
    pr = rho + C_LIGHT * cb
    rr = np.einsum("ij,ij->i", e, vs - v_r) + C_LIGHT * drift
    z = np.zeros(n)
    return GnssEpoch(0.0, [f"{s}{i:02d}" for i, s in enumerate(system)], system, pr, -rr / 0.19, rr,
                     np.full(n, 0.19), z + 45, sat, vs, z, z, z, z, z + 45, z, z + 0.5, z + 0.05)


def test_tc_factors_vanish_at_the_truth():
    """Pseudorange/Doppler factors: clock in seconds, lever arm in body, nav frame via ecef_T_nav, Sagnac."""
    rng = np.random.default_rng(4)
    frame = NavFrame(47.0, 8.0, 500.0)
    R = gtsam.Rot3.Ypr(0.7, 0.05, -0.1)
    p_imu = np.array([120.0, -40.0, -90.0])
    v_imu = np.array([8.0, 3.0, -1.0])
    lever = np.array([0.1, -0.2, -0.4])
    omega_b = np.array([0.05, -0.02, 0.3])
    p_ant = p_imu + R.matrix() @ lever
    v_ant = v_imu + R.matrix() @ np.cross(omega_b, lever)
    clk = {"G": 2.0e-5, "E": 2.0e-5 + 8e-9}
    drift = 5e-8
    ep = _epoch(frame, p_ant, v_ant, clk, drift, rng)
    vals = gtsam.Values()
    vals.insert(X(3), gtsam.Pose3(R, p_imu))
    vals.insert(V(3), v_imu)
    vals.insert(CLK("G", 3), clk["G"])
    vals.insert(CLK("E", 3), clk["E"])
    vals.insert(DRIFT(3), drift)
    vals.insert(ZERO(), 0.0)
    # an SPP-quality position is enough (the Doppler line of sight errs by 1 mm/s per ~5 m)
    r_approx = frame.to_ecef(p_ant) + np.array([3.0, -2.0, 1.0])
    T = frame.ecef_T_nav()
    pr = pseudorange_factors(3, ep, r_approx, lever, T, huber_k=None)
    dop = doppler_factors(3, ep, r_approx, lever, omega_b, T, huber_k=None)
    e_pr = np.array([f.unwhitenedError(vals)[0] for f in pr])
    e_dop = np.array([f.unwhitenedError(vals)[0] for f in dop])
    assert np.max(np.abs(e_pr)) < 2e-3
    assert np.max(np.abs(e_dop)) < 2e-3
    # and they see a 1 m position error and a 1 ns clock error
    vals.update(X(3), gtsam.Pose3(R, p_imu + [1.0, 0, 0]))
    assert np.max(np.abs([f.unwhitenedError(vals)[0] for f in pr])) > 0.2
    vals.update(X(3), gtsam.Pose3(R, p_imu))
    vals.update(CLK("G", 3), clk["G"] + 1e-9)
    assert pr[0].unwhitenedError(vals)[0] - e_pr[0] == pytest.approx(C_LIGHT * 1e-9, rel=1e-6)


def test_split_at_keyframes_keeps_the_increments():
    from dgcal.pos.smoother.preintegration import split_at_keyframes
    rng = np.random.default_rng(0)
    t = 100.0 + np.arange(1, 1001) * 0.01
    g = rng.normal(size=(1000, 3))
    a = rng.normal(size=(1000, 3))
    t_key = np.array([100.0, 100.5, 101.003, 103.0, 109.997])
    seg = split_at_keyframes(t, g, a, t_key, 0.01)
    assert seg.dt.sum() == pytest.approx(t_key[-1] - t_key[0])
    for k in range(len(t_key) - 1):
        sl = slice(seg.start[k], seg.start[k + 1])
        assert seg.dt[sl].sum() == pytest.approx(t_key[k + 1] - t_key[k], abs=1e-9)
    # the integral of the rates equals the sum of the (partial) increments
    n_full = int(np.floor((t_key[-1] - 100.0) / 0.01 + 1e-9))  # samples entirely inside the span
    full = (g * 0.01)[:n_full].sum(0)
    part = g[n_full] * 0.007
    assert np.allclose((seg.gyro * seg.dt[:, None]).sum(0), full + part, atol=1e-9)


def test_preintegration_is_exact_in_a_steady_turn():
    # body yawing at 13 deg/s with a constant horizontal specific force in nav (a coordinated turn's
    # centripetal part): the velocity increment over 1 s at 100 Hz must equal f_nav * T. Without the
    # rotation compensation gtsam rotates each sample's force by the start attitude: error w dt/2 * |f| * T
    from dgcal.pos.ins.error_model import imu_grade
    from dgcal.pos.smoother.preintegration import (ImuSegments, preintegrate, preintegration_params,
                                                   rotation_compensated_accel)
    import gtsam
    w, dt, n = 0.228, 0.01, 100
    f_nav = np.array([4.5, 0.0, -9.8])
    tau = (np.arange(n)[:, None] + (np.arange(400) + 0.5)[None, :] / 400) * dt  # fine quadrature per sample
    c, s = np.cos(w * tau), np.sin(w * tau)
    f_b = np.stack([(c * f_nav[0] + s * f_nav[1]).mean(1), (-s * f_nav[0] + c * f_nav[1]).mean(1),
                    np.full(n, f_nav[2])], 1)  # mean body specific force of each sample
    gyro = np.tile([0.0, 0.0, w], (n, 1))
    seg = ImuSegments(gyro, f_b, np.full(n, dt), np.array([0, n]))
    params = preintegration_params(imu_grade("adis16488").smoother_noise(), NavFrame(23.0, 120.0, 0.0),
                                   earth_rotation=False)
    pim = preintegrate(params, seg, [gtsam.imuBias.ConstantBias()])[0]
    assert np.abs(pim.deltaVij() - f_nav * n * dt).max() < 2e-5
    raw = gtsam.PreintegratedCombinedMeasurements(params, gtsam.imuBias.ConstantBias())
    for j in range(n):
        raw.integrateMeasurement(f_b[j], gyro[j], dt)
    assert np.abs(raw.deltaVij() - f_nav * n * dt).max() > 3e-3  # the half-sample lag the compensation removes
    assert np.allclose(rotation_compensated_accel(gyro, f_b, seg.dt)[:, 2], f_b[:, 2])


def test_euler_rate_matrix_matches_numerical_derivative():
    from dgcal.fields.frames import R_body_to_ned_from_rph, rph_from_R_body_to_ned
    from dgcal.pos.smoother.output import euler_rate_matrix
    rph = np.array([[12.0, -7.0, 250.0]])
    J = euler_rate_matrix(rph)[0]
    R0 = R_body_to_ned_from_rph(*rph[0])
    h = 1e-6
    Jn = np.empty((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        Rp = R0 @ gtsam.Rot3.Expmap(d).matrix()
        Rm = R0 @ gtsam.Rot3.Expmap(-d).matrix()
        Jn[:, i] = np.radians(rph_from_R_body_to_ned(Rp) - rph_from_R_body_to_ned(Rm)) / (2 * h)
    assert np.allclose(J, Jn, atol=1e-6)


def test_gravity_tilts_with_distance():
    from dgcal.pos.smoother.preintegration import interval_gravity, keyframe_gravity
    f = NavFrame(35.0, 139.0, 50.0)
    p = np.array([[2000.0, 0.0, 0.0], [2000.0, 0.0, 0.0]])  # 2 km north
    g = keyframe_gravity(f, p)[0]
    # gravity at 2 km north points back towards the origin's vertical: -g d/R along north
    assert g[0] == pytest.approx(-f.gravity * 2000.0 / 6.36e6, rel=0.03)
    assert abs(g[1]) < 1e-6 and g[2] == pytest.approx(f.gravity, abs=5e-5)  # latitude: +1.4e-5
    # 100 m up: the free-air gradient, 0.31 mGal/m
    assert keyframe_gravity(f, np.array([[0.0, 0.0, -100.0]]))[0, 2] - f.gravity == pytest.approx(-3.086e-4, rel=0.01)
    gi = interval_gravity(f, np.array([[0.0, 0.0, 0.0], [2000.0, 0.0, 0.0]]))
    assert gi.shape == (1, 3) and gi[0, 0] == pytest.approx(0.5 * g[0], rel=1e-6)


def test_gravity_set_after_preintegration_reaches_the_factor():
    """gtsam applies gravity in the prediction, from the parameters the factor shares: setting an interval's gravity
    after its preintegration changes the factor's error as a new preintegration would (exactly)."""
    from dgcal.pos.ins.error_model import imu_grade
    from dgcal.pos.smoother.preintegration import ImuSegments, preintegrate, preintegration_params, set_gravity
    rng = np.random.default_rng(3)
    frame = NavFrame(23.0, 120.0, 0.0)
    n = 100
    seg = ImuSegments(rng.normal(0, 0.1, (n, 3)), rng.normal(0, 1, (n, 3)) + [0, 0, -9.8], np.full(n, 0.01),
                      np.array([0, n]))
    noise = imu_grade("adis16488").smoother_noise()
    pa, pb = preintegration_params(noise, frame), preintegration_params(noise, frame)
    g = np.array([[1.5e-3, -0.7e-3, frame.gravity + 2e-4]])
    set_gravity([pb], g)
    fresh = preintegrate(pb, seg, [gtsam.imuBias.ConstantBias()])[0]
    late = preintegrate(pa, seg, [gtsam.imuBias.ConstantBias()])[0]
    set_gravity([pa], g)
    ns = gtsam.NavState(gtsam.Rot3.Rz(0.3), np.array([10.0, 5.0, -100.0]), np.array([3.0, 4.0, 0.5]))
    b = gtsam.imuBias.ConstantBias()
    assert np.allclose(fresh.predict(ns, b).velocity(), late.predict(ns, b).velocity(), atol=1e-12)
    assert np.allclose(fresh.predict(ns, b).position(), late.predict(ns, b).position(), atol=1e-12)


def test_bias_moved_bounds_gtsams_first_order_correction():
    """Where `bias_moved` says no, the first-order bias correction of a preintegration about zero bias is within
    its bound of a preintegration about the bias itself; a consumer-grade bias is flagged."""
    from dgcal.pos.ins.error_model import imu_grade
    from dgcal.pos.smoother.preintegration import ImuSegments, bias_moved, preintegrate, preintegration_params
    rng = np.random.default_rng(2)
    n = 200
    gyro = np.tile([0.05, -0.02, 0.2], (n, 1)) + rng.normal(0, 0.01, (n, 3))
    seg = ImuSegments(gyro, np.tile([0.5, 0.3, -9.8], (n, 1)), np.full(n, 0.005), np.array([0, n]))
    noise = imu_grade("adis16488").smoother_noise()
    params = preintegration_params(noise, NavFrame(23.0, 120.0, 0.0), earth_rotation=False)
    for bg, ba, moved in ((5.7e-4, 0.01, False), (8e-3, 0.2, True)):
        bias = np.r_[np.array([ba, -ba, ba]) / np.sqrt(3), np.array([bg, bg, -bg]) / np.sqrt(3)]
        assert bias_moved(noise, seg, np.zeros((1, 6)), bias[None], 0.01)[0] == moved
        b = gtsam.imuBias.ConstantBias(bias[:3], bias[3:])
        p0 = preintegrate(params, seg, [gtsam.imuBias.ConstantBias()])[0]
        p1 = preintegrate(params, seg, [b])[0]
        dv = np.linalg.norm(p0.predict(gtsam.NavState(), b).velocity() - p1.predict(gtsam.NavState(), b).velocity())
        assert dv <= bg * (0.5 * ba + bg * 9.8 / 6)      # the bound bias_moved uses (T = 1 s)
        if not moved:
            assert dv < 0.01 * noise.accel_vrw


def _lc_problem(K=40, seed=0):
    """A small LC problem built from a straight simulated segment (no clocks, so gtsam.Marginals works)."""
    from dgcal.pos.ins.imu_data import ImuData
    from dgcal.pos.smoother.batch import SmootherOptions, build_problem, optimize
    from dgcal.pos.ins.error_model import ImuErrorModel
    from dgcal.pos.smoother.initial import GnssFixes
    rng = np.random.default_rng(seed)
    frame = NavFrame(30.0, 100.0, 0.0)
    rate = 50.0
    t = 1000.0 + np.arange(1, int(K * rate) + 1) / rate
    acc = np.tile([0.0, 0.0, -frame.gravity], (len(t), 1)) + rng.normal(0, 0.01, (len(t), 3))
    acc[:, 1] += 0.5 * np.sin(0.3 * (t - t[0]))
    gyr = np.tile([0.0, 0.0, 0.05], (len(t), 1)) + rng.normal(0, 1e-3, (len(t), 3))
    imu = ImuData.from_rates(t, gyr, acc, rate)
    tk = 1000.0 + np.arange(0, K + 1, 1.0)
    p = np.column_stack([5.0 * (tk - 1000.0), np.zeros_like(tk), np.zeros_like(tk)])
    fx = GnssFixes(tk, frame.to_ecef(p + rng.normal(0, 0.5, p.shape)), np.full(p.shape, 0.5),
                   np.tile([5.0, 0.0, 0.0], (len(tk), 1)) @ frame.R_nav_to_ecef.T, np.full(p.shape, 0.1))
    noise = ImuErrorModel("test", gyro_arw=1e-3, accel_vrw=1e-2, gyro_bias_rw=1e-5, accel_bias_rw=1e-4,
                          gyro_bias_sigma=1e-3, accel_bias_sigma=1e-2)
    pr = build_problem(imu, frame, tk, fx, noise, SmootherOptions(earth_rotation=False), "lc", None, fx)
    return pr, optimize(pr)


def test_block_covariances_equal_gtsam_marginals():
    """The block recursion's marginals are gtsam's, the LC fixes' error states (`FE`) included."""
    from dgcal.pos.smoother.covariance import smoothed_covariances
    from dgcal.pos.smoother.factors import FE
    pr, vals = _lc_problem()
    blocks = pr.blocks()
    assert blocks.fix is not None and blocks.n == 18
    P = smoothed_covariances(pr.graph, vals, blocks)
    m = gtsam.Marginals(pr.graph, vals)
    for k in (0, 7, len(pr.t_key) - 1):
        assert np.allclose(P[k, :6, :6], m.marginalCovariance(X(k)), rtol=1e-6, atol=1e-12)
        assert np.allclose(P[k, 6:9, 6:9], m.marginalCovariance(V(k)), rtol=1e-6, atol=1e-12)
        assert np.allclose(P[k, 15:18, 15:18], m.marginalCovariance(FE(k)), rtol=1e-6, atol=1e-12)


def test_forward_pass_meets_the_smoother_at_the_last_epoch():
    """Filter and smoother agree at the final epoch (same information), and the filter is never tighter."""
    from dgcal.pos.smoother.covariance import forward_pass, smoothed_covariances
    pr, vals = _lc_problem()
    blocks = pr.blocks()
    dx, Pf = forward_pass(pr.graph, vals, blocks)
    Ps = smoothed_covariances(pr.graph, vals, blocks)
    assert np.allclose(Pf[-1], Ps[-1], rtol=1e-6, atol=1e-12)
    # the correction at the last epoch is the full Gauss-Newton step there (the graph's own solve)
    step = pr.graph.linearize(vals).optimize()
    K = len(pr.t_key) - 1
    assert np.allclose(dx[-1, :6], step.at(X(K)), atol=1e-7)
    assert np.allclose(dx[-1, 6:9], step.at(V(K)), atol=1e-7)
    tr_f = np.trace(Pf[:, 3:6, 3:6], axis1=1, axis2=2)
    tr_s = np.trace(Ps[:, 3:6, 3:6], axis1=1, axis2=2)
    assert np.all(tr_f >= tr_s * (1 - 1e-9))
    assert np.mean(tr_f) > 1.2 * np.mean(tr_s)


def test_scale_and_misalignment_are_turn_noise_not_bias_jumps():
    """A 180 deg turn between straight lines: the extra gyro noise integrates to (scale * 180 deg)^2 on the turn
    axis, GYRO_MISALIGN_SHARE of (misalignment * 180 deg)^2 on the others, nothing on the straights, and the bias
    walk is unchanged."""
    from dgcal.pos.ins.error_model import ImuErrorModel
    from dgcal.pos.smoother.preintegration import GYRO_MISALIGN_SHARE, ImuSegments, interval_params
    dt = 0.5
    t = np.arange(0.0, 120.0, dt)
    w = np.where((t >= 50.0) & (t < 50.0 + np.pi / 0.4), 0.4, 0.0)  # 0.4 rad/s for pi rad, shorter than the window
    n = len(t)
    gyro = np.column_stack([np.zeros(n), np.zeros(n), w])
    accel = np.tile([0.0, 0.0, -9.8], (n, 1))
    seg = ImuSegments(gyro, accel, np.full(n, dt), np.arange(n + 1))
    noise = ImuErrorModel("test", gyro_arw=1e-4, accel_vrw=5e-4, gyro_bias_rw=1e-6, accel_bias_rw=4e-5,
                          gyro_bias_sigma=1e-4, accel_bias_sigma=2e-2, gyro_scale_sigma=5e-4, gyro_misalign_sigma=3e-4)
    ps = interval_params(noise, NavFrame(23.0, 120.0, 0.0), seg, earth_rotation=False)
    extra = np.array([np.diag(p.getGyroscopeCovariance()) - noise.gyro_arw ** 2 for p in ps])
    total = (extra * dt).sum(0)
    angle = (w * dt).sum()  # pi, to the sampling
    assert total[2] == pytest.approx((5e-4 * angle) ** 2, rel=1e-6)
    assert total[0] == pytest.approx(GYRO_MISALIGN_SHARE * (3e-4 * angle) ** 2, rel=1e-6)
    assert np.all(extra[t < 45.0] == 0) and np.all(extra[t > 50.0 + np.pi / 0.4 + 11.0] == 0)
    for p in ps:
        assert np.allclose(np.diag(p.getBiasOmegaCovariance()), noise.gyro_bias_rw ** 2)


def test_roll_in_and_out_within_the_window_make_no_turn_noise():
    """A fixed wing's roll into a 30 deg bank and out again 4 s later: the net angle within the window is zero, and
    so is the error a roll-axis scale makes after it; the turn noise follows the net angle (it counted twice the bank
    angle with the absolute rates), while a roll in without the roll out gets (scale * 30 deg)^2."""
    from dgcal.pos.ins.error_model import ImuErrorModel
    from dgcal.pos.smoother import preintegration
    from dgcal.pos.smoother.preintegration import ImuSegments, interval_params
    dt = 0.05
    t = np.arange(0.0, 60.0, dt)
    bank = np.radians(30.0)
    roll_in = (t >= 20.0) & (t < 21.0)
    roll_out = (t >= 25.0) & (t < 26.0)
    noise = ImuErrorModel("test", gyro_arw=1e-4, accel_vrw=5e-4, gyro_bias_rw=1e-6, accel_bias_rw=4e-5,
                          gyro_bias_sigma=1e-4, accel_bias_sigma=2e-2, gyro_scale_sigma=5e-4, gyro_misalign_sigma=0.0)

    def roll_axis_variance(w_x: np.ndarray) -> float:
        n = len(t)
        seg = ImuSegments(np.column_stack([w_x, np.zeros(n), np.zeros(n)]), np.tile([0.0, 0.0, -9.8], (n, 1)),
                          np.full(n, dt), np.arange(n + 1))
        ps = interval_params(noise, NavFrame(23.0, 120.0, 0.0), seg, earth_rotation=False)
        return float(sum((p.getGyroscopeCovariance()[0, 0] - noise.gyro_arw ** 2) * dt for p in ps))

    both = np.where(roll_in, bank, 0.0) - np.where(roll_out, bank, 0.0)
    one_way = np.where(roll_in, bank, 0.0)
    assert roll_axis_variance(one_way) == pytest.approx((5e-4 * bank) ** 2, rel=0.01)
    assert roll_axis_variance(both) < 0.3 * (5e-4 * bank) ** 2
    try:
        preintegration.SIGNED_TURNS = False
        assert roll_axis_variance(both) == pytest.approx(2 * 2 * (5e-4 * bank) ** 2, rel=0.01)
    finally:
        preintegration.SIGNED_TURNS = True
