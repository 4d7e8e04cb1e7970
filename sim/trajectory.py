"""True UAV flights with exact, self-consistent kinematics: position, velocity, attitude, IMU signals.

A flight is built from smooth control profiles in a fixed NED tangent frame `l` at the site centre
(earth-fixed): horizontal speed V, heading rate r(t) (coordinated turns), vertical speed; each profile
is a sum of 7th-order smooth steps, so heading, height and all derivatives are analytic and only the
horizontal position needs quadrature (4-point Gauss-Legendre per IMU interval). Attitude: heading =
course (+ optional crab), pitch = flight-path angle + angle of attack, roll such that the
kinematic specific force lies in the body x-z plane (coordinated flight: atan(V r / g) in level
turns). Specific force and angular rate are derived exactly in ECEF (J2 gravitation,
earth rate, centrifugal and Coriolis terms), and the IMU increments are their integrals over each
sampling interval — what a real IMU outputs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.fields.constants import OMEGA_IE_E
from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.frames import R_ecef_to_ned, rph_from_R_body_to_ned
from dgcal.fields.io.formats import Events, Trajectory, gps_seconds
from dgcal.sim.strapdown import gravitation_ecef

_GL_X, _GL_W = np.polynomial.legendre.leggauss(4)
_GL_X = 0.5 * (_GL_X + 1.0)  # nodes on [0, 1]
_GL_W = 0.5 * _GL_W
G_NOMINAL = 9.79


class SmoothSteps:
    """f(t) = sum_j delta_j * S((t - a_j)/T_j), S the 7th-order smooth step (C3); value, rate and integral."""

    def __init__(self, a, T, delta):
        self.a, self.T, self.delta = (np.asarray(x, float) for x in (a, T, delta))
        self.e = self.a + self.T
        o = np.argsort(self.e, kind="stable")
        self._e_sorted = self.e[o]
        self._cum_d = np.concatenate([[0.0], np.cumsum(self.delta[o])])
        self._cum_dc = np.concatenate([[0.0], np.cumsum(self.delta[o] * (self.a[o] + 0.5 * self.T[o]))])

    def _active(self, t: np.ndarray):
        for j in range(len(self.a)):
            i0 = np.searchsorted(t, self.a[j], side="right")
            i1 = np.searchsorted(t, self.e[j], side="left")
            if i1 > i0:
                yield j, slice(i0, i1), (t[i0:i1] - self.a[j]) / self.T[j]

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(integral from -inf, value, first and second time derivative) at sorted times t."""
        t = np.asarray(t, float)
        n_done = np.searchsorted(self._e_sorted, t, side="right")
        val = self._cum_d[n_done].copy()
        integ = t * self._cum_d[n_done] - self._cum_dc[n_done]
        der = np.zeros_like(t)
        der2 = np.zeros_like(t)
        for j, sl, x in self._active(t):
            x2, x3 = x * x, x * x * x
            x4 = x2 * x2
            d, T = self.delta[j], self.T[j]
            val[sl] += d * x4 * (35 - 84 * x + 70 * x2 - 20 * x3)
            der[sl] += d * 140 * x3 * (1 - x) ** 3 / T
            der2[sl] += d * 420 * x2 * (1 - x) ** 2 * (1 - 2 * x) / T ** 2
            integ[sl] += d * T * x4 * x * (7 - 14 * x + 10 * x2 - 2.5 * x3)
        return integ, val, der, der2


@dataclass
class Segment:
    """A named part of the flight plan: kind 'takeoff'|'climb'|'runin'|'strip'|'runout'|'turn'|'loiter'."""

    kind: str
    t_start: float
    t_end: float
    index: int = -1
    height_agl: float = float("nan")
    heading_deg: float = float("nan")


@dataclass
class FlightProfile:
    """The analytic control profiles of a flight in the tangent frame `l` (NED at lat0, lon0, h0)."""

    lat0: float
    lon0: float
    h0: float
    t0: float
    p0_l: np.ndarray
    speed: float
    heading0: float
    turn: SmoothSteps  # heading rate, rad/s
    climb: SmoothSteps  # vertical speed (up), m/s
    aoa_rad: float = 0.0
    crab_rad: float = 0.0

    def __post_init__(self):
        self.origin_ecef = geodetic_to_ecef(self.lat0, self.lon0, self.h0)
        self.R_l_to_ecef = R_ecef_to_ned(self.lat0, self.lon0).T

    def controls(self, t: np.ndarray) -> dict:
        """Heading, rates, speeds and accelerations (l frame) at sorted absolute GPS times t."""
        tau = np.asarray(t, float) - self.t0
        psi_i, r, rdot, _ = self.turn.evaluate(tau)
        up_i, vup, vupdot, vupddot = self.climb.evaluate(tau)
        psi = self.heading0 + psi_i
        V = self.speed
        c, s = np.cos(psi), np.sin(psi)
        v_l = np.stack([V * c, V * s, -vup], -1)
        a_l = np.stack([-V * r * s, V * r * c, -vupdot], -1)
        j_l = np.stack([-V * rdot * s - V * r * r * c, V * rdot * c - V * r * r * s, -vupddot], -1)
        return dict(psi=psi, r=r, rdot=rdot, height=up_i, vup=vup, vupdot=vupdot, v_l=v_l, a_l=a_l, j_l=j_l)

    def attitude(self, c: dict) -> tuple[np.ndarray, np.ndarray]:
        """R_body_to_l (N,3,3) and omega_lb_b (N,3) rad/s from the controls."""
        V = self.speed
        th = np.arctan2(c["vup"], V) + self.aoa_rad
        thdot = V * c["vupdot"] / (V * V + c["vup"] ** 2)
        psi, psidot = c["psi"] + self.crab_rad, c["r"]
        ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
        # coordinated flight: roll puts the specific force (nominal gravity) in the body x-z plane
        f = c["a_l"] - np.array([0.0, 0.0, G_NOMINAL])
        fd = c["j_l"]
        z = np.zeros_like(cp)
        u_h = np.stack([-sp, cp, z], -1)
        u_k = np.stack([cp * st, sp * st, ct], -1)
        h = np.sum(u_h * f, -1)
        k = np.sum(u_k * f, -1)
        hdot = psidot * np.sum(np.stack([-cp, -sp, z], -1) * f, -1) + np.sum(u_h * fd, -1)
        kdot = (psidot * np.sum(np.stack([-sp * st, cp * st, z], -1) * f, -1)
                + thdot * np.sum(np.stack([cp * ct, sp * ct, -st], -1) * f, -1) + np.sum(u_k * fd, -1))
        phi = np.arctan2(h, -k)
        phidot = (h * kdot - hdot * k) / (h * h + k * k)
        cf, sf = np.cos(phi), np.sin(phi)
        R_body_to_l = np.empty(phi.shape + (3, 3))
        R_body_to_l[..., 0, 0] = cp * ct
        R_body_to_l[..., 0, 1] = cp * st * sf - sp * cf
        R_body_to_l[..., 0, 2] = cp * st * cf + sp * sf
        R_body_to_l[..., 1, 0] = sp * ct
        R_body_to_l[..., 1, 1] = sp * st * sf + cp * cf
        R_body_to_l[..., 1, 2] = sp * st * cf - cp * sf
        R_body_to_l[..., 2, 0] = -st
        R_body_to_l[..., 2, 1] = ct * sf
        R_body_to_l[..., 2, 2] = ct * cf
        w = np.stack([phidot - psidot * st, thdot * cf + psidot * sf * ct, -thdot * sf + psidot * cf * ct], -1)
        return R_body_to_l, w

    def kinematics(self, t: np.ndarray, p_l: np.ndarray) -> dict:
        """Full state at sorted times t given the tangent-frame positions p_l there (N,3)."""
        c = self.controls(t)
        R_body_to_l, w_lb = self.attitude(c)
        p_e = self.origin_ecef + p_l @ self.R_l_to_ecef.T
        v_e = c["v_l"] @ self.R_l_to_ecef.T
        a_e = c["a_l"] @ self.R_l_to_ecef.T
        R_body_to_ecef = self.R_l_to_ecef @ R_body_to_l
        f_e = (a_e + 2 * np.cross(OMEGA_IE_E, v_e) + np.cross(OMEGA_IE_E, np.cross(OMEGA_IE_E, p_e))
               - gravitation_ecef(p_e))
        f_b = np.einsum("nji,nj->ni", R_body_to_ecef, f_e)
        w_ib = w_lb + np.einsum("nji,j->ni", R_body_to_ecef, OMEGA_IE_E)
        return dict(p_ecef=p_e, v_ecef=v_e, R_body_to_ecef=R_body_to_ecef, f_b=f_b, omega_ib_b=w_ib, v_l=c["v_l"])

    def horizontal_increment(self, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
        """Integral of the l-frame horizontal velocity from ta to tb (elementwise), m; (N,2)."""
        ta, tb = np.asarray(ta, float), np.asarray(tb, float)
        nodes = (ta[:, None] + (tb - ta)[:, None] * _GL_X[None, :]).ravel()
        o = np.argsort(nodes, kind="stable")
        v = np.empty((nodes.size, 3))
        v[o] = self.controls(nodes[o])["v_l"]
        v = v.reshape(len(ta), len(_GL_X), 3)
        return np.einsum("k,nkj->nj", _GL_W, v[..., :2]) * (tb - ta)[:, None]


@dataclass
class TrueTrajectory:
    """A true flight sampled at the IMU rate; body FRD, attitude NED->body Z-Y-X (deg), GPS seconds.

    `omega_ib_b` (rad/s) and `f_b` (m/s^2) are instantaneous values at t; `dtheta` (rad) and `dvel` (m/s)
    are their exact integrals over (t[k] - 1/rate_hz, t[k]] (noise-free IMU increments).
    """

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    p_ecef: np.ndarray
    v_ecef: np.ndarray
    v_ned: np.ndarray
    R_body_to_ned: np.ndarray
    R_body_to_ecef: np.ndarray
    rph: np.ndarray
    omega_ib_b: np.ndarray
    f_b: np.ndarray
    dtheta: np.ndarray
    dvel: np.ndarray
    rate_hz: float
    segments: list = field(default_factory=list)
    profile: FlightProfile | None = field(default=None, repr=False)
    p_l: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def strips(self) -> list:
        """The 'strip' segments (straight image lines) in flight order."""
        return [s for s in self.segments if s.kind == "strip"]

    def as_trajectory(self, step: int = 1) -> Trajectory:
        """Every `step`-th sample as a `dgcal.fields.io.formats.Trajectory` (e.g. to write the true trajectory CSV)."""
        sl = slice(None, None, step)
        return Trajectory(t=self.t[sl], lat=self.lat[sl], lon=self.lon[sl], h=self.h[sl], v_ned=self.v_ned[sl],
                          rph=self.rph[sl])

    def at(self, t_query) -> "TrueTrajectory":
        """The exact true state at arbitrary GPS times (within or slightly outside the sampled span)."""
        tq = np.atleast_1d(np.asarray(t_query, float))
        o = np.argsort(tq, kind="stable")
        ts = tq[o]
        k = np.clip(np.searchsorted(self.t, ts, side="right") - 1, 0, len(self.t) - 1)
        p_l = self.p_l[k].copy()
        p_l[:, :2] += self.profile.horizontal_increment(self.t[k], ts)
        integ = self.profile.climb.evaluate(ts - self.profile.t0)[0]
        p_l[:, 2] = self.profile.p0_l[2] - integ
        out = assemble_trajectory(self.profile, ts, p_l, with_increments=False, rate_hz=self.rate_hz)
        inv = np.empty_like(o)
        inv[o] = np.arange(len(o))
        for name in ("t", "lat", "lon", "h", "p_ecef", "v_ecef", "v_ned", "R_body_to_ned", "R_body_to_ecef",
                     "rph", "omega_ib_b", "f_b", "p_l"):
            setattr(out, name, getattr(out, name)[inv])
        return out


def _kinematics_chunked(profile: FlightProfile, t: np.ndarray, p_l: np.ndarray, keys, chunk: int) -> dict:
    out = {k: [] for k in keys}
    for i0 in range(0, max(len(t), 1), chunk):     # no times: one empty chunk, so every key has its (0, ...) array
        sl = slice(i0, min(len(t), i0 + chunk))
        kin = profile.kinematics(t[sl], p_l[sl])
        for k in keys:
            out[k].append(kin[k])
    return {k: np.concatenate(v) for k, v in out.items()}


def assemble_trajectory(profile: FlightProfile, t: np.ndarray, p_l: np.ndarray, with_increments: bool, rate_hz: float,
              chunk: int = 50000) -> TrueTrajectory:
    """The true trajectory (state, specific force, rates; increments optionally) of a profile at times t (s) and
    local positions p_l (m)."""
    n = len(t)
    keys = ("p_ecef", "v_ecef", "R_body_to_ecef", "f_b", "omega_ib_b", "v_l")
    arr = _kinematics_chunked(profile, t, p_l, keys, chunk)
    dth, dvl = np.zeros((n, 3)), np.zeros((n, 3))
    if with_increments:
        # Simpson's rule over (t-dt, t] with the end values shared between neighbouring intervals: one
        # extra evaluation per sample (error ~ dt^5 * 4th derivative / 2880: < 1e-12 rad at 200 Hz)
        dt = 1.0 / rate_hz
        t_prev = np.array([t[0] - dt])
        c_prev = profile.controls(t_prev)
        p_prev = p_l[:1] - dt * 0.5 * (c_prev["v_l"] + arr["v_l"][:1])
        p_prev[:, 2] = profile.p0_l[2] - c_prev["height"]
        k_prev = profile.kinematics(t_prev, p_prev)
        pa = np.vstack([p_prev, p_l[:-1]])
        va = np.vstack([c_prev["v_l"], arr["v_l"][:-1]])
        t_mid = t - 0.5 * dt
        # positions at the midpoints by cubic Hermite (they only feed gravitation and centrifugal terms)
        p_mid = 0.5 * (pa + p_l) + dt / 8.0 * (va - arr["v_l"])
        p_mid[:, 2] = profile.p0_l[2] - profile.climb.evaluate(t_mid - profile.t0)[0]
        mid = _kinematics_chunked(profile, t_mid, p_mid, ("f_b", "omega_ib_b"), chunk)
        w_a = np.vstack([k_prev["omega_ib_b"], arr["omega_ib_b"][:-1]])
        f_a = np.vstack([k_prev["f_b"], arr["f_b"][:-1]])
        dth = dt / 6.0 * (w_a + 4.0 * mid["omega_ib_b"] + arr["omega_ib_b"])
        dvl = dt / 6.0 * (f_a + 4.0 * mid["f_b"] + arr["f_b"])
    geo = ecef_to_geodetic(arr["p_ecef"])
    R_ecef_to_local_ned = R_ecef_to_ned(geo[:, 0], geo[:, 1])
    v_ned = np.einsum("nij,nj->ni", R_ecef_to_local_ned, arr["v_ecef"])
    R_body_to_ned = R_ecef_to_local_ned @ arr["R_body_to_ecef"]
    return TrueTrajectory(t=t, lat=geo[:, 0], lon=geo[:, 1], h=geo[:, 2], p_ecef=arr["p_ecef"],
                          v_ecef=arr["v_ecef"], v_ned=v_ned, R_body_to_ned=R_body_to_ned,
                          R_body_to_ecef=arr["R_body_to_ecef"], rph=rph_from_R_body_to_ned(R_body_to_ned),
                          omega_ib_b=arr["omega_ib_b"], f_b=arr["f_b"], dtheta=dth, dvel=dvl, rate_hz=rate_hz,
                          profile=profile, p_l=p_l)


class _Planner:
    """Builds the heading-rate and climb-rate step lists from manoeuvres (ideal-geometry timing)."""

    def __init__(self, speed: float, turn_rate: float, ramp_s: float, climb_rate: float, climb_ramp_s: float):
        self.V, self.rate, self.ramp, self.climb_rate, self.climb_ramp = speed, turn_rate, ramp_s, climb_rate, \
            climb_ramp_s
        self.tc = 0.0
        self.turn_terms: list[tuple[float, float, float]] = []
        self.climb_terms: list[tuple[float, float, float]] = []
        self.segments: list[Segment] = []
        self.height = 0.0

    def straight(self, duration: float, kind: str = "straight", **kw) -> None:
        if duration > 0:
            self.segments.append(Segment(kind, self.tc, self.tc + duration, **kw))
            self.tc += duration

    def turn(self, angle: float, kind: str = "turn") -> None:
        """Turn by `angle` rad (positive = right) at the planned rate, ramps centred on the ideal switch times."""
        if angle == 0:
            return
        r = np.sign(angle) * self.rate
        dur = abs(angle) / self.rate
        self.turn_terms.append((self.tc - self.ramp / 2, self.ramp, r))
        self.turn_terms.append((self.tc + dur - self.ramp / 2, self.ramp, -r))
        self.segments.append(Segment(kind, self.tc, self.tc + dur))
        self.tc += dur

    def climb_to(self, height: float, t_start: float) -> float:
        """Schedule a climb (or descent) to `height` starting at t_start; returns its end time."""
        dh = height - self.height
        if dh == 0:
            return t_start
        v = np.sign(dh) * self.climb_rate
        dur = abs(dh) / self.climb_rate
        self.climb_terms.append((t_start, self.climb_ramp, v))
        self.climb_terms.append((t_start + dur, self.climb_ramp, -v))
        self.height = height
        return t_start + dur + self.climb_ramp

    def reversal(self, d_right: float) -> None:
        """180 deg reversal ending |d_right| m to the right (positive) or left of the current track."""
        R = self.V / self.rate
        s = 1.0 if d_right >= 0 else -1.0
        d = abs(d_right)
        if d >= 2 * R:
            self.turn(s * np.pi / 2)
            self.straight((d - 2 * R) / self.V, "turn")
            self.turn(s * np.pi / 2)
        else:  # bulb turn: out by beta, round by 180 + 2 beta, back by beta
            beta = np.arccos((d / (2 * R) + 1) / 2)
            self.turn(-s * beta)
            self.turn(s * (np.pi + 2 * beta))
            self.turn(-s * beta)

    def orbit_climb(self, height: float, direction: float, t_start: float | None = None) -> None:
        """Full circles (direction +1 right / -1 left) while climbing to `height` (climb from t_start)."""
        t_end = self.climb_to(height, self.tc + 1.0 if t_start is None else t_start)
        need = t_end - self.tc + 2.0
        n = max(1, int(np.ceil(need * self.rate / (2 * np.pi))))
        self.turn(direction * 2 * np.pi * n, "climb")


PRESETS = {
    "fixed-wing": dict(speed=25.0, bank_deg=25.0, climb_rate=3.0, aoa_deg=2.0),
    "multirotor": dict(speed=10.0, bank_deg=15.0, climb_rate=2.5, aoa_deg=-4.0),
}


def simulate_true_trajectory(kind: str = "fixed-wing", lat0: float = 23.0, lon0: float = 120.2,
                             h_ground: float = 30.0, heights_agl: tuple[float, ...] = (300.0,), n_strips: int = 4,
                             strip_length_m: float = 1000.0, strip_spacing_m: float = 200.0,
                             strip_heading_deg: float = 0.0, speed: float | None = None,
                             bank_deg: float | None = None, climb_rate: float | None = None,
                             aoa_deg: float | None = None, crab_deg: float = 0.0, margin_m: float = 150.0,
                             rate_hz: float = 200.0, gps_week: int = 2300, gps_sow: float = 200000.0,
                             duration_s: float | None = None) -> TrueTrajectory:
    """A true UAV flight: take-off, orbit climb, parallel strips in alternating headings at each height.

    Strip lines are centred on (lat0, lon0) at `strip_heading_deg` (true), `strip_spacing_m` apart; the
    aircraft flies `margin_m` straight before and after each strip. Heights are above `h_ground`
    (ellipsoidal height of the site, tangent-plane heights above it). `duration_s` pads with orbits or
    truncates. Times are continuous GPS seconds from (gps_week, gps_sow).
    """
    pre = dict(PRESETS[kind])
    for k, v in dict(speed=speed, bank_deg=bank_deg, climb_rate=climb_rate, aoa_deg=aoa_deg).items():
        if v is not None:
            pre[k] = v
    V = float(pre["speed"])
    turn_rate = G_NOMINAL * np.tan(np.radians(pre["bank_deg"])) / V
    pl = _Planner(V, turn_rate, ramp_s=2.0, climb_rate=float(pre["climb_rate"]), climb_ramp_s=3.0)
    psi_s = np.radians(strip_heading_deg)
    u = np.array([np.cos(psi_s), np.sin(psi_s)])  # along-strip (N, E)
    c = np.array([-np.sin(psi_s), np.cos(psi_s)])  # across, to the right of the first strip
    offsets = (np.arange(n_strips) - (n_strips - 1) / 2) * strip_spacing_m
    takeoff_s = 10.0
    start_xy = offsets[0] * c + (-strip_length_m / 2 - margin_m - V * takeoff_s) * u
    pl.straight(takeoff_s, "takeoff")
    heading_sign = 1.0  # +1 flying along u, -1 against
    order = list(range(n_strips))
    cur = None
    for hi, H in enumerate(heights_agl):
        if hi > 0:
            pl.straight(margin_m / V, "runout")
            pl.orbit_climb(H, direction=-heading_sign)  # orbit away from the field (left of strip 0 side)
            pl.reversal(0.0)
            heading_sign = -heading_sign
            order = order[::-1]
        else:
            pl.orbit_climb(H, direction=-1.0, t_start=3.0)
        for k, i in enumerate(order):
            if cur is not None and k > 0:
                pl.straight(margin_m / V, "runout")
                d_right = (offsets[i] - offsets[cur]) * heading_sign
                pl.reversal(d_right)
                heading_sign = -heading_sign
            pl.straight(margin_m / V, "runin")
            hd = np.degrees(psi_s) % 360.0 if heading_sign > 0 else (np.degrees(psi_s) + 180.0) % 360.0
            pl.straight(strip_length_m / V, "strip", index=i, height_agl=float(H), heading_deg=float(hd))
            cur = i
    pl.straight(margin_m / V, "runout")
    if duration_s is not None and pl.tc < duration_s:
        n_orbits = int(np.ceil((duration_s - pl.tc) * turn_rate / (2 * np.pi)))
        pl.turn(heading_sign * 2 * np.pi * n_orbits, "loiter")
    total = float(duration_s) if duration_s is not None else pl.tc
    t0 = float(gps_seconds(gps_week, gps_sow))
    ta = np.array([x[0] for x in pl.turn_terms] or [1e9])
    tt = SmoothSteps(ta, [x[1] for x in pl.turn_terms] or [1.0], [x[2] for x in pl.turn_terms] or [0.0])
    cl = SmoothSteps([x[0] for x in pl.climb_terms] or [1e9], [x[1] for x in pl.climb_terms] or [1.0],
                     [x[2] for x in pl.climb_terms] or [0.0])
    p0_l = np.array([start_xy[0], start_xy[1], 0.0])  # on the ground: l's origin is at h_ground
    profile = FlightProfile(lat0, lon0, h_ground, t0, p0_l, V, psi_s, tt, cl, np.radians(pre["aoa_deg"]),
                            np.radians(crab_deg))
    n = int(np.floor(total * rate_hz + 1e-9)) + 1
    t = t0 + np.arange(n) / rate_hz
    # horizontal positions: Gauss-Legendre per interval, summed; vertical analytic
    inc = profile.horizontal_increment(t[:-1], t[1:])
    p_l = np.zeros((n, 3))
    p_l[:, :2] = p0_l[:2] + np.vstack([np.zeros(2), np.cumsum(inc, axis=0)])
    integ = cl.evaluate(t - t0)[0]
    p_l[:, 2] = p0_l[2] - integ
    traj = assemble_trajectory(profile, t, p_l, with_increments=True, rate_hz=rate_hz)
    traj.segments = [Segment(s.kind, s.t_start + t0, min(s.t_end, total) + t0, s.index, s.height_agl,
                             s.heading_deg) for s in pl.segments if s.t_start < total]
    return traj


def camera_events(traj: TrueTrajectory, interval_s: float | None = None, distance_m: float | None = None,
                  delay_s: float = 0.0, strips_only: bool = True, prefix: str = "IMG_") -> Events:
    """Camera trigger events (GPS s) every `interval_s` or every `distance_m` along track on the strips.

    The true exposure of each event is at t_event + delay_s (seed 003's delay convention); events are
    placed so that exposures fall inside the strips.
    """
    if (interval_s is None) == (distance_m is None):
        raise ValueError("give exactly one of interval_s or distance_m")
    spans = [(s.t_start, s.t_end) for s in traj.strips] if strips_only else [(traj.t[0], traj.t[-1])]
    speed = traj.profile.speed if traj.profile is not None else float(np.median(np.linalg.norm(traj.v_ned, axis=1)))
    step = interval_s if interval_s is not None else distance_m / speed
    times = []
    for a, b in spans:
        n = int(np.floor((b - a) / step + 1e-9)) + 1
        times.append(a + np.arange(n) * step - delay_s)
    t_ev = np.concatenate(times) if times else np.zeros(0)
    t_ev = t_ev[(t_ev + delay_s >= traj.t[0]) & (t_ev + delay_s <= traj.t[-1])]
    names = np.array([f"{prefix}{k + 1:04d}.JPG" for k in range(len(t_ev))], dtype=object)
    return Events(image=names, t=t_ev)
