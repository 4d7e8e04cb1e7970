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
