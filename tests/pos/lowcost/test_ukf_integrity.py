"""Data integrity in `dgcal pos --mode ukf` (issue 16): a GNSS fix 1000 km off is rejected before the filter (as the
smoother's screening does, named by its time), and a bridged 3 s IMU gap widens the UKF's sigmas over it."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.ins.integrity import check_imu
from dgcal.pos.lowcost.ukf_pos import process_ukf
from dgcal.pos.smoother.initial import GnssFixes
from dgcal.sim.lowcost_flight import _rph_error, simulate_lowcost_flight


@pytest.fixture(scope="module")
def flight():
    return simulate_lowcost_flight(duration_s=90.0, rate_hz=100.0, gnss_hz=10.0, seed=3)


def _position_errors(res, truth):
    u = res.ukf
    return np.linalg.norm(u.p_nav - u.frame.from_ecef(truth.at(u.t).p_ecef), axis=1)


def test_a_fix_1000_km_off_is_rejected_and_named(flight):
    fx = flight.fixes
    j = int(np.searchsorted(fx.t, fx.t[0] + 50.0))
    p = fx.p_ecef.copy()
    p[j] += np.array([6.0e5, -6.0e5, 5.0e5])                       # ~1000 km
    bad = GnssFixes(fx.t, p, fx.sigma_ned, fx.v_ecef, fx.sigma_v_ned)
    clean = process_ukf(flight.imu, "adis16405", np.zeros(3), fx, compare=False, skip_s=20.0)
    res = process_ukf(flight.imu, "adis16405", np.zeros(3), bad, compare=False, skip_s=20.0)
    rej = res.summary["integrity"]["gnss_rejected"]
    assert [r["t_gps"] for r in rej] == [pytest.approx(fx.t[j])] and rej[0]["kind"] == "position"
    assert any("rejected" in w and f"{fx.t[j]:.3f}" in w for w in res.summary["warnings"])
    assert "integrity" not in clean.summary or not clean.summary["integrity"].get("gnss_rejected")
    e, e0 = _position_errors(res, flight.truth), _position_errors(clean, flight.truth)
    assert np.max(e) < np.max(e0) + 1.0                              # the filter never saw it


def test_a_bridged_imu_gap_widens_the_ukf_sigmas(flight):
    imu = flight.imu
    i0 = int(np.searchsorted(imu.t, imu.t[0] + 45.0))
    i1 = i0 + int(round(3.0 * imu.rate_hz))
    keep = np.r_[0:i0, i1:len(imu)]
    gappy, report = check_imu(ImuData(imu.t[keep], imu.dtheta[keep], imu.dvel[keep], imu.rate_hz))
    assert report.count("gap") == 1 and gappy.bridges
    # no GNSS over the gap either: the filter coasts on the bridged samples
    fx = flight.fixes
    out = (fx.t > imu.t[i0] - 0.5) & (fx.t < imu.t[i1] + 0.5)
    sub = GnssFixes(fx.t[~out], fx.p_ecef[~out], fx.sigma_ned[~out], fx.v_ecef[~out], fx.sigma_v_ned[~out])
    res = process_ukf(gappy, "adis16405", np.zeros(3), sub, compare=False, skip_s=20.0)
    plain = process_ukf(imu, "adis16405", np.zeros(3), sub, compare=False, skip_s=20.0)
    k = int(np.searchsorted(res.ukf.t, imu.t[i1] + 0.5))            # the first update after the gap
    sig = np.sqrt(np.einsum("kii->ki", res.ukf.P[:, 6:9, 6:9]))
    sig0 = np.sqrt(np.einsum("kii->ki", plain.ukf.P[:, 6:9, 6:9]))
    assert np.all(sig[k] > 1.5 * sig0[k])                             # the prediction across the gap is wider
    # and the attitude after the gap is within its sigmas
    e = np.radians(_rph_error(flight.truth, res.ukf.t[k:k + 20], res.ukf.rph_deg[k:k + 20]))
    assert np.all(np.abs(e) <= 3.0 * sig[k:k + 20])
