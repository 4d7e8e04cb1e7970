"""Benchmark and acceptance run of the GNSS/INS smoother (issues 4 and 12).

    python bench/pos.py                 # 1 h of 200 Hz IMU + 1 Hz GNSS, TC: wall time beside the gtsam-only peer
                                        # (the same graph built and solved with gtsam alone), median of 3 runs
    python bench/pos.py --code-errors   # the same hour with the satellites' slow code errors (code-bias states)
    python bench/pos.py --acceptance    # 20-min ADIS16488 flight, TC and LC: accuracy, sigma honesty,
                                        # smoother vs forward, 60 s with 3 satellites (several seeds)
    python bench/pos.py --carrier       # issue 12: 20-min flight, rover + base carrier phase: TC with carrier vs
                                        # LC on the same PPK positions, the 3-satellite minute (several seeds)
    python bench/pos.py --carrier --hours 1   # 1 h of 200 Hz IMU + 1 Hz rover/base TC with carrier phase:
                                        # wall time per stage and peak memory
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _cpu_s() -> float:
    """CPU seconds of this process and its joined children (dgcal forks the trajectory's densification)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _rms(x, axis=0):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


def _errors(sol, traj):
    from dgcal.sim.pos import navigation_errors
    return navigation_errors(sol, traj)


def acceptance(seeds, duration, rate):
    from dgcal.pos.gnss_ins import process
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.sim.pos import navigation_errors, simulate_pos
    for seed in seeds:
        t0 = time.time()
        sim = simulate_pos(seed=seed, duration_s=duration, rate_hz=rate)
        print(f"seed {seed}: simulated {duration:.0f} s at {rate:.0f} Hz in {time.time() - t0:.1f} s; "
              f"{len(sim.obs.epochs)} epochs, mean {np.mean([e.n for e in sim.obs.epochs]):.1f} satellites")
        opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                          model_errors=False, systems=tuple(sim.obs.signals))
        t0_out, t1_out, nmax = sim.outage
        for mode in ("tc", "lc"):
            t0 = time.time()
            r = process(mode, sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                        events=sim.events)
            wall = time.time() - t0
            for name, sol in (("smoothed", r.smoothed), ("forward", r.forward)):
                dp, dth, sp, sa = navigation_errors(sol, sim.traj)
                inside = (sol.t >= t0_out) & (sol.t <= t1_out)
                ev = ""
                if name == "smoothed":
                    te = sim.traj.at(sim.events.t)
                    d = r.events.rph - te.rph
                    d[:, 2] = (d[:, 2] + 180) % 360 - 180
                    ev = (f" | events rph RMS {np.array2string(_rms(d), precision=4)} deg, "
                          f"normalised {np.array2string(_rms(d / r.events.sigma[:, 3:]), precision=2)}")
                print(f"  {mode} {name:8s} pos 3D RMS {_rms(np.linalg.norm(dp, axis=1)):.3f} m, "
                      f"att RMS (x,y,z body) {np.array2string(np.degrees(_rms(dth)), precision=4)} deg, "
                      f"normalised pos {_rms((dp / sp).ravel()):.2f} att {_rms((dth / sa).ravel()):.2f} "
                      f"(per axis {np.array2string(_rms(dth / sa), precision=2)}), "
                      f"outage max 3D {np.max(np.linalg.norm(dp[inside], axis=1)):.2f} m "
                      f"({int(sol.gnss_update[inside].sum())} GNSS updates){ev}")
            print(f"  {mode} wall time {wall:.1f} s (SPP, smoother, forward, outputs)")


def peer_inputs(imu, sim, opts):
    """What the gtsam-only peer is handed (not timed): dgcal's front end (SPP, modelled epochs) and first problem
    taken apart into arrays: the IMU pieces between the keyframes, each interval's noise and gravity, the initial
    values, the modelled epochs at the keyframes. The peer builds and solves the same graph from them."""
    from dgcal.pos.ins.integrity import check_imu
    from dgcal.pos.gnss_ins import fixes_from_spp, tc_epochs
    from dgcal.pos.gnss.spp import spp
    from dgcal.pos.smoother.batch import SmootherOptions, setup_problem
    from dgcal.pos.smoother.factors import B, CLK, DRIFT, V, X
    from dgcal.pos.smoother.initial import initial_track
    from dgcal.pos.smoother.preintegration import rotation_compensated_accel
    imu, _ = check_imu(imu)
    sol = spp(sim.obs, sim.nav, opts)
    fixes = fixes_from_spp(sol)
    sopts = SmootherOptions(lever_arm_b=np.asarray(sim.lever_arm_b, float))
    su = setup_problem(imu, fixes, sim.grade, sopts, "tc", gnss=tc_epochs(sim.obs, sim.nav, sol, opts))
    pr = su.problem
    if pr.code_bias is not None:
        raise ValueError("the peer has no code-bias states: simulate without code errors")
    vals, K = pr.values, len(pr.t_key)
    seg = pr.seg
    ip = pr.interval_params
    p_ant, _ = initial_track(pr.t_key, su.fixes, pr.frame)
    return dict(
        t_key=pr.t_key, start=seg.start, gyro=seg.gyro, dt=seg.dt,
        accel=rotation_compensated_accel(seg.gyro, seg.accel, seg.dt),
        gyro_cov=np.array([q.getGyroscopeCovariance() for q in ip]),
        accel_cov=np.array([q.getAccelerometerCovariance() for q in ip]),
        gravity=np.array([q.n_gravity for q in ip]), integration_cov=ip[0].getIntegrationCovariance(),
        bias_acc_cov=ip[0].getBiasAccCovariance(), bias_omega_cov=ip[0].getBiasOmegaCovariance(),
        omega=ip[0].getOmegaCoriolis(),
        R=np.array([vals.atPose3(X(k)).rotation().matrix() for k in range(K)]),
        p=np.array([vals.atPose3(X(k)).translation() for k in range(K)]),
        v=np.array([vals.atPoint3(V(k)) for k in range(K)]),
        bias=np.array([vals.atConstantBias(B(k)).vector() for k in range(K)]),
        clock={s: np.array([vals.atDouble(CLK(s, k)) for k in range(K)]) for s in pr.systems},
        drift=np.array([vals.atDouble(DRIFT(k)) for k in range(K)]), systems=list(pr.systems),
        epochs=su.epochs, r_approx=pr.frame.to_ecef(p_ant), omega_b=pr.omega_b, lever=pr.lever_arm_b,
        ecef_T_nav=pr.frame.ecef_T_nav(), static=su.static, opts=sopts, noise=su.noise, problem=pr)


def gtsam_peer(d):
    """The same TC graph built and optimised with gtsam alone: a Python loop of `integrateMeasurement` over the
    IMU pieces into one PreintegratedCombinedMeasurements per keyframe interval, the TC pseudorange/Doppler/clock
    factors (dgcal's thin helpers of pos/smoother/factors.py), the priors, one LevenbergMarquardtOptimizer with
    dgcal's parameters; no covariances. Returns (seconds, values, iterations, factors)."""
    import gtsam
    from dgcal.fields.constants import C_LIGHT
    from dgcal.pos.smoother.factors import (B, CLK, DRIFT, V, X, ZERO, clock_factors, doppler_factors,
                                            pseudorange_factors)
    from dgcal.pos.smoother.static import zero_motion_factors
    t0 = time.perf_counter()
    o, K = d["opts"], len(d["t_key"])
    graph, vals = gtsam.NonlinearFactorGraph(), gtsam.Values()
    acc, gyr, dts, start = d["accel"], d["gyro"], d["dt"], d["start"]
    zero = gtsam.imuBias.ConstantBias()
    for k in range(K - 1):
        p = gtsam.PreintegrationCombinedParams.MakeSharedD(float(d["gravity"][k][2]))
        p.setGyroscopeCovariance(d["gyro_cov"][k])
        p.setAccelerometerCovariance(d["accel_cov"][k])
        p.setIntegrationCovariance(d["integration_cov"])
        p.setBiasOmegaCovariance(d["bias_omega_cov"])
        p.setBiasAccCovariance(d["bias_acc_cov"])
        if d["omega"] is not None:
            p.setOmegaCoriolis(d["omega"])
        p.n_gravity = d["gravity"][k]
        pim = gtsam.PreintegratedCombinedMeasurements(p, zero)
        for j in range(start[k], start[k + 1]):
            pim.integrateMeasurement(acc[j], gyr[j], dts[j])
        graph.add(gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pim))
    for k in range(K):
        vals.insert(X(k), gtsam.Pose3(gtsam.Rot3(d["R"][k]), d["p"][k]))
        vals.insert(V(k), d["v"][k])
        vals.insert(B(k), gtsam.imuBias.ConstantBias(d["bias"][k, :3], d["bias"][k, 3:]))
        for s in d["systems"]:
            vals.insert(CLK(s, k), float(d["clock"][s][k]))
        vals.insert(DRIFT(k), float(d["drift"][k]))
    vals.insert(ZERO(), 0.0)
    n = d["noise"]
    graph.add(gtsam.PriorFactorPose3(X(0), vals.atPose3(X(0)), gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[np.radians(o.prior_rot_sigma_deg), [o.prior_pos_sigma_m] * 3])))
    graph.add(gtsam.PriorFactorPoint3(V(0), d["v"][0], gtsam.noiseModel.Isotropic.Sigma(3, o.prior_vel_sigma_mps)))
    graph.add(gtsam.PriorFactorConstantBias(B(0), zero, gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[[n.accel_bias_sigma] * 3, [n.gyro_bias_sigma] * 3])))
    for s in d["systems"]:
        graph.add(gtsam.PriorFactorDouble(CLK(s, 0), float(d["clock"][s][0]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, 1e3 / C_LIGHT)))
    graph.add(gtsam.PriorFactorDouble(DRIFT(0), float(d["drift"][0]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, 100.0 / C_LIGHT)))
    graph.add(gtsam.PriorFactorDouble(ZERO(), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, 1e-3 / C_LIGHT)))
    t_key = d["t_key"]
    for k in range(K - 1):
        for f in clock_factors(d["systems"], k, t_key[k + 1] - t_key[k], o.clock_bias_rw_m, o.clock_drift_rw_mps, vals):
            graph.add(f)
    for k, ep in enumerate(d["epochs"]):
        if ep is None or ep.n == 0:
            continue
        for f in pseudorange_factors(k, ep, d["r_approx"][k], d["lever"], d["ecef_T_nav"], o.huber_k):
            graph.add(f)
        for f in doppler_factors(k, ep, d["r_approx"][k], d["lever"], d["omega_b"][k], d["ecef_T_nav"], o.huber_k):
            graph.add(f)
    if d["static"] is not None and d["static"].any():
        for _, _, f in zero_motion_factors(d["static"], t_key):
            graph.add(f)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(o.max_iterations)
    lm.setRelativeErrorTol(1e-5)
    lm.setAbsoluteErrorTol(1e-7)
    lm.setlambdaUpperBound(1e12)
    order = gtsam.Ordering()   # keyframe by keyframe, the pinned zero last (dgcal's ordering)
    for k in range(K):
        for key in [X(k), V(k), B(k)] + [CLK(s, k) for s in d["systems"]] + [DRIFT(k)]:
            order.push_back(key)
    order.push_back(ZERO())
    lm.setOrdering(order)
    t1 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, vals, lm)
    result = opt.optimize()
    t2 = time.perf_counter()
    d["split"] = (t1 - t0, t2 - t1)   # build, optimise
    return t2 - t0, result, opt.iterations(), graph.size()


def benchmark(hours, rate, systems, runs=3, code_errors=False):
    from dgcal.pos.ins.imu_data import ImuData
    from dgcal.pos.gnss_ins import process
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.smoother.batch import optimize
    from dgcal.pos.smoother.factors import X
    from dgcal.sim.gnss import CodeErrorModel
    from dgcal.sim.pos import simulate_pos
    t0 = time.time()
    sim = simulate_pos(seed=0, duration_s=hours * 3600.0, rate_hz=rate, systems=systems, n_strips=10,
                       strip_length_m=1000.0, strip_spacing_m=100.0, carrier=False,
                       code_errors=CodeErrorModel() if code_errors else None)
    n_sat = np.mean([e.n for e in sim.obs.epochs])
    print(f"simulated {hours * 3600:.0f} s: {len(sim.imu.t)} IMU samples at {rate:.0f} Hz, {len(sim.obs.epochs)} "
          f"GNSS epochs with {n_sat:.1f} satellites on average ({''.join(systems)}"
          f"{', slow code errors' if code_errors else ''}); {time.time() - t0:.1f} s")
    imu = ImuData(sim.imu.t.copy(), sim.imu.dtheta.copy(), sim.imu.dvel.copy(), sim.imu.rate_hz)
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=code_errors, systems=tuple(systems))
    peer = None if code_errors else peer_inputs(imu, sim, opts)
    rss0 = _rss_mb()
    dg, pe = [], []
    for i in range(runs):   # alternating, so both see the same load
        t0, c0 = time.perf_counter(), _cpu_s()
        r = process("tc", imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                    events=sim.events)          # the defaults: no forward pass (opt-in)
        dg.append((time.perf_counter() - t0, _cpu_s() - c0, r.smoothed.info["timing"]))
        if peer is not None:
            c0 = _cpu_s()
            t_peer, vals, iters, n_f = gtsam_peer(peer)
            pe.append((t_peer, _cpu_s() - c0))
        print(f"  run {i + 1}: dgcal {dg[-1][0]:.1f} s ({dg[-1][1]:.1f} s CPU)"
              + (f", gtsam-only peer {pe[-1][0]:.1f} s ({pe[-1][1]:.1f} s CPU)" if pe else "")
              + f" (load {os.getloadavg()[0]:.1f})")
    j = int(np.argsort([x[0] for x in dg])[len(dg) // 2])
    wall, cpu, timing = dg[j]
    info = r.smoothed.info
    print(f"TC smoothing of {hours:g} h, median of {runs}: dgcal {wall:.1f} s wall ({cpu:.1f} s CPU) for SPP + "
          f"smoother (2 passes) + covariances + {len(r.trajectory.t)}-row trajectory + "
          f"{len(r.events.t)} events; "
          f"{info['keyframes']} keyframes, {info['factors']} factors, LM iterations {info['lm_iterations']}")
    print(f"  dgcal stages (median run): {timing}")
    if code_errors:
        cb = r.smoothed.problem.code_bias
        print(f"  code-bias states: {sum(a1 - a0 + 1 for a0, a1 in zip(cb.k0, cb.k1))} in {len(cb)} arcs, "
              f"{cb.n_slots} slots per keyframe" if cb is not None else "  no code-bias states")
    else:
        tp = float(np.median([x[0] for x in pe]))
        cp = float(np.median([x[1] for x in pe]))
        ref = optimize(peer["problem"], peer["opts"].max_iterations)
        dmax = max(float(np.max(np.abs(vals.atPose3(X(k)).translation() - ref.atPose3(X(k)).translation())))
                   for k in range(len(peer["t_key"])))
        print(f"  gtsam-only peer (build + one LM, same graph, {n_f} factors, {iters} iterations): {tp:.1f} s "
              f"(last run: build {peer['split'][0]:.1f} s, LM {peer['split'][1]:.1f} s); "
              f"its optimum vs dgcal's first pass: max position difference {dmax:.1e} m")
        print(f"  ratio dgcal / peer: wall {wall / tp:.2f}, CPU (children included) {cpu / cp:.2f} (target <= 1.5)")
    print(f"  peak RSS {_rss_mb():.0f} MB (before the runs {rss0:.0f} MB, after simulating the data)")
    dp, dth, sp, sa = _errors(r.smoothed, sim.traj)
    print(f"  accuracy: pos 3D RMS {_rms(np.linalg.norm(dp, axis=1)):.3f} m, attitude RMS "
          f"{np.array2string(np.degrees(_rms(dth)), precision=4)} deg, normalised pos {_rms((dp / sp).ravel()):.2f} "
          f"att {_rms((dth / sa).ravel()):.2f}; NIS {r.summary.get('normalised_innovations')}")


def carrier_acceptance(seeds, duration, rate, misalignment):
    from dgcal.pos.gnss.carrier import code_observations
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import fixes_from_ppk, process
    from dgcal.sim.pos import navigation_errors, simulate_pos
    for seed in seeds:
        t0 = time.time()
        sim = simulate_pos(seed=seed, duration_s=duration, rate_hz=rate, misalignment=misalignment)
        c = sim.carrier
        print(f"seed {seed}: simulated {duration:.0f} s at {rate:.0f} Hz (triad misalignment {misalignment}) in "
              f"{time.time() - t0:.1f} s; slips {len(c.truth['slips'])}, outages {sim.outages}")
        opts = SppOptions(code_sigma_zenith_m=0.3, doppler_sigma_zenith_mps=0.1, model_errors=False,
                          systems=("G", "E"))
        t0 = time.time()
        tc = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=code_observations(c.rover), nav=sim.nav,
                     spp_opts=opts, events=sim.events, carrier=(c.rover, c.base, c.base_ecef))
        wall = time.time() - t0
        lc = process("lc", sim.imu, sim.grade, sim.lever_arm_b, lc_fixes=fixes_from_ppk(tc.carrier.ppk),
                     events=sim.events, forward=False)
        o0, o1, _ = sim.outage
        for name, r in (("TC carrier", tc), ("LC on PPK", lc)):
            sol = r.smoothed
            dp, dth, sp, sa = navigation_errors(sol, sim.traj)
            inside = (sol.t >= o0 + 1) & (sol.t <= o1 - 1)
            e = np.linalg.norm(dp, axis=1)
            print(f"  {name:10s} pos 3D RMS {100 * _rms(e):.2f} cm, att RMS (x,y,z body) "
                  f"{np.array2string(np.degrees(_rms(dth)), precision=4)} deg, "
                  f"normalised pos {_rms((dp / sp).ravel()):.2f} "
                  f"att {_rms((dth / sa).ravel()):.2f} (per axis {np.array2string(_rms(dth / sa), precision=2)}); "
                  f"3-satellite minute max {100 * e[inside].max():.1f} cm RMS {100 * _rms(e[inside]):.1f} cm")
        s = tc.summary["carrier"]
        print(f"  TC wall {wall:.1f} s {tc.smoothed.info.get('timing')}; PPK {100 * s['ppk_fix_rate']:.0f} % fixed, "
              f"TC-PPK(fixed) {100 * s['tc_minus_ppk_fixed_rms_m']:.2f} cm, DD phase residual RMS/sigma "
              f"{tc.summary['residuals']['ddp']['rms_normalised']:.2f}, NIS {tc.summary['normalised_innovations']}")


def carrier_benchmark(hours, rate):
    from dgcal.pos.gnss.carrier import code_observations
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import process
    from dgcal.sim.pos import simulate_pos
    t0 = time.time()
    sim = simulate_pos(seed=0, duration_s=hours * 3600.0, rate_hz=rate, n_strips=10, strip_length_m=1000.0,
                       strip_spacing_m=100.0, misalignment=False)
    c = sim.carrier
    print(f"simulated {hours * 3600:.0f} s: {len(sim.imu.t)} IMU samples at {rate:.0f} Hz, {len(c.rover.t_gps)} "
          f"rover/base epochs ({len(c.rover.sats)} satellites in the file, 2 frequencies); {time.time() - t0:.1f} s")
    opts = SppOptions(code_sigma_zenith_m=0.3, doppler_sigma_zenith_mps=0.1, model_errors=False, systems=("G", "E"))
    raw = code_observations(c.rover)
    rss0 = _rss_mb()
    t0, c0 = time.time(), time.process_time()
    r = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=raw, nav=sim.nav, spp_opts=opts, events=sim.events,
                carrier=(c.rover, c.base, c.base_ecef))
    wall, cpu = time.time() - t0, time.process_time() - c0
    dp, dth, sp, sa = _errors(r.smoothed, sim.traj)
    print(f"TC with carrier phase, {hours:g} h: wall {wall:.1f} s, CPU {cpu:.1f} s (load {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores); stages {r.smoothed.info.get('timing')}; front end {r.carrier.info}")
    print(f"  peak RSS {_rss_mb():.0f} MB (before the run {rss0:.0f} MB, after simulating the data)")
    print(f"  accuracy: pos 3D RMS {100 * _rms(np.linalg.norm(dp, axis=1)):.2f} cm, attitude RMS "
          f"{np.array2string(np.degrees(_rms(dth)), precision=4)} deg, normalised pos {_rms((dp / sp).ravel()):.2f} "
          f"att {_rms((dth / sa).ravel()):.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--acceptance", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=1200.0, help="acceptance flight, s")
    ap.add_argument("--rate", type=float, default=200.0, help="IMU rate, Hz")
    ap.add_argument("--hours", type=float, default=1.0, help="benchmark length, h")
    ap.add_argument("--systems", default="G",
                    help="benchmark constellations (real nav file: G, E, J); G gives ~10 satellites")
    ap.add_argument("--carrier", action="store_true", help="TC with carrier phase against a base (issue 12)")
    ap.add_argument("--misalignment", action="store_true", help="--carrier: simulate a misaligned IMU triad")
    ap.add_argument("--runs", type=int, default=3, help="benchmark: alternating runs of dgcal and the peer")
    ap.add_argument("--code-errors", action="store_true",
                    help="benchmark: the satellites' slow code errors (code-bias states on; no peer)")
    a = ap.parse_args()
    if a.carrier and "--hours" in sys.argv:
        carrier_benchmark(a.hours, a.rate)
    elif a.carrier:
        carrier_acceptance(a.seeds, a.duration, a.rate, a.misalignment)
    elif a.acceptance:
        acceptance(a.seeds, a.duration, a.rate)
    else:
        benchmark(a.hours, a.rate, tuple(a.systems), a.runs, a.code_errors)
    return 0


if __name__ == "__main__":
    sys.exit(main())
