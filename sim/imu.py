"""IMU simulator: true increments of a flight plus the errors of a grade (dgcal.pos.ins.error_model).

Per interval k of length dt (body FRD):
  dtheta_k = (I + S_g + M_g) dtheta_true_k + b_g(t_k) dt + arw * sqrt(dt) * n
  dvel_k   = (I + S_a + M_a) dvel_true_k   + b_a(t_k) dt + vrw * sqrt(dt) * n
with S diagonal scale factors, M skew-free (off-diagonal) misalignments, and b = turn-on constant
+ first-order Gauss-Markov in-run bias + random walk. Vectorised (the Markov recursion by blocks).
`dgcal simulate imu` writes a flight's IMU file (KF-GINS text), true trajectory, events and truth.json.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgcal.fields.io.csv_tables import atomic_write, staged_dir
from dgcal.fields.io.formats import week_sow, write_events, write_trajectory
from dgcal.pos.ins.error_model import ImuErrorModel, imu_grade
from dgcal.pos.ins.imu_data import ImuData, write_kf_gins
from dgcal.sim.trajectory import camera_events, simulate_true_trajectory


@dataclass
class ImuErrorRealisation:
    """The errors drawn for one simulated IMU from its `ImuErrorModel`: biases over time (rad/s, m/s^2) and
    the fixed scale-factor / misalignment matrices (body FRD)."""

    t: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_turn_on: np.ndarray
    accel_turn_on: np.ndarray
    gyro_scale: np.ndarray
    accel_scale: np.ndarray
    gyro_matrix: np.ndarray  # I + S + M applied to the true gyro increments
    accel_matrix: np.ndarray
    grade: ImuErrorModel  # the model they were drawn from

    def as_dict(self) -> dict:
        """Summary for truth.json (SI units; biases at the first and last sample and their means)."""
        return {"grade": self.grade.as_dict(),
                "gyro_turn_on_rad_s": self.gyro_turn_on.tolist(), "accel_turn_on_m_s2": self.accel_turn_on.tolist(),
                "gyro_bias_mean_rad_s": self.gyro_bias.mean(0).tolist(),
                "accel_bias_mean_m_s2": self.accel_bias.mean(0).tolist(),
                "gyro_scale": self.gyro_scale.tolist(), "accel_scale": self.accel_scale.tolist(),
                "gyro_matrix": self.gyro_matrix.tolist(), "accel_matrix": self.accel_matrix.tolist()}


def gauss_markov(n: int, dt: float, sigma: float, tau: float, rng: np.random.Generator, x0=None) -> np.ndarray:
    """n samples (n,3) of a stationary first-order Gauss-Markov process (std sigma, correlation time tau)."""
    if sigma <= 0 or n == 0:
        return np.zeros((n, 3))
    phi = np.exp(-dt / tau)
    q = sigma * np.sqrt(1.0 - phi * phi)
    w = rng.standard_normal((n, 3)) * q
    w[0] = rng.standard_normal(3) * sigma if x0 is None else x0
    return first_order_recursion(w, phi)


def first_order_recursion(w: np.ndarray, phi: float, block: int = 64) -> np.ndarray:
    """x[k] = phi x[k-1] + w[k] along axis 0 (x[-1] = 0; scipy.signal.lfilter([1], [1, -phi]) without importing
    scipy.signal, 0.5 s): within blocks of `block` samples a lower-triangular Toeplitz product, the state carried
    from block to block."""
    n = len(w)
    if n == 0:
        return np.zeros_like(w, dtype=float)
    B = min(block, n)
    lag = np.arange(B)[:, None] - np.arange(B)[None, :]
    T = np.where(lag >= 0, phi ** np.maximum(lag, 0), 0.0)        # response of a block to its own inputs
    decay = phi ** np.arange(1, B + 1)                            # of the state carried into it
    nb = -(-n // B)
    W = np.zeros((nb * B,) + w.shape[1:])
    W[:n] = w
    W = W.reshape((nb, B) + w.shape[1:])
    X = np.matmul(T, W.reshape(nb, B, -1)).reshape(W.shape)      # one BLAS product per block
    for b in range(1, nb):
        X[b] += decay.reshape((B,) + (1,) * (w.ndim - 1)) * X[b - 1, -1]
    return X.reshape((nb * B,) + w.shape[1:])[:n]


def _bias(n: int, dt: float, bi: float, tau: float, rw: float, rng: np.random.Generator) -> np.ndarray:
    b = gauss_markov(n, dt, bi, tau, rng)
    if rw > 0:
        b += np.cumsum(rng.standard_normal((n, 3)) * rw * np.sqrt(dt), axis=0)
    return b


def _matrix(scale_sigma: float, misalign_sigma: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    s = rng.standard_normal(3) * scale_sigma
    M = rng.standard_normal((3, 3)) * misalign_sigma
    np.fill_diagonal(M, 0.0)
    return s, np.eye(3) + np.diag(s) + M


def simulate_imu(truth, grade: str | ImuErrorModel | dict = "adis16488", seed: int = 0,
                 misalignment: bool = True) -> tuple[ImuData, ImuErrorRealisation]:
    """Noisy IMU increments (ImuData, body FRD) from a TrueTrajectory's exact increments, and the true errors."""
    g = imu_grade(grade)
    rng = np.random.default_rng(seed)
    t = np.asarray(truth.t, float)
    n = len(t)
    dt = 1.0 / float(truth.rate_hz)
    sg, Mg = _matrix(g.gyro_scale_sigma, g.gyro_misalign_sigma if misalignment else 0.0, rng)
    sa, Ma = _matrix(g.accel_scale_sigma, g.accel_misalign_sigma if misalignment else 0.0, rng)
    bg0 = rng.standard_normal(3) * g.gyro_bias_sigma
    ba0 = rng.standard_normal(3) * g.accel_bias_sigma
    bg = bg0 + _bias(n, dt, g.gyro_bias_instability, g.gyro_bias_tau_s, g.gyro_bias_rw, rng)
    ba = ba0 + _bias(n, dt, g.accel_bias_instability, g.accel_bias_tau_s, g.accel_bias_rw, rng)
    dth = truth.dtheta @ Mg.T + bg * dt + rng.standard_normal((n, 3)) * g.gyro_arw * np.sqrt(dt)
    dv = truth.dvel @ Ma.T + ba * dt + rng.standard_normal((n, 3)) * g.accel_vrw * np.sqrt(dt)
    imu = ImuData(t=t.copy(), dtheta=dth, dvel=dv, rate_hz=float(truth.rate_hz))
    return imu, ImuErrorRealisation(t=t.copy(), gyro_bias=bg, accel_bias=ba, gyro_turn_on=bg0, accel_turn_on=ba0,
                                    gyro_scale=sg, accel_scale=sa, gyro_matrix=Mg, accel_matrix=Ma, grade=g)


def simulate_imu_dataset(out: str | Path, seed: int = 0, grade: str = "adis16488", kind: str = "fixed-wing",
                         heights_agl: tuple[float, ...] = (300.0,), n_strips: int = 4, duration_s: float | None = None,
                         rate_hz: float = 200.0, truth_rate_hz: float = 10.0, event_distance_m: float = 100.0,
                         delay_s: float = 0.0, lat0: float = 23.0, lon0: float = 120.2) -> dict:
    """Write DIR/imu.txt (KF-GINS), trajectory_true.csv, events.csv and truth.json; returns the truth dict."""
    truth = simulate_true_trajectory(kind, lat0=lat0, lon0=lon0, heights_agl=tuple(heights_agl),
                                     n_strips=n_strips, rate_hz=rate_hz, duration_s=duration_s)
    imu, err = simulate_imu(truth, grade, seed=seed)
    events = camera_events(truth, distance_m=event_distance_m, delay_s=delay_s)
    week0 = int(week_sow(truth.t[0])[0])
    info = {"kind": "imu", "seed": seed, "gps_week": week0, "rate_hz": rate_hz, "platform": kind,
            "lat0": lat0, "lon0": lon0, "heights_agl": list(heights_agl), "delay_s": delay_s,
            "imu_errors": err.as_dict(), "grade_datasheet": err.grade.datasheet(),
            "segments": [{"kind": s.kind, "t_start": s.t_start, "t_end": s.t_end, "index": s.index,
                          "height_agl": s.height_agl, "heading_deg": s.heading_deg} for s in truth.segments],
            "files": {"imu": "imu.txt (KF-GINS: sow, dtheta xyz rad, dvel xyz m/s, FRD)",
                      "trajectory": "trajectory_true.csv", "events": "events.csv"}}
    step = max(1, int(round(rate_hz / truth_rate_hz)))
    with staged_dir(out) as d:
        d = Path(d)
        write_kf_gins(d / "imu.txt", imu)
        write_trajectory(d / "trajectory_true.csv", truth.as_trajectory(step))
        write_events(d / "events.csv", events)
        with atomic_write(d / "truth.json") as fh:
            json.dump(info, fh, indent=1, default=float)
    return info
