"""dgcal compare: a significant mounting change is detected, an unchanged one is not."""
import numpy as np

from dgcal.calib.mounting.common import MountingResult
from dgcal.fields.pose import so3_exp
from dgcal.calib.mounting.compare import compare_mountings


def _m(delay, lever, rot, sig=(1e-3, 0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4)):
    return MountingResult("proposed", np.array(lever, float), so3_exp(np.array(rot, float)), delay,
                          np.diag(np.square(sig)))


def test_unchanged_and_changed():
    rng = np.random.default_rng(0)
    a = _m(-0.14, [0.1, 0.2, 0.3], [0, 0, 0])
    false_alarms = 0
    for _ in range(200):
        n = rng.normal(0, 1, 7) * np.sqrt(2) * np.sqrt(np.diag(a.cov))
        b = _m(-0.14 + n[0], np.array([0.1, 0.2, 0.3]) + n[1:4], n[4:])
        false_alarms += compare_mountings(a, b)["changed"]
    assert false_alarms <= 8  # alpha = 1 %
    c = _m(-0.14, [0.1, 0.2, 0.3], [0, 0, np.radians(0.05)])
    r = compare_mountings(a, c)
    assert r["changed"] and abs(r["z"]["boresight_z"]) > 5
    assert abs(r["difference"]["boresight_deg"][2] - 0.05) < 1e-9


def test_fixed_delay_is_not_tested():
    a = _m(0.0, [0.1, 0.2, 0.3], [0, 0, 0], sig=(0, 0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4))
    b = _m(0.0, [0.1, 0.2, 0.3], [0, 0, 0], sig=(0, 0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4))
    r = compare_mountings(a, b)
    assert r["dof"] == 6 and "delay" in r["not_tested"] and not r["changed"]
