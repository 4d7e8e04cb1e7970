"""Honest sigmas on real data (issue 12): the rtklibexplorer car drive (`../shared/data/gnss-imu-drive`), LC from
its RTK fixes with 15 s of every 45 s withheld; inside those gaps the trajectory is compared with the withheld
fixes: 3D RMS <= 0.31 m (the data set's own forward EKF with zero-velocity updates) and error / sigma RMS
between 0.7 and 1.5.

Inputs through the library: the IMU log (g, deg/s, millisecond counter + RTKLIB time tags; sensor axes -> FRD by
Z-Y-X [180, 0, 180] deg plus the mounting [0, -6.79, 5.35] deg; -0.125 s logging delay) by
`dgcal.pos.ins.imu_formats` (preset `rtklibexplorer`), the RTKLIB .pos by `dgcal.pos.gnss.solution_files`. The
IMU model is the TDK ICM-45686 datasheet's (as the data's author configured it); the smoother raises its white
noise to what the static start shows (engine vibration) and uses the static start and end as zero motion.
RTKLIB's velocities are not used here (`lc_velocity=false`): on this drive they differ from the positions'
derivative by 0.07-0.1 m/s RMS (twice their sigma) and lag by about 0.1 s; the default ("auto") measures that lag
and uses them with it removed (`test_drive_through_the_cli_defaults`).

What makes the sigmas honest (issue 27): the RTK fixes' errors are time-correlated (Gauss-Markov states,
`dgcal.pos.smoother.fix_errors`, their white share estimated: about 0.35 of RTKLIB's 1 cm) and the IMU is noisier
on the road than at rest (its white noise raised to what its factors' residuals show, about 2x the static start's
engine vibration): with the datasheet's noise raised only to the static start's, the gaps' error/sigma was
1.8/1.5/0.9 (N/E/D).
"""
from __future__ import annotations

import numpy as np
import pytest

import json
from pathlib import Path

from dgcal.cli import main
from dgcal.fields.crs import R_ecef_to_ned_at, ecef_to_geodetic
from dgcal.fields.frames import R_ecef_to_ned
from dgcal.fields.io.formats import read_trajectory
from dgcal.pos.gnss_ins import outage_mask
from dgcal.pos.ins.interpolate import interpolate_trajectory
from dgcal.pos.gnss.solution_files import read_rtklib_pos
from dgcal.pos.ins.error_model import ImuErrorModel
from dgcal.pos.ins.imu_formats import imu_format, read_imu
from dgcal.pos.gnss_ins import fixes_from_solution, process
from dgcal.pos.gnss_ins_summary import antenna_ecef
from dgcal.pos.smoother.batch import SmootherOptions


# TDK ICM-45686 as configured by the data's author (drive_config.py): noise PSDs 0.0038 deg/s/rtHz and
# 70 ug/rtHz, bias random walks 3.8e-5 deg/s/rtHz and 7 ug/rtHz; turn-on 0.1 deg/s and 10 mg; consumer-class
# scale factors (0.5 %) and misalignments (0.2 deg), not estimated (turn noise)
ICM45686 = ImuErrorModel.from_datasheet(
    "icm45686", gyro_arw_deg_rt_h=0.0038 * 60, gyro_bias_instability_deg_h=0.0,
    accel_vrw_m_s_rt_h=70e-6 * 9.80665 * 60, accel_bias_instability_mg=0.0, gyro_turn_on_deg_s=0.1,
    accel_turn_on_mg=10.0, gyro_rrw_deg_h_rt_h=3.8e-5 * 3600 * 60, accel_rrw_m_s2_rt_h=7e-6 * 9.80665 * 60,
    gyro_scale_ppm=5000.0, accel_scale_ppm=5000.0, gyro_misalign_deg=0.2, accel_misalign_deg=0.2)
LEVER_ARM_M = (0.0, -0.05, 0.0)      # IMU -> antenna, vehicle FRD
EXAMPLES = Path(__file__).resolve().parents[3] / "docs" / "examples"


def _gaps(t: np.ndarray) -> np.ndarray:
    """15 s of every 45 s from 40 s after the first fix to 30 s before the last (the source's own schedule)."""
    x = t - t[0]
    return (x >= 40.0) & (np.mod(x - 40.0, 45.0) < 15.0) & (t < t[-1] - 30.0)


def _drive_lc(shared_data, **process_kw):
    """LC on the drive's RTK fixes outside the gaps (IMU delay -125 ms, the data's own); the result and the
    withheld fixes."""
    d = shared_data / "gnss-imu-drive"
    fmt = imu_format("rtklibexplorer", ["axes.euler_zyx_deg=[180,0,180]", "axes.mounting_deg=[0,-6.79,5.35]",
                                        "axes.mounting=add"], time_offset_s=-0.125)
    imu = read_imu(d / "imu_1934.csv", fmt)
    sol = read_rtklib_pos(d / "gnss_1934_sf.pos")
    gap = _gaps(sol.t)
    res = process("lc", imu, ICM45686, LEVER_ARM_M, lc_fixes=fixes_from_solution(sol.subset(~gap)), forward=False,
                  smoother_opts=SmootherOptions(lc_velocity=False), **process_kw)
    return res, sol.subset(gap)


@pytest.fixture(scope="module")
def drive(shared_data):
    return _drive_lc(shared_data)


def _gap_errors(res, withheld):
    s = res.smoothed
    p = antenna_ecef(s, LEVER_ARM_M)
    j = np.clip(np.searchsorted(s.t, withheld.t - 1e-6), 0, len(s.t) - 1)
    ok = np.abs(s.t[j] - withheld.t) < 1e-3
    geo = ecef_to_geodetic(withheld.p_ecef[ok])
    Rn = R_ecef_to_ned(geo[:, 0], geo[:, 1])
    d = np.einsum("nij,nj->ni", Rn, p[j[ok]] - withheld.p_ecef[ok])
    Rne = s.frame.R_nav_to_ecef
    P = Rn @ (Rne @ s.cov_p_nav[j[ok]] @ Rne.T) @ np.swapaxes(Rn, 1, 2) + withheld.cov_ned[ok]
    return d, np.sqrt(np.einsum("nii->ni", P)), int(ok.sum())


def test_static_start_and_end_found(drive):
    res, _ = drive
    spans = res.smoothed.info["static_start_end_s"]
    assert len(spans) == 2 and spans[0][0] == 0.0 and spans[0][1] > 25.0 and spans[1][1] - spans[1][0] > 10.0
    # at rest the IMU is far noisier than its datasheet (engine vibration): the smoother uses what it shows
    w = res.smoothed.info["static_white_noise"]
    assert w["gyro_arw_deg_rt_h"] > 1.0 and w["accel_vrw_m_s_rt_h"] > 0.2


def test_gaps_accuracy_and_honest_sigmas(drive):
    res, withheld = drive
    d, sig, n = _gap_errors(res, withheld)
    rms3 = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
    z = float(np.sqrt(np.mean((d / sig) ** 2)))
    print(f"\n{n} withheld fixes: 3D RMS {rms3:.3f} m (N,E,D {np.sqrt(np.mean(d ** 2, axis=0)).round(3)}), "
          f"error/sigma RMS {z:.2f} (per axis {np.sqrt(np.mean((d / sig) ** 2, axis=0)).round(2)})")
    assert n > 600
    assert rms3 <= 0.31
    assert 0.7 <= z <= 1.5


def test_time_offset_on_the_drive_is_not_determinable(shared_data, drive):
    """The IMU logging delay estimated from the same fixes (outside the gaps) instead of the data author's -125 ms:
    the chi-square profile's vertex is near -214 ms with a curvature sigma of about 2 ms, but the profile split
    into time windows (block jackknife, `dgcal.pos.smoother.time_offset`) tells another story: the windows'
    offsets run from about the author's -125 ms early in the drive to below -250 ms at its end, a jackknife sigma
    near 17 ms, 9x the curvature's. A constant offset does not describe these data (errors the smoother does not
    model, or an IMU clock rate off GNSS time): the estimate is reported as not determinable, with a warning, and
    not applied; the run is the one with the -125 ms given (gaps as closed, sigmas honest)."""
    res, withheld = _drive_lc(shared_data, estimate_imu_time_offset=True)
    o = res.summary["imu_time_offset"]
    dd, sig, n = _gap_errors(res, withheld)
    rms3 = float(np.sqrt(np.mean(np.sum(dd ** 2, axis=1))))
    z = float(np.sqrt(np.mean((dd / sig) ** 2)))
    base, _ = drive
    d0, _, _ = _gap_errors(base, withheld)
    rms0 = float(np.sqrt(np.mean(np.sum(d0 ** 2, axis=1))))
    print(f"\nprofile vertex {-125.0 + o['estimate_ms']:+.1f} ms, sigma {o['sigma_ms']:.1f} (curvature "
          f"{o['formal_sigma_ms']:.1f}, jackknife {o['jackknife_sigma_ms']:.1f}), windows "
          f"{np.round(np.array(o['window_offsets_ms'], float) - 125.0)}; gaps {rms3:.3f} m (with -125 ms {rms0:.3f} m)"
          f", error/sigma {z:.2f}")
    assert -300.0 < -125.0 + o["estimate_ms"] < -150.0
    assert o["jackknife_sigma_ms"] > 5.0 * o["formal_sigma_ms"] and o["sigma_ms"] == o["jackknife_sigma_ms"]
    assert not o["determinable"] and o["offset_ms"] == 0.0
    assert any("IMU time offset not determinable" in w for w in res.summary["warnings"])
    w = np.array(o["window_offsets_ms"], float)
    assert np.nanmax(w) - np.nanmin(w) > 100.0                       # the windows disagree by a tenth of a second
    assert abs(rms3 - rms0) < 1e-3 and 0.7 <= z <= 1.5


def test_drive_through_the_cli_defaults(shared_data, tmp_path):
    """Issue 27's acceptance: the drive through `dgcal pos --mode lc` as a user runs it (the data's own files, the
    docs/examples descriptions, the data author's -125 ms, 15 s of every 45 s withheld) with every default: inside
    the gaps 3D RMS <= 0.25 m and error/sigma 0.7-1.4 on each axis (the trajectory's sigma and the withheld fix's
    own). RTKLIB's velocities are used with their measured latency (about 126 ms) removed. The largest normalised error,
    4.9, is the first withheld fix of one gap: 8 cm below the track 0.25 s after the last fix used."""
    d = shared_data / "gnss-imu-drive"
    out = tmp_path / "lc"
    assert main(["pos", "--mode", "lc", "--imu", str(d / "imu_1934.csv"), "--imu-format",
                 str(EXAMPLES / "gnss_imu_drive_imu.toml"), "--imu-time-offset", "-0.125", "--gnss",
                 str(d / "gnss_1934_sf.pos"), "--lever-arm", "0", "-0.05", "0", "--imu-grade",
                 str(EXAMPLES / "gnss_imu_drive_grade.toml"), "--gnss-outages", "40", "15", "45", "--out", str(out),
                 "--no-progress", "--no-report"]) == 0
    summary = json.loads((out / "pos_summary.json").read_text())
    sol = read_rtklib_pos(d / "gnss_1934_sf.pos")
    w = sol.subset(outage_mask(sol.t, (40.0, 15.0, 45.0)))
    tr = read_trajectory(out / "trajectory.csv")
    w = w.subset((w.t >= tr.t[0]) & (w.t <= tr.t[-1]))
    st = interpolate_trajectory(tr, w.t)
    p_ant = st.p_ecef + np.einsum("nij,j->ni", st.R_body_to_ecef, np.asarray(LEVER_ARM_M))
    dn = np.einsum("nij,nj->ni", R_ecef_to_ned_at(w.p_ecef).reshape(-1, 3, 3), p_ant - w.p_ecef)
    z = dn / np.sqrt(st.sigma[:, :3] ** 2 + np.einsum("nii->ni", w.cov_ned))
    rms3 = float(np.sqrt(np.mean(np.sum(dn ** 2, axis=1))))
    z_axes = np.sqrt(np.mean(z ** 2, axis=0))
    print(f"\n{len(dn)} withheld fixes: 3D RMS {rms3:.3f} m (N,E,D {np.sqrt(np.mean(dn ** 2, axis=0)).round(3)}), "
          f"error/sigma N,E,D {z_axes.round(2)}, largest {np.abs(z).max():.1f}")
    assert len(dn) > 600 and abs(summary["withheld_fixes"]["rms_3d_m"] - rms3) < 0.01
    assert rms3 <= 0.25
    assert np.all((z_axes >= 0.7) & (z_axes <= 1.4)), z_axes
    assert np.abs(z).max() < 6.0
    # the summary says the same (pos_summary.json withheld_fixes, what a user reads)
    np.testing.assert_allclose(summary["withheld_fixes"]["normalised_rms_ned"], z_axes, atol=0.01)
    assert summary["smoother"]["lc_velocity"] and "lc_fix_errors" in summary["smoother"]
