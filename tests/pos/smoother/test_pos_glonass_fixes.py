"""GLONASS in the GNSS/INS modes through their SPP fixes (lc; ukf alike): simulated multirotor flights with GPS and
GLONASS (each GLONASS satellite at its own FDMA frequency, its own receiver clock), GPS + GLONASS beside GPS alone on
the same observations, against the truth. (tc leaves GLONASS out: in a window of three satellites, two GPS and one
GLONASS, at the end of a flight its Doppler made the positions 5-6.5 sigma off; without its Doppler they held.)"""
from __future__ import annotations

import numpy as np

from dgcal.pos.gnss.spp import SppOptions
from dgcal.pos.gnss_ins import process
from dgcal.pos.smoother.batch import SmootherOptions
from dgcal.sim.pos import navigation_errors, simulate_pos


def test_lc_with_glonass_fixes_is_honest_and_helps():
    z, rms = {"G": [], "GR": []}, {"G": [], "GR": []}
    for seed, duration in ((1, 150.0), (1, 300.0), (2, 300.0)):
        sim = simulate_pos(seed=seed, duration_s=duration, rate_hz=100.0, carrier=False, systems=("G", "R"))
        assert sim.nav.glonass is not None              # the records the simulation drew, for the processing
        for systems in ("G", "GR"):
            opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                              model_errors=False, systems=tuple(systems))
            r = process("lc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                        smoother_opts=SmootherOptions(lc_velocity="true"))
            dp, _, sp, _ = navigation_errors(r.smoothed, sim.traj)
            z[systems].append(dp / sp)
            rms[systems].append(float(np.sqrt(np.mean(np.sum(dp ** 2, axis=1)))))
    zr = np.concatenate(z["GR"])
    per_axis = np.sqrt(np.mean(zr ** 2, axis=0))
    print(f"\nGPS 3D RMS {np.round(rms['G'], 3)} m, GPS+GLONASS {np.round(rms['GR'], 3)} m; error/sigma N/E/D "
          f"{per_axis.round(2)}, largest {np.abs(zr).max():.1f}")
    assert np.all((per_axis > 0.4) & (per_axis < 1.4)) and np.abs(zr).max() < 5.0
    assert np.mean(rms["GR"]) < 0.9 * np.mean(rms["G"])
