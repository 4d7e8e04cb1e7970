"""IMU data in the wrong units or axes are refused by their likely cause before smoothing (issue 31): accelerations in
g, a z axis pointing up, gravity along x (axes swapped), rates in deg/s read as rad/s; plausible data pass."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.constants import G0
from dgcal.fields.errors import InputError
from dgcal.pos.ins.imu_data import ImuData
from dgcal.pos.ins.integrity import check_imu
from dgcal.pos.ins.plausibility import check_imu_units


def _imu(rate=100.0, n=3000, seed=0):
    """A level vehicle turning and accelerating gently: FRD specific force about -g along z, rates < 0.5 rad/s."""
    rng = np.random.default_rng(seed)
    t = 1e9 + np.arange(1, n + 1) / rate
    f = np.column_stack([0.5 * np.sin(t / 7), 0.8 * np.sin(t / 5), -G0 + 0.2 * np.sin(t / 3)])
    f += rng.normal(0, 0.5, f.shape)                       # vibration
    w = np.column_stack([0.05 * np.sin(t / 2), 0.05 * np.cos(t / 3), 0.4 * np.sin(t / 9)])
    return ImuData(t, w / rate, f / rate, rate)


def test_plausible_data_pass():
    check_imu_units(_imu())
    check_imu(_imu())


@pytest.mark.parametrize("change, field, words", [
    (lambda a, g: (a / G0, g), "units.accel", "in g, not m/s^2"),
    (lambda a, g: (a * 1000.0, g), "units.accel", "not near g"),
    (lambda a, g: (a * np.array([1.0, 1.0, -1.0]), g), "axes", "z points up"),
    (lambda a, g: (a[:, [2, 1, 0]], g), "axes", "gravity lies along body x"),
    (lambda a, g: (a, np.degrees(g) * 2.0), "units.gyro", "deg/s read as rad/s"),
])
def test_unit_and_axis_mistakes_are_named(change, field, words):
    imu = _imu()
    a, g = change(imu.dvel.copy(), imu.dtheta.copy())
    bad = ImuData(imu.t, g, a, imu.rate_hz, path="imu.csv")
    with pytest.raises(InputError) as exc:
        check_imu(bad)
    assert exc.value.field == field and words in str(exc.value) and "imu.csv" in str(exc.value)


def test_a_mirrored_gnss_track_is_refused_by_its_turns():
    """ECEF x and y swapped mirror the track: its turns go the other way from the gyros' (issue 31: 15,400 km off
    without a word). The simulated low-cost flight passes; mirrored (east negated) it is refused, as is a flipped
    IMU z axis."""
    from dgcal.pos.gnss_ins import track_velocity_ned
    from dgcal.pos.ins.plausibility import check_turn_sense
    from dgcal.sim.lowcost_flight import simulate_lowcost_flight
    fl = simulate_lowcost_flight(duration_s=150.0, seed=2)
    fx = fl.fixes
    v = track_velocity_ned(fx)
    check_turn_sense(fl.imu, fx.t, v)
    mirrored = v * np.array([1.0, -1.0, 1.0])
    with pytest.raises(InputError, match="opposite directions") as exc:
        check_turn_sense(fl.imu, fx.t, mirrored, "gnss.csv")
    assert "x and y swapped" in str(exc.value) and "gnss.csv" in str(exc.value)
    flipped = ImuData(fl.imu.t, fl.imu.dtheta * np.array([1.0, 1.0, -1.0]), fl.imu.dvel, fl.imu.rate_hz)
    with pytest.raises(InputError, match="opposite directions"):
        check_turn_sense(flipped, fx.t, v)
