"""IMU data that cannot be what they claim, named by their likely cause before anything is smoothed: specific force
in g instead of m/s^2, gravity along the wrong body axis (dgcal's body frame is FRD: at rest the accelerometers read
-g along z), angular rates in deg/s read as rad/s. A smoother fed such data returns events hundreds of metres off with
decimetre sigmas; this refuses them (InputError naming the file and the description key to fix)."""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import G0
from dgcal.fields.errors import InputError

MAX_RATE_RAD_S = 35.0           # 2000 deg/s: beyond any MEMS gyro's range
TILT_LIMIT_DEG = 60.0           # the record's mean specific force this far from body -z: not an FRD body frame


def check_imu_units(imu) -> None:
    """Refuse an IMU record whose mean specific force is not near g along body -z, or whose rates exceed any gyro's
    range (`MAX_RATE_RAD_S`): the likely unit or axis mistake in the message."""
    if len(imu) < 10:
        return
    dt = np.asarray(imu.dt, float)
    ok = np.isfinite(dt) & (dt > 0)
    if ok.sum() < 10:
        return
    f = np.asarray(imu.dvel, float)[ok] / dt[ok, None]             # specific force, body FRD, m/s^2
    w = np.asarray(imu.dtheta, float)[ok] / dt[ok, None]           # rad/s
    f_mean = np.mean(f, axis=0)                                    # vibration and manoeuvres average out
    g = float(np.linalg.norm(f_mean))
    if 0.5 < g < 1.5:
        raise InputError(f"the mean specific force is {g:.3f} m/s^2, about 1 g: the accelerometers are in g, not "
                         "m/s^2 (set units.accel = \"g\" in the IMU description)", imu.path, field="units.accel")
    if not 0.5 * G0 < g < 2.0 * G0:
        raise InputError(f"the mean specific force is {g:.3g} m/s^2, not near g ({G0:.2f}): a unit or scale mistake "
                         "in the accelerometer columns (units.accel)", imu.path, field="units.accel")
    tilt = float(np.degrees(np.arccos(np.clip(-f_mean[2] / g, -1.0, 1.0))))
    if tilt > TILT_LIMIT_DEG:
        axis = "xyz"[int(np.argmax(np.abs(f_mean)))]
        why = ("z points up: dgcal's body frame is FRD (x forward, y right, z down)" if f_mean[2] > 0.5 * g else
               f"gravity lies along body {axis}: the axes are swapped, or the IMU is mounted on its side")
        raise InputError(f"at rest and on average the accelerometers should read -g along body z, these read "
                         f"{np.round(f_mean, 2).tolist()} m/s^2 ({tilt:.0f} deg from it): {why}; give the sensor "
                         "axes (axes.* in the IMU description)", imu.path, field="axes")
    rate = float(np.percentile(np.linalg.norm(w, axis=1), 99.9))
    if rate > MAX_RATE_RAD_S:
        raise InputError(f"angular rates reach {rate:.0f} rad/s ({np.degrees(rate):.0f} deg/s), beyond any gyro's "
                         "range: deg/s read as rad/s? (units.gyro)", imu.path, field="units.gyro")
