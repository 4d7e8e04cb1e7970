"""The vectorised mechanisation (dgcal.pos.smoother.mechanisation) against gtsam's own preintegration and prediction,
and the densified trajectory that uses it; the linearised graph's whitened errors against gtsam's factors."""
import numpy as np
import pytest

import gtsam  # a required dependency: missing is an error, not a skip

from dgcal.pos.smoother.mechanisation import predict, preintegrate_means  # noqa: E402


@pytest.mark.parametrize("earth_rate", [False, True])
def test_means_and_prediction_equal_gtsams(earth_rate):
    """Many intervals at once, with biases, per-interval gravity, a rotating nav frame and recorded intermediate
    states: positions to 1e-9 m, velocities to 1e-10 m/s, attitude to 1e-12."""
    rng = np.random.default_rng(1)
    M, n = 12, 150
    w_ie = np.array([5.3e-5, 0.0, -4.1e-5]) if earth_rate else None
    gyro = rng.normal(0, 0.3, (M * n, 3))
    acc = rng.normal(0, 2, (M * n, 3)) + [0, 0, -9.8]
    dt = rng.uniform(0.004, 0.006, M * n)
    lane = np.repeat(np.arange(M), n)
    step = np.tile(np.arange(n), M)
    rec = (step % 25) == 24
    bg, ba = rng.normal(0, 1e-3, (M, 3)), rng.normal(0, 0.05, (M, 3))
    g = np.array([1e-3, -2e-3, 9.79]) + rng.normal(0, 1e-4, (M, 3))
    (th, pp, vv), _ = preintegrate_means(gyro - bg[lane], acc - ba[lane], dt, lane, step, M, rec)
    R0 = np.stack([gtsam.Rot3.Expmap(rng.normal(0, 1, 3)).matrix() for _ in range(M)])
    p0, v0 = rng.normal(0, 1000, (M, 3)), rng.normal(0, 20, (M, 3))
    lr = lane[rec]
    T = np.array([dt[(lane == m) & (step <= s)].sum() for m, s in zip(lr, step[rec])])
    R, P, V = predict(R0[lr], p0[lr], v0[lr], th, pp, vv, T, g[lr], w_ie)
    o = 0
    for m in range(M):
        p = gtsam.PreintegrationCombinedParams.MakeSharedD(9.79)
        p.n_gravity = g[m]
        if w_ie is not None:
            p.setOmegaCoriolis(w_ie)
        b = gtsam.imuBias.ConstantBias(ba[m], bg[m])
        pim = gtsam.PreintegratedCombinedMeasurements(p, b)
        ns = gtsam.NavState(gtsam.Rot3(R0[m]), p0[m], v0[m])
        for j in range(m * n, (m + 1) * n):
            pim.integrateMeasurement(acc[j], gyro[j], dt[j])
            if rec[j]:
                q = pim.predict(ns, b)
                assert np.abs(q.position() - P[o]).max() < 1e-9
                assert np.abs(q.velocity() - V[o]).max() < 1e-10
                assert np.abs(q.attitude().matrix() - R[o]).max() < 1e-12
                o += 1


def test_densified_trajectory_is_gtsams_prediction_between_keyframes():
    """At the keyframes the trajectory is the solution; between them it is gtsam's prediction from the keyframe
    (its bias, its interval's gravity) plus the closure spread linearly in time."""
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import process
    from dgcal.pos.smoother.output import output_times
    from dgcal.pos.smoother.preintegration import rotation_compensated_accel, split_at_keyframes
    from dgcal.sim.pos import simulate_pos
    sim = simulate_pos(seed=2, duration_s=60.0, rate_hz=50.0, carrier=False)
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=False, systems=("G", "E"))
    r = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                forward=False)
    sol, traj, pr = r.smoothed, r.trajectory, r.smoothed.problem
    t_out = output_times(sol.t, 10.0)
    assert np.array_equal(traj.t, t_out)
    key = np.searchsorted(t_out, sol.t)
    ref = r.keyframes
    assert np.allclose(traj.lat[key], ref.lat, rtol=0, atol=1e-12) and np.allclose(traj.h[key], ref.h, atol=1e-6)
    imu = sim.imu
    seg = split_at_keyframes(imu.t, imu.gyro_rad_s, imu.accel_m_s2, t_out, imu.dt[0])
    acc = rotation_compensated_accel(seg.gyro, seg.accel, seg.dt)
    k = 7
    b = gtsam.imuBias.ConstantBias(sol.bias[k, :3], sol.bias[k, 3:])
    pim = gtsam.PreintegratedCombinedMeasurements(pr.interval_params[k], b)
    ns = gtsam.NavState(gtsam.Rot3(sol.R_body_to_nav[k]), sol.p_nav[k], sol.v_nav[k])
    closure = None
    pred = []
    for i in range(key[k], key[k + 1]):
        for j in range(seg.start[i], seg.start[i + 1]):
            pim.integrateMeasurement(acc[j], seg.gyro[j], seg.dt[j])
        pred.append(pim.predict(ns, b).position())
    closure = sol.p_nav[k + 1] - pred[-1]
    w = (t_out[key[k] + 1:key[k + 1] + 1] - sol.t[k]) / (sol.t[k + 1] - sol.t[k])
    expect = sol.frame.to_ecef(np.array(pred) + w[:, None] * closure)
    from dgcal.fields.crs import geodetic_to_ecef
    got = geodetic_to_ecef(traj.lat, traj.lon, traj.h)[key[k] + 1:key[k + 1] + 1]
    assert np.abs(got - expect).max() < 1e-6


def test_whitened_errors_undo_the_huber_weights():
    """The outlier test and the residuals read each factor's whitened error from the linearised graph, where gtsam
    has scaled robust rows by sqrt(w); undone, they equal the factors' own (base-noise) whitened errors."""
    from dgcal.pos.smoother.integrity import factor_table, whitened_errors
    from dgcal.pos.smoother.linearised import keyframe_rows
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import process
    from dgcal.sim.pos import simulate_pos
    sim = simulate_pos(seed=3, duration_s=40.0, rate_hz=50.0, carrier=False)
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=False, systems=("G", "E"))
    r = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                forward=False)
    pr, vals = r.smoothed.problem, r.smoothed.values
    # move one keyframe by 5 m: its pseudoranges become Huber outliers
    bad = gtsam.Values(vals)
    x = bad.atPose3(gtsam.symbol("x", 10))
    bad.update(gtsam.symbol("x", 10), gtsam.Pose3(x.rotation(), x.translation() + np.array([5.0, 0, 0])))
    tab = factor_table(pr)
    z = whitened_errors(keyframe_rows(pr.graph, bad, pr.blocks()), tab)
    n_out = 0
    for i, kd in enumerate(tab.kinds):
        if kd is None or kd[0] not in ("pr", "dop"):
            continue
        f = pr.graph.at(i)
        nm = f.noiseModel()
        e = nm.noise().whiten(np.atleast_1d(f.unwhitenedError(bad)))
        assert z[tab.start[i]] == pytest.approx(float(e[0]), rel=1e-6, abs=1e-9)
        n_out += abs(e[0]) > tab.huber[i]
    assert n_out >= 5
