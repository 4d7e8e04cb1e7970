"""The heading sigma of a record whose motion never determined the heading (issue 27).

A heading comes from the GNSS course (moving faster than `HEADING_SPEED_MPS`), from horizontal accelerations the
accelerometers see well above their bias, or, with nothing else, from the earth's rotation (gyrocompassing): the
gyros see the horizontal earth rate Omega cos(lat) and its direction is north. Any gyro bias along the horizontal
is indistinguishable from a heading error, so static alignment reaches sigma_psi = sigma_b / (Omega cos lat) at
best, sigma_b the gyro bias the grade leaves (turn-on and instability) with the white noise averaged over the
record. A navigation-grade IMU gyrocompasses to hundredths of a degree; a MEMS gyro (hundreds of deg/h of bias
against 10-15 deg/h of earth rate) cannot, and its heading is as good as unknown: the sigma of a heading uniform
on the circle, 180/sqrt(3) = 104 deg.

The smoother's linearised covariance misses this on such records: about a wrong heading its gyro-bias and
earth-rate terms still look informative (a static consumer-grade record gave 25-30 deg sigmas with 60-150 deg
errors). `add_heading_budget` raises the heading variance of every keyframe to at least the gyrocompassing limit
when neither a course nor large enough accelerations exist, about the nav frame's down axis (roll and pitch
unchanged).

A slow ground platform (a robot at 0.3-1.5 m/s) has no course above HEADING_SPEED_MPS, yet its straight stretches
give one: over +-5 to 20 s (TRACK_HALF_WINDOWS_S) a displacement of several fix sigmas fixes the course to a few
degrees, and on the ground the course is the heading (`track_course`). Such a record keeps the smoother's own
heading sigma (it holds there: error/sigma about 1 on simulated robots, issue 27) instead of an unknown heading's
104 deg, unless its heading disagrees with those courses beyond COURSE_DISAGREEMENT_LIMIT sigmas (a heading
drifting behind a wrong gyro bias): then the disagreement is added to its variance and the summary says so. That
check also runs where the accelerations gave the heading (a tactical grade's small accelerometer bias makes any
motion count) once a gyro bias estimate is beyond the grade's range, and then adds any disagreement (the heading's
own sigma is not to be trusted): a consumer IMU processed as tactical grade drifted 30-44 deg against the course
with a 3 deg sigma (the issue's real robot log), now a 28-41 deg sigma.
"""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import OMEGA_EARTH

HEADING_SPEED_MPS = 3.0          # the GNSS course gives the first heading above this ground speed
HEADING_UNKNOWN_SIGMA_DEG = 104.0  # a heading uniform over the circle (180/sqrt(3) deg)
# horizontal accelerations (m/s^2) beyond this many accelerometer-bias sigmas make the heading observable: a heading
# error psi turns them into a horizontal specific-force error psi*|a| the bias cannot absorb when the vehicle turns
ACCEL_OBSERVABLE_SIGMAS = 5.0
# a straight stretch of the GNSS track gives a course (= heading on the ground) when its displacement over
# +-w (one of TRACK_HALF_WINDOWS_S, the best) is TRACK_MIN_SIGMAS times the fixes' relative error: a course to
# 1/4 rad (14 deg) or better
TRACK_HALF_WINDOWS_S = (5.0, 10.0, 20.0)
TRACK_MIN_SIGMAS = 4.0
TRACK_MAX_TURN_DEG = 15.0
# heading minus course beyond this many sigmas (RMS over the straight stretches) is a heading the data contradict
COURSE_DISAGREEMENT_LIMIT = 3.0


def gyrocompass_sigma(noise, lat_deg: float, duration_s: float) -> float:
    """Heading sigma (rad) static alignment reaches with the gyro model `noise` (smoother noise: turn-on bias sigma
    rad/s, white noise rad/sqrt(s)) over `duration_s` at latitude `lat_deg`: sigma_b / (Omega cos lat), at most that
    of an unknown heading."""
    sb = float(np.hypot(noise.gyro_bias_sigma, float(noise.gyro_arw) / np.sqrt(max(duration_s, 1.0))))
    horizontal = OMEGA_EARTH * abs(np.cos(np.radians(lat_deg)))
    unknown = np.radians(HEADING_UNKNOWN_SIGMA_DEG)
    return float(min(sb / horizontal, unknown)) if horizontal > 0 else float(unknown)


def heading_from_motion(t: np.ndarray, v_nav: np.ndarray, noise) -> bool:
    """True when the motion determines the heading: a horizontal speed above HEADING_SPEED_MPS (a course), or a
    horizontal acceleration (1 s secants of the velocities v_nav m/s at times t s) beyond ACCEL_OBSERVABLE_SIGMAS
    accelerometer-bias sigmas."""
    v_h = np.hypot(v_nav[:, 0], v_nav[:, 1])
    if np.any(v_h > HEADING_SPEED_MPS):
        return True
    if len(t) < 2:
        return False
    j = np.clip(np.searchsorted(t, t + 1.0), 0, len(t) - 1)
    dt = t[j] - t
    ok = dt > 0.5
    a_h = np.linalg.norm(v_nav[j[ok], :2] - v_nav[ok, :2], axis=1) / dt[ok]
    return bool(a_h.size and a_h.max() > ACCEL_OBSERVABLE_SIGMAS * float(noise.accel_bias_sigma))


def track_course(t: np.ndarray, p_nav: np.ndarray, heading: np.ndarray, sigma_h_m: float,
                 half_windows_s: tuple[float, ...] = TRACK_HALF_WINDOWS_S) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The course of a track (t s, p_nav (K,3) m, headings rad along it) from its displacement over +-w about each
    epoch, w the one of `half_windows_s` giving the smallest sigma: (course rad, its sigma rad, usable mask).
    Usable where the displacement is at least TRACK_MIN_SIGMAS times the relative error of two fixes of horizontal
    sigma sigma_h_m (sqrt(2) sigma_h, their correlation ignored) and the heading turned less than
    TRACK_MAX_TURN_DEG over the window (a straight stretch: on the ground the course is the heading)."""
    t = np.asarray(t, float)
    rel = np.sqrt(2.0) * max(float(sigma_h_m), 1e-3)
    course, sigma = np.zeros(len(t)), np.full(len(t), np.inf)
    for w in half_windows_s:
        i0 = np.searchsorted(t, t - w)
        i1 = np.maximum(np.searchsorted(t, t + w, side="right") - 1, i0)
        d = p_nav[i1, :2] - p_nav[i0, :2]
        dist = np.hypot(d[:, 0], d[:, 1])
        turn = np.abs(np.angle(np.exp(1j * (heading[i1] - heading[i0]))))
        ok = (dist >= TRACK_MIN_SIGMAS * rel) & (turn < np.radians(TRACK_MAX_TURN_DEG)) & (t[i1] - t[i0] > w)
        s = np.where(ok, rel / np.maximum(dist, 1e-9), np.inf)
        better = s < sigma
        course[better], sigma[better] = np.arctan2(d[better, 1], d[better, 0]), s[better]
    return course, sigma, np.isfinite(sigma)


def heading_determined(sol, noise) -> bool:
    """True when the motion of a smoother solution `sol` determines its heading: `heading_from_motion`, or straight
    stretches of its track giving a course (`track_course` with the solution's median horizontal position sigma)
    over at least 10 s in all."""
    if heading_from_motion(sol.t, sol.v_nav, noise):
        return True
    _, _, ok = _solution_course(sol)
    dt = float(np.median(np.diff(sol.t))) if len(sol.t) > 1 else 0.0
    return bool(ok.sum() * dt >= 10.0)


def _solution_course(sol):
    """`track_course` of the solution's own track (positions pinned to the fixes at their sigma)."""
    if sol.cov_p_nav is not None:
        sigma_h = float(np.median(np.sqrt(np.einsum("kii->ki", sol.cov_p_nav[:, :2, :2]))))
    else:
        sigma_h = 1.0
    psi = np.arctan2(sol.R_body_to_nav[:, 1, 0], sol.R_body_to_nav[:, 0, 0])
    return track_course(sol.t, sol.p_nav, psi, sigma_h)


def course_disagreement(sol) -> tuple[float, float, int, float]:
    """The solution's heading against the course of its straight stretches (`track_course`): RMS of heading minus
    course (rad), that RMS normalised by the course's and heading's sigmas, the number of keyframes compared and
    the circular mean of heading minus course (rad: a constant offset is an IMU x axis yawed from the direction of
    travel, or a heading off by as much); all modulo 180 deg (driving backwards agrees with the heading)."""
    course, s_c, ok = _solution_course(sol)
    if not ok.any() or sol.cov_pose is None:
        return 0.0, 0.0, 0, 0.0
    psi = np.arctan2(sol.R_body_to_nav[:, 1, 0], sol.R_body_to_nav[:, 0, 0])
    # modulo 180 deg: a robot reversing (docking, backing out) has its course opposite its heading
    d = 0.5 * np.angle(np.exp(2j * (psi - course)))[ok]
    rows = heading_rows(sol.R_body_to_nav[ok])
    var_h = np.einsum("ni,nij,nj->n", rows, sol.cov_pose[ok, :3, :3], rows)
    z = d / np.sqrt(s_c[ok] ** 2 + var_h)
    mean = float(0.5 * np.angle(np.mean(np.exp(2j * d))))
    return float(np.sqrt(np.mean(d ** 2))), float(np.sqrt(np.mean(z ** 2))), int(ok.sum()), mean


def gyro_bias_beyond_grade(sol, noise) -> bool:
    """True when a gyro bias estimate of `sol` (sol.bias[:, 3:] rad/s) is beyond 3 sigma of the model `noise`'s
    turn-on bias: the motion left it unobservable, or the grade given is wrong."""
    bias = getattr(sol, "bias", None)
    return bias is not None and bool(np.abs(np.asarray(bias)[:, 3:]).max() > 3.0 * float(noise.gyro_bias_sigma))


def add_heading_budget(sol, noise) -> None:
    """On a record never faster than HEADING_SPEED_MPS raise each keyframe's heading variance (about the nav down
    axis in body coordinates, in the rotation blocks of `sol.cov_pose` and `sol.cov_block`): to at least the
    gyrocompassing limit (`gyrocompass_sigma`) when neither its accelerations nor its track give the heading
    (`heading_determined`; the floor, deg, in sol.info['heading_budget_deg']); else, unless the accelerations give
    it with gyro biases inside the grade's range (`gyro_bias_beyond_grade`), by the disagreement between
    heading and course (`course_disagreement`) when it is beyond COURSE_DISAGREEMENT_LIMIT of its sigmas (any
    disagreement once a gyro bias is beyond the grade's range)
    (sol.info['heading_course_disagreement_deg'] and the mean offset 'heading_course_offset_deg')."""
    if sol.cov_pose is None:
        return
    u_b = sol.R_body_to_nav[:, 2, :]                     # nav down in body axes: a rotation about it is heading only
    rph_rate = heading_rows(sol.R_body_to_nav)
    var_h = np.einsum("ni,nij,nj->n", rph_rate, sol.cov_pose[:, :3, :3], rph_rate)
    if np.any(np.hypot(sol.v_nav[:, 0], sol.v_nav[:, 1]) > HEADING_SPEED_MPS):
        return                                           # a course above HEADING_SPEED_MPS
    if not heading_determined(sol, noise):
        floor = gyrocompass_sigma(noise, sol.frame.lat0, float(sol.t[-1] - sol.t[0]))
        add = np.maximum(floor ** 2 - var_h, 0.0)
        sol.info["heading_budget_deg"] = round(float(np.degrees(floor)), 4)
    else:
        suspect = gyro_bias_beyond_grade(sol, noise)
        if heading_from_motion(sol.t, sol.v_nav, noise) and not suspect:
            return                  # the accelerations give the heading (a multirotor's course is not its heading)
        rms, z, n, mean = course_disagreement(sol)
        # with a gyro bias beyond the grade the heading's own sigma is not to be trusted: any disagreement counts
        if n == 0 or z <= (0.0 if suspect else COURSE_DISAGREEMENT_LIMIT):
            return
        # the heading drifts against the course (a wrong gyro bias the slow motion could not correct): its sigma
        # covers the disagreement seen
        add = np.full(len(var_h), rms ** 2)
        sol.info["heading_course_disagreement_deg"] = round(float(np.degrees(rms)), 3)
        sol.info["heading_course_offset_deg"] = round(float(np.degrees(mean)), 3)
    dC = add[:, None, None] * np.einsum("ni,nj->nij", u_b, u_b)
    for C in (sol.cov_pose, sol.cov_block):
        if C is not None:
            C[:, :3, :3] += dC


def heading_rows(R_body_to_nav: np.ndarray) -> np.ndarray:
    """d heading / d delta_theta_body (N,3) for R_body_to_nav perturbed as R Exp(delta_theta) (ZYX Euler angles)."""
    r = np.arctan2(R_body_to_nav[:, 2, 1], R_body_to_nav[:, 2, 2])
    p = -np.arcsin(np.clip(R_body_to_nav[:, 2, 0], -1.0, 1.0))
    cp = np.maximum(np.cos(p), 1e-9)
    return np.stack([np.zeros_like(r), np.sin(r) / cp, np.cos(r) / cp], -1)
