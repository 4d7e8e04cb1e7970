"""GLONASS broadcast ephemerides: RINEX records, orbit integration (GLONASS ICD), clocks and FDMA frequencies.

A GLONASS navigation record holds the satellite's position, velocity and lunisolar acceleration in PZ-90 at its
epoch ``toe`` (UTC in RINEX; kept here as continuous GPS seconds), the clock terms ``-tau_n``, ``gamma_n`` and the
frequency channel ``k``. The position at another time is integrated from the nearest healthy record (within
`MAX_AGE_S`) by fourth-order Runge-Kutta in steps of at most `STEP_S` through the ICD's equations of motion (central
term, J2, the rotating frame's centrifugal and Coriolis terms, the broadcast acceleration) - RTKLIB's and cssrlib's
``geph2pos``, vectorised over satellites. The clock is ``-tau_n + gamma_n (t - toe)`` (s). PZ-90.11 is taken as
WGS84/ITRF (they agree to a few centimetres, below the broadcast orbits' metre level). Positions and velocities are
ECEF (m, m/s) in the frame of the time given, like `dgcal.pos.gnss.ephemeris.satellite_states`.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field

import numpy as np

MU_GLO = 3.9860044e14          # m^3/s^2, PZ-90 (GLONASS ICD 5.1)
J2_GLO = 1.0826257e-3
RE_GLO = 6378136.0             # m
OMGE_GLO = 7.292115e-5         # rad/s
MAX_AGE_S = 1800.0             # |t - toe| allowed (RTKLIB's MAXDTOE_GLO; records come every 30 min)
STEP_S = 60.0                  # Runge-Kutta step (RTKLIB's TSTEP)
F1_BASE_HZ, F1_STEP_HZ = 1602.0e6, 0.5625e6
F2_BASE_HZ, F2_STEP_HZ = 1246.0e6, 0.4375e6
# GPS - UTC (s) from these UTC dates on (no leap second since 2017); RINEX GLONASS epochs are UTC
_LEAPS = ((1999, 1, 13), (2006, 1, 14), (2009, 1, 15), (2012, 7, 16), (2015, 7, 17), (2017, 1, 18))


def gps_minus_utc_s(year: int, month: int) -> int:
    """GPS - UTC leap seconds (s) in the given UTC month (from 1999 on)."""
    out = 13
    for y, m, s in _LEAPS:
        if (year, month) >= (y, m):
            out = s
    return out


def gps_seconds_from_utc(year: int, month: int, day: int, hour: int, minute: int, sec: float) -> float:
    """A UTC calendar epoch (a RINEX GLONASS record's) -> continuous GPS seconds."""
    d = _dt.datetime(year, month, day, hour, minute) - _dt.datetime(1980, 1, 6)
    return d.days * 86400.0 + d.seconds + float(sec) + gps_minus_utc_s(year, month)


def glonass_frequency_hz(k: np.ndarray | int, band: str = "1") -> np.ndarray:
    """FDMA carrier frequency (Hz) of frequency channel ``k`` on band '1' (G1: 1602 + 0.5625 k MHz) or '2' (G2:
    1246 + 0.4375 k MHz)."""
    k = np.asarray(k, float)
    if band == "1":
        return F1_BASE_HZ + F1_STEP_HZ * k
    if band == "2":
        return F2_BASE_HZ + F2_STEP_HZ * k
    raise ValueError(f"GLONASS FDMA band must be '1' or '2', not {band!r}")


@dataclass
class GlonassEphemerides:
    """GLONASS broadcast records as arrays (one row per record): ``sat`` ('R05'), ``toe`` (continuous GPS s),
    ``pos``/``vel``/``acc`` (n,3) PZ-90 m, m/s, m/s^2 at toe, ``taun`` (s), ``gamn`` (-), ``frq`` (channel k),
    ``svh`` (health, 0 = usable), ``age`` (days), ``line`` (the record's first line in its file)."""

    sat: np.ndarray
    toe: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    taun: np.ndarray
    gamn: np.ndarray
    frq: np.ndarray
    svh: np.ndarray
    age: np.ndarray
    line: np.ndarray
    _by_sat: dict = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.sat)

    @classmethod
    def from_rows(cls, rows: list[dict]) -> "GlonassEphemerides":
        """Records given as dicts of the field names (scalars; pos/vel/acc 3-vectors)."""
        def col(k, shape=()):
            return np.array([r[k] for r in rows], float).reshape((len(rows),) + shape)
        return cls(np.array([r["sat"] for r in rows], dtype=object), col("toe"), col("pos", (3,)), col("vel", (3,)),
                   col("acc", (3,)), col("taun"), col("gamn"), col("frq").astype(int), col("svh").astype(int),
                   col("age"), col("line").astype(int))

    @classmethod
    def concat(cls, parts: list["GlonassEphemerides"]) -> "GlonassEphemerides":
        """The records of several files together."""
        names = ("sat", "toe", "pos", "vel", "acc", "taun", "gamn", "frq", "svh", "age", "line")
        return cls(*(np.concatenate([getattr(p, n) for p in parts]) for n in names))

    def frequency_numbers(self) -> dict[str, int]:
        """Frequency channel k of every satellite (its latest record's)."""
        order = np.argsort(self.toe, kind="stable")
        return {str(self.sat[i]): int(self.frq[i]) for i in order}

    def records_of(self, sid: str) -> np.ndarray:
        """Row indices of one satellite's records."""
        if not self._by_sat:
            for i, s in enumerate(self.sat):
                self._by_sat.setdefault(str(s), []).append(i)
            self._by_sat = {k: np.array(v) for k, v in self._by_sat.items()}
        return self._by_sat.get(sid, np.zeros(0, int))

    def select(self, sats: list[str], t_gps: np.ndarray) -> np.ndarray:
        """Per satellite and time: the row of the healthy record with the nearest toe within `MAX_AGE_S`, or -1."""
        t_gps = np.asarray(t_gps, float)
        out = np.full(len(sats), -1)
        sats_a = np.asarray(sats, dtype=object).astype(str)
        for sid in np.unique(sats_a):
            at = np.flatnonzero(sats_a == sid)
            rec = self.records_of(str(sid))
            rec = rec[self.svh[rec] == 0] if len(rec) else rec
            if not len(rec):
                continue
            age = np.abs(t_gps[at, None] - self.toe[rec][None, :])
            j = np.argmin(age, axis=1)
            good = age[np.arange(len(at)), j] <= MAX_AGE_S
            out[at[good]] = rec[j[good]]
        return out


def _deq(x: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Time derivative (n,6) of GLONASS states x (n,6) in the rotating PZ-90 frame (ICD A.3.1.2)."""
    r = x[:, :3]
    r2 = np.sum(r * r, axis=1)
    r3 = r2 * np.sqrt(r2)
    a = 1.5 * J2_GLO * MU_GLO * RE_GLO ** 2 / r2 / r3
    b = 5.0 * x[:, 2] ** 2 / r2
    c = -MU_GLO / r3 - a * (1.0 - b)
    w2 = OMGE_GLO ** 2
    out = np.empty_like(x)
    out[:, :3] = x[:, 3:]
    out[:, 3] = (c + w2) * x[:, 0] + 2.0 * OMGE_GLO * x[:, 4]
    out[:, 4] = (c + w2) * x[:, 1] - 2.0 * OMGE_GLO * x[:, 3]
    out[:, 5] = (c - 2.0 * a) * x[:, 2]
    out[:, 3:] += acc
    return out


def integrate_orbits(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, dt_s: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (n,3) m, m/s after integrating states (pos, vel at toe; constant acc) over dt_s (n,)
    seconds (either sign): Runge-Kutta 4 in equal steps of at most `STEP_S` per row."""
    dt_s = np.asarray(dt_s, float)
    x = np.concatenate([np.asarray(pos, float), np.asarray(vel, float)], axis=1)
    if not len(dt_s):
        return x[:, :3], x[:, 3:]
    n_steps = int(np.ceil(np.max(np.abs(dt_s)) / STEP_S)) if np.any(dt_s) else 0
    if n_steps:
        h = (dt_s / n_steps)[:, None]
        for _ in range(n_steps):
            k1 = _deq(x, acc)
            k2 = _deq(x + 0.5 * h * k1, acc)
            k3 = _deq(x + 0.5 * h * k2, acc)
            k4 = _deq(x + h * k3, acc)
            x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x[:, :3], x[:, 3:]


def glonass_states(eph: GlonassEphemerides, sats: list[str], t_gps: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Broadcast states of GLONASS satellites at GPS times t_gps (s, per satellite): position (n,3) m and velocity
    (n,3) m/s ECEF, clock offset (s), clock drift (s/s) and ok (n,) (False: no healthy record within `MAX_AGE_S`,
    values NaN)."""
    n = len(sats)
    t_gps = np.array(np.broadcast_to(np.asarray(t_gps, float), (n,)))
    p, v = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    clk, drift = np.full(n, np.nan), np.full(n, np.nan)
    row = eph.select(sats, t_gps) if n else np.zeros(0, int)
    ok = row >= 0
    if ok.any():
        r = row[ok]
        dt = t_gps[ok] - eph.toe[r]
        p[ok], v[ok] = integrate_orbits(eph.pos[r], eph.vel[r], eph.acc[r], dt)
        clk[ok] = -eph.taun[r] + eph.gamn[r] * dt
        drift[ok] = eph.gamn[r]
    return p, v, clk, drift, ok

