"""Plausibility of a mounting calibration in physical terms: inputs that cannot belong together are refused with
their likely cause (EOPs and POS kilometres apart: another zone or CRS; metres apart along the track: a time shift),
and results no payload has (a delay beyond a camera's shutter lag, a lever arm beyond an airframe) are warned or
refused; the two-step method states the delay it cannot see and what it does to its lever arm.
"""
from __future__ import annotations

import numpy as np

from dgcal.calib.mounting.common import Epochs, MountingResult
from dgcal.fields.errors import InputError, ResultError

MAX_OFFSET_M = 50.0        # EOP centres vs IMU positions: a lever arm is metres, not tens of metres
DELAY_WARN_S = 0.2         # shutter lag and trigger latency: milliseconds to 0.14 s (seed 003's platform, -0.14 s)
DELAY_REFUSE_S = 0.5       # beyond this the events and the trajectory are in different time scales
LEVER_WARN_M = 2.0         # the camera a couple of metres from the IMU on a UAV or a car roof
LEVER_REFUSE_M = 5.0


def check_epochs(ep: Epochs, source=None) -> None:
    """Refuse EOPs and POS that cannot describe the same flight: median distance between the camera centres and the
    IMU positions beyond `MAX_OFFSET_M`, named as a time shift (the offset follows the velocity) or as another
    zone / CRS / datum (it does not); InputError naming the EOP file."""
    if len(ep) == 0:
        return
    d = ep.eop.C_world - ep.pos.r_imu_world                 # world ENU, m
    dist = np.linalg.norm(d, axis=1)
    med = float(np.median(dist))
    if med <= MAX_OFFSET_M:
        return
    v = ep.pos.v_world
    speed2 = np.sum(v * v, axis=1)
    moving = speed2 > 4.0
    why = ""
    if moving.sum() >= 3:
        dt = np.sum(d[moving] * v[moving], axis=1) / speed2[moving]
        shift = float(np.median(dt))
        rest = np.linalg.norm(d[moving] - shift * v[moving], axis=1)
        if np.median(rest) < max(MAX_OFFSET_M, 0.2 * med) and abs(shift) > 0.05:
            leap = " (GPS - UTC = 18 s?)" if abs(abs(shift) - 18.0) < 1.0 else ""
            why = (f"the offset follows the track: the events or the trajectory are shifted by about {shift:+.2f} s"
                   f"{leap} (another time scale, a logger offset, a wrong week?)")
    if not why:
        dm = np.median(d, axis=0)
        why = (f"the median offset E/N/U is {dm[0]:+.0f}/{dm[1]:+.0f}/{dm[2]:+.0f} m: the EOPs in another zone, "
               "CRS or datum than the one given, or the trajectory of another flight?")
    raise InputError(f"camera centres and POS positions are {med:.0f} m apart (median over {len(ep)} images): {why}",
                     source, field="crs")


def result_warnings(res: MountingResult, ep: Epochs, refuse: bool = True) -> list[str]:
    """Warnings on a plausible but unusual result (a delay beyond `DELAY_WARN_S`, a lever arm beyond
    `LEVER_WARN_M`); ResultError beyond the refusal limits, with the likely cause (`refuse` False: warnings only,
    for the two-step method, whose lever arm takes up the delay it cannot see)."""
    out = []
    lever = float(np.linalg.norm(res.lever_arm_m))
    speed = float(np.median(np.linalg.norm(ep.pos.v_world, axis=1))) if len(ep) else 0.0
    if refuse and abs(res.delay_s) > DELAY_REFUSE_S:
        raise ResultError(f"{res.method}: exposure delay {res.delay_s:+.3f} s is beyond any camera's shutter lag "
                          f"({DELAY_REFUSE_S:g} s): the events and the trajectory are likely in different time "
                          "scales (UTC vs GPS, a logger offset); check their times", field="events")
    if refuse and lever > LEVER_REFUSE_M:
        raise ResultError(f"{res.method}: lever arm {lever:.2f} m is beyond an airframe ({LEVER_REFUSE_M:g} m): a "
                          f"time shift (at {speed:.0f} m/s, {lever / max(speed, 1e-3):.2f} s moves the camera that "
                          "far), the trajectory of another reference point, or another CRS?", field="trajectory")
    if abs(res.delay_s) > DELAY_WARN_S:
        out.append(f"exposure delay {res.delay_s:+.3f} s is longer than a camera's usual shutter lag "
                   f"({DELAY_WARN_S:g} s): check the events' time scale and the logger's offsets")
    if lever > LEVER_WARN_M:
        out.append(f"lever arm {lever:.2f} m is longer than usual ({LEVER_WARN_M:g} m): check the trajectory's "
                   "reference point (IMU, antenna) and the events' times")
    return out


def unseen_delay_warning(two_step: MountingResult, joint: MountingResult, ep: Epochs) -> str | None:
    """What the two-step method cannot see: the joint method's delay on the same data, and the along-track lever-arm
    shift it causes in the two-step result (median speed x delay), when the delay is significant (> 3 sigma)."""
    s = float(joint.sigmas[0])
    if not (np.isfinite(s) and s > 0 and abs(joint.delay_s) > 3 * s):
        return None
    speed = float(np.median(np.linalg.norm(ep.pos.v_world, axis=1)))
    shift = abs(joint.delay_s) * speed
    lever_sigma = float(np.max(two_step.sigmas[1:4])) if np.all(np.isfinite(two_step.sigmas[1:4])) else np.nan
    z = f" ({shift / lever_sigma:.0f} sigma of its own)" if np.isfinite(lever_sigma) and lever_sigma > 0 else ""
    return (f"two-step assumes no exposure delay; the joint method finds {joint.delay_s:+.4f} +- {s:.4f} s on these "
            f"data, which moves the two-step lever arm by about {shift:.2f} m along the track{z}: use joint or iso")
