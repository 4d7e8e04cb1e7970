"""Simulated low-cost logger streams (seed 000): a 50 Hz GNSS stream and a crystal-clocked logger with packet
loss, a recorded PPS, a photoresistor channel with exposure spikes, trigger commands and a laser range.

The two recorders start and stop at different moments (the GNSS stream a few seconds after the logger; the
ends `end_gap_s` apart, within half a second by default as in the seed, up to many seconds in practice);
packets are lost at the seed's rates (340 GNSS packets in bursts and 145 logger packets scattered per
12 minutes); the aircraft's height wanders (climbs, descents, a pilot's few metres) over gently rolling
ground, which the laser sees and the GNSS height does not; a few images may have no spike (the sensor
saturated) and the camera clock (image storage times) runs at its own rate.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.io.csv_tables import staged_dir
from dgcal.fields.io.formats import week_sow
from dgcal.pos.lowcost.exposure import pulse_response
from dgcal.pos.lowcost.stream_align import synthetic_pps


@dataclass
class LoggerSim:
    """Recorded streams and their truth."""

    gnss_t: np.ndarray            # GPS time tags of the recorded GNSS packets (s)
    gnss_h: np.ndarray            # GNSS ellipsoidal height in those packets (m)
    counter: np.ndarray           # logger counter of the recorded logger packets (16-bit, wraps)
    pps: np.ndarray
    photo: np.ndarray
    trigger: np.ndarray           # 1 where the logger sent a shutter command
    laser: np.ndarray             # laser range (m), 10 Hz updates held
    images: list[str]
    image_clock: np.ndarray       # camera clock time of each image file (storage time, s)
    truth: dict = field(default_factory=dict)


def _smooth_noise(rng, t: np.ndarray, rms: float, periods_s: tuple[float, float], n: int = 24) -> np.ndarray:
    """A smooth random signal (sum of sinusoids with periods in `periods_s`, s) of the given RMS at times t (s)."""
    per = np.exp(rng.uniform(np.log(periods_s[0]), np.log(periods_s[1]), n))
    amp = rng.standard_normal(n) * np.sqrt(per / per.mean())
    ph = rng.uniform(0, 2 * np.pi, n)
    y = (amp[None, :] * np.sin(2 * np.pi * t[:, None] / per[None, :] + ph[None, :])).sum(axis=1)
    return y * rms / max(float(np.sqrt(np.mean(y ** 2))), 1e-12)


def simulate_logger(seed: int = 0, duration_s: float = 720.0, rate_hz: float = 50.0, drift: float = 80e-6,
                    gnss_lost: int | None = None, logger_lost: int | None = None, n_bursts: int | None = None,
                    burst_triggers: int = 30, tau: float = 0.05, blackout_s: float = 0.06, skip_prob: float = 0.08,
                    max_frames: int = 22, end_gap_s: float | None = None, start_gap_s: float | None = None,
                    n_no_spike: int = 0, camera_drift: float = 30e-6) -> LoggerSim:
    """Simulate the streams of one flight; truth holds the clock, lost packets, exposures and skipped triggers.

    Packet losses default to the seed's rates scaled to `duration_s` (340 GNSS and 145 logger packets per
    720 s); bursts of triggers default to one per three minutes. `end_gap_s` is the GNSS stream's end minus
    the logger's (s; default uniform within +-0.4 s), `start_gap_s` its start minus the logger's (default
    0.5-4 s); `n_no_spike` images get no spike in the light channel; `camera_drift` is the camera clock's rate
    error.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    scale = duration_s / 720.0
    gnss_lost = int(round(340 * scale)) if gnss_lost is None else int(gnss_lost)
    logger_lost = int(round(145 * scale)) if logger_lost is None else int(logger_lost)
    n_bursts = max(1, int(round(duration_s / 180.0))) if n_bursts is None else int(n_bursts)
    t0_gps = 2150 * SECONDS_PER_WEEK + 345600.0 + rng.uniform(0, 1)  # logger time 0 in GPS time
    n_log = int(duration_s * rate_hz)
    k = np.arange(n_log)
    t_log = k * dt
    g_of = lambda tl: t0_gps + (1 + drift) * tl  # noqa: E731  GPS time of a logger time
    g = g_of(t_log)

    end_gap = rng.uniform(-0.4, 0.4) if end_gap_s is None else float(end_gap_s)
    start_gap = rng.uniform(0.5, 4.0) if start_gap_s is None else float(start_gap_s)
    gnss_t_all = np.arange(np.ceil((g[0] + start_gap) * rate_hz) / rate_hz, g[-1] + end_gap, dt)
    # height: a slow climb/descent, a pilot's few metres; the laser also sees the ground roll by
    span = np.r_[gnss_t_all, g] - g[0]
    h_of = lambda tt: (350.0 + 30.0 * np.sin(2 * np.pi * tt / 240.0)  # noqa: E731
                       + _smooth_noise(np.random.default_rng(seed + 101), tt, 3.0, (2.0, 60.0), 40))
    alt_all = h_of(span)
    alt, h_true = alt_all[:len(gnss_t_all)], alt_all[len(gnss_t_all):]
    gm = _smooth_noise(np.random.default_rng(seed + 102), gnss_t_all - g[0], 0.8, (60.0, 400.0))
    gnss_h_all = alt + gm + rng.normal(0, 0.05, len(gnss_t_all))
    ground = 300.0 + _smooth_noise(np.random.default_rng(seed + 103), t_log, 1.0, (4.0, 60.0), 40)
    keep_g = np.ones(len(gnss_t_all), bool)
    gnss_lost = min(gnss_lost, len(gnss_t_all) // 3)
    while (~keep_g).sum() < gnss_lost:
        s = rng.integers(1, max(2, len(gnss_t_all) - 30))
        keep_g[s:s + rng.integers(1, 25)] = False
    keep_g[[0, -1]] = True

    # triggers every 0.5 s in bursts; the camera wakes late, skips some and stops after `max_frames`
    trig = np.zeros(n_log, int)
    t_exp, skipped, trig_idx = [], [], []
    burst_len = burst_triggers * 0.5
    margin = min(60.0, 0.2 * duration_s)
    starts = np.linspace(margin, max(margin, duration_s - margin - burst_len), n_bursts)
    for s in starts:
        ks = np.round((s + np.arange(burst_triggers) * 0.5) / dt).astype(int)
        ks = ks[ks < n_log - int(2 / dt)]
        if not len(ks):
            continue
        trig[ks] = 1
        wake = t_log[ks[0]] + rng.uniform(1.0, 1.4)
        frames = 0
        for kk in ks:
            n_before = len(trig_idx)
            trig_idx.append(kk)
            tl = t_log[kk]
            if tl < wake or frames >= max_frames or rng.random() < skip_prob:
                skipped.append(n_before)
                continue
            t_exp.append(g_of(tl + 0.2 + rng.normal(0, 0.01)))
            frames += 1
    t_exp = np.array(t_exp)
    # logger losses scattered; packets carrying a shutter command are kept so the skipped-trigger truth holds
    cand = np.setdiff1d(np.arange(1, n_log - 1), np.nonzero(trig)[0])
    lost_l = rng.choice(cand, min(logger_lost, n_log // 10), replace=False)
    keep_l = np.ones(n_log, bool)
    keep_l[lost_l] = False
    images = [f"IMG_{i + 1:04d}.JPG" for i in range(len(t_exp))]
    no_spike = np.sort(rng.choice(np.arange(1, len(t_exp)), min(n_no_spike, max(len(t_exp) - 1, 0)),
                                  replace=False)) if n_no_spike and len(t_exp) > 1 else np.zeros(0, int)
    photo = 1.0 + 0.05 * np.sin(2 * np.pi * t_log / 97.0)
    for i, te in enumerate(t_exp):
        if i not in no_spike:
            photo -= 0.5 * pulse_response(g, te, blackout_s, tau)
    photo += rng.normal(0, 0.001, n_log)  # about one LSB of a 10-bit A/D
    pps = synthetic_pps(g) + rng.normal(0, 0.02, n_log)
    laser_raw = h_true - ground + rng.normal(0, 0.3, n_log)
    laser = laser_raw[(k // 5) * 5]  # 10 Hz updates held at 50 Hz
    counter = (k + 1234) % 65536
    image_clock = (t_exp - t0_gps) * (1 + camera_drift) + 1000.0 + rng.uniform(0.3, 0.6, len(t_exp))
    truth = {"t0_gps": t0_gps, "drift": drift, "rate_hz": rate_hz, "duration_s": duration_s,
             "gnss_lost": int((~keep_g).sum()), "logger_lost": int(len(lost_l)),
             "logger_lost_index": sorted(int(i) for i in lost_l),
             "gnss_lost_times": [float(x) for x in gnss_t_all[~keep_g]], "t_exposure": t_exp.tolist(),
             "skipped_triggers": skipped, "n_triggers": len(trig_idx), "tau": tau, "blackout_s": blackout_s,
             "images": images, "end_gap_s": float(end_gap), "start_gap_s": float(start_gap),
             "no_spike_images": [images[i] for i in no_spike], "camera_drift": camera_drift}
    return LoggerSim(gnss_t_all[keep_g], gnss_h_all[keep_g], counter[keep_l], pps[keep_l], photo[keep_l],
                     trig[keep_l], laser[keep_l], images, image_clock, truth)


def write_logger_sim(out: Path, sim: LoggerSim) -> None:
    """Write gnss_log.csv, logger.csv, images.csv and truth.json into `out` (all or nothing)."""
    with staged_dir(out) as tmp:
        w, s = week_sow(sim.gnss_t)
        _write_csv(tmp / "gnss_log.csv", "gps_week,gps_sow,h",
                   [w.astype(int), s, sim.gnss_h], ["%d", "%.3f", "%.3f"])
        _write_csv(tmp / "logger.csv", "counter,pps,photo,trigger,laser",
                   [sim.counter, sim.pps, sim.photo, sim.trigger, sim.laser], ["%d", "%.4f", "%.5f", "%d", "%.2f"])
        with open(tmp / "images.csv", "w") as fh:
            fh.write("image,camera_time_s\n")
            fh.writelines(f"{n},{c:.3f}\n" for n, c in zip(sim.images, sim.image_clock))
        (tmp / "truth.json").write_text(json.dumps(sim.truth, indent=1))


def _write_csv(path: Path, header: str, cols: list, fmt: list[str]) -> None:
    """Columns (arrays) as CSV with one printf format per column."""
    np.savetxt(path, np.column_stack(cols), fmt=fmt, delimiter=",", header=header, comments="")
