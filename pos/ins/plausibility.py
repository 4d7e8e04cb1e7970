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


MIN_TURN_RATE_DEG_S = 2.0       # course rates that make a turn's sense unmistakable
MIN_TURN_EPOCHS = 10


def check_turn_sense(imu, t_fix: np.ndarray, v_ned: np.ndarray, path=None) -> None:
    """Refuse an IMU and a GNSS track that turn in opposite directions: the yaw rate the gyros measure (body z, FRD:
    positive turning right) against the GNSS course rate (from NED velocities (N,3) m/s at GPS times `t_fix`),
    over the turns faster than `MIN_TURN_RATE_DEG_S`. Opposite senses mean a mirrored track (ECEF x and y swapped,
    a sign lost) or a flipped IMU z axis; InputError naming the GNSS file."""
    t_fix, v_ned = np.asarray(t_fix, float), np.asarray(v_ned, float)
    one_per_second = np.r_[0, np.flatnonzero(np.diff(np.floor(t_fix)) > 0) + 1]     # 50 Hz fixes: noise only
    t_fix, v_ned = t_fix[one_per_second], v_ned[one_per_second]
    moving = np.hypot(v_ned[:, 0], v_ned[:, 1]) > 3.0
    k = np.flatnonzero(moving[:-1] & moving[1:] & (np.diff(t_fix) > 0) & (np.diff(t_fix) < 2.5))
    t_imu = np.asarray(imu.t, float)
    k = k[(t_fix[k] >= t_imu[0]) & (t_fix[k + 1] <= t_imu[-1])]
    if len(k) < MIN_TURN_EPOCHS:
        return
    course = np.arctan2(v_ned[:, 1], v_ned[:, 0])
    dt = t_fix[k + 1] - t_fix[k]
    course_rate = (np.angle(np.exp(1j * (course[k + 1] - course[k])))) / dt
    theta_z = np.r_[0.0, np.cumsum(np.asarray(imu.dtheta, float)[:, 2])]
    t_cum = np.r_[t_imu[0] - float(imu.dt[0]), t_imu]
    gyro_rate = (np.interp(t_fix[k + 1], t_cum, theta_z) - np.interp(t_fix[k], t_cum, theta_z)) / dt
    turning = np.abs(course_rate) > np.radians(MIN_TURN_RATE_DEG_S)
    if turning.sum() < MIN_TURN_EPOCHS:
        return
    agree = np.sign(course_rate[turning]) == np.sign(gyro_rate[turning])
    if agree.mean() < 0.2:
        raise InputError(f"the GNSS track and the IMU turn in opposite directions in {100 * (1 - agree.mean()):.0f} % "
                         f"of {int(turning.sum())} turning epochs: a mirrored track (ECEF x and y swapped, a sign "
                         "lost) or the IMU's z axis flipped", path, field="x,y,z")
