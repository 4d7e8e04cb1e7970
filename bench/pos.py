"""Benchmark and acceptance run of the GNSS/INS smoother (issues 4 and 12).

    python bench/pos.py                 # 1 h of 200 Hz IMU + 1 Hz GNSS, TC: wall time and peak memory
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


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _rms(x, axis=0):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


def _errors(sol, traj):
    from dgcal.sim.pos import navigation_errors
    return navigation_errors(sol, traj)


def acceptance(seeds, duration, rate):
    from dgcal.pos.pipeline import process
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


def benchmark(hours, rate, systems):
    from dgcal.pos.ins.imu_data import ImuData
    from dgcal.pos.pipeline import process
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.sim.pos import simulate_pos
    t0 = time.time()
    sim = simulate_pos(seed=0, duration_s=hours * 3600.0, rate_hz=rate, systems=systems, n_strips=10,
                       strip_length_m=1000.0, strip_spacing_m=100.0)
    n_sat = np.mean([e.n for e in sim.obs.epochs])
    print(f"simulated {hours * 3600:.0f} s: {len(sim.imu.t)} IMU samples at {rate:.0f} Hz, {len(sim.obs.epochs)} "
          f"GNSS epochs with {n_sat:.1f} satellites on average ({''.join(systems)}); {time.time() - t0:.1f} s")
    imu = ImuData(sim.imu.t.copy(), sim.imu.dtheta.copy(), sim.imu.dvel.copy(), sim.imu.rate_hz)
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=False, systems=tuple(systems))
    rss0 = _rss_mb()
    t0 = time.time()
    c0 = time.process_time()
    r = process("tc", imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                events=sim.events, forward=True)
    wall = time.time() - t0
    cpu = time.process_time() - c0
    load = os.getloadavg()[0]
    info = r.smoothed.info
    dp, dth, sp, sa = _errors(r.smoothed, sim.traj)
    print(f"TC smoothing of {hours:g} h: wall time {wall:.1f} s, CPU time {cpu:.1f} s (target < 60 s; load average "
          f"{load:.1f} on {os.cpu_count()} cores) for SPP + smoother (2 passes) + covariances + forward + "
          f"{len(r.trajectory.t)}-row trajectory + {len(r.events.t)} events")
    print(f"  {info['keyframes']} keyframes, {info['factors']} factors; timings {info.get('timing', {})}")
    print(f"  peak RSS {_rss_mb():.0f} MB (before the run {rss0:.0f} MB, after simulating the data)")
    print(f"  accuracy: pos 3D RMS {_rms(np.linalg.norm(dp, axis=1)):.3f} m, attitude RMS "
          f"{np.array2string(np.degrees(_rms(dth)), precision=4)} deg, normalised pos {_rms((dp / sp).ravel()):.2f} "
          f"att {_rms((dth / sa).ravel()):.2f}")


def carrier_acceptance(seeds, duration, rate, misalignment):
    from dgcal.pos.gnss.carrier import code_observations
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.pipeline import fixes_from_ppk, process
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
    from dgcal.pos.pipeline import process
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
    a = ap.parse_args()
    if a.carrier and "--hours" in sys.argv:
        carrier_benchmark(a.hours, a.rate)
    elif a.carrier:
        carrier_acceptance(a.seeds, a.duration, a.rate, a.misalignment)
    elif a.acceptance:
        acceptance(a.seeds, a.duration, a.rate)
    else:
        benchmark(a.hours, a.rate, tuple(a.systems))
    return 0


if __name__ == "__main__":
    sys.exit(main())
