"""Simulated low-cost logger streams (seed 000): a 50 Hz GNSS stream and a crystal-clocked logger with packet
loss, a recorded PPS, a photoresistor channel with exposure spikes, trigger commands and a laser range."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.io.csv_tables import staged_dir, write_table
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


def simulate_logger(seed: int = 0, duration_s: float = 720.0, rate_hz: float = 50.0, drift: float = 80e-6,
                    gnss_lost: int = 340, logger_lost: int = 145, n_bursts: int = 4, burst_triggers: int = 30,
                    tau: float = 0.05, blackout_s: float = 0.06, skip_prob: float = 0.08,
                    max_frames: int = 22) -> LoggerSim:
    """Simulate the streams of one flight; truth holds the clock, lost packets, exposures and skipped triggers."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t0_gps = 2150 * SECONDS_PER_WEEK + 345600.0 + rng.uniform(0, 1)  # logger time 0 in GPS time
    n_log = int(duration_s * rate_hz)
    k = np.arange(n_log)
    t_log = k * dt
    g_of = lambda tl: t0_gps + (1 + drift) * tl  # noqa: E731  GPS time of a logger time
    g = g_of(t_log)

    # GNSS stream on the GPS second grid, starting near the logger start, ending within 0.4 s of it
    end_gap = rng.uniform(-0.4, 0.4)
    gnss_t_all = np.arange(np.ceil(g[0] * rate_hz) / rate_hz + 1.0, g[-1] + end_gap, dt)
    alt = 350 + 60 * np.sin(2 * np.pi * (gnss_t_all - g[0]) / 240)
    # losses: bursts in the GNSS stream, scattered in the logger stream (first/last packets kept)
    keep_g = np.ones(len(gnss_t_all), bool)
    while (~keep_g).sum() < gnss_lost:
        s = rng.integers(1, len(gnss_t_all) - 30)
        keep_g[s:s + rng.integers(1, 25)] = False
    keep_g[[0, -1]] = True
    lost_l = rng.choice(np.arange(1, n_log - 1), logger_lost, replace=False)
    keep_l = np.ones(n_log, bool)
    keep_l[lost_l] = False

    # triggers every 0.5 s in bursts; the camera wakes late, skips some and stops after `max_frames`
    trig = np.zeros(n_log, int)
    t_exp, skipped, trig_idx = [], [], []
    starts = np.linspace(60, duration_s - 60 - burst_triggers * 0.5, n_bursts)
    for s in starts:
        ks = np.round((s + np.arange(burst_triggers) * 0.5) / dt).astype(int)
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
    photo = 1.0 + 0.05 * np.sin(2 * np.pi * t_log / 97.0)
    for te in t_exp:
        photo -= 0.5 * pulse_response(g, te, blackout_s, tau)
    photo += rng.normal(0, 0.001, n_log)  # about one LSB of a 10-bit A/D
    pps = synthetic_pps(g) + rng.normal(0, 0.02, n_log)
    h_true = np.interp(g, gnss_t_all, alt)
    laser_raw = h_true - 50.0 + rng.normal(0, 0.3, n_log)
    laser = laser_raw[(k // 5) * 5]  # 10 Hz updates held at 50 Hz
    counter = (k + 1234) % 65536
    images = [f"IMG_{i + 1:04d}.JPG" for i in range(len(t_exp))]
    image_clock = t_exp - t0_gps + 1000.0 + rng.uniform(0.3, 0.6, len(t_exp))
    truth = {"t0_gps": t0_gps, "drift": drift, "rate_hz": rate_hz, "gnss_lost": int((~keep_g).sum()),
             "logger_lost": int(logger_lost), "logger_lost_index": sorted(int(i) for i in lost_l),
             "gnss_lost_times": [float(x) for x in gnss_t_all[~keep_g]], "t_exposure": t_exp.tolist(),
             "skipped_triggers": skipped, "n_triggers": len(trig_idx), "tau": tau, "blackout_s": blackout_s,
             "images": images}
    return LoggerSim(gnss_t_all[keep_g], alt[keep_g], counter[keep_l], pps[keep_l], photo[keep_l], trig[keep_l],
                     laser[keep_l], images, image_clock, truth)


def write_logger_sim(out: Path, sim: LoggerSim) -> None:
    """Write gnss_log.csv, logger.csv, images.csv and truth.json into `out` (all or nothing)."""
    with staged_dir(out) as tmp:
        w, s = week_sow(sim.gnss_t)
        write_table(tmp / "gnss_log.csv", ["gps_week", "gps_sow", "h"],
                    ([int(w[i]), "%.3f" % s[i], "%.3f" % sim.gnss_h[i]] for i in range(len(w))))
        write_table(tmp / "logger.csv", ["counter", "pps", "photo", "trigger", "laser"],
                    ([int(sim.counter[i]), "%.4f" % sim.pps[i], "%.5f" % sim.photo[i], int(sim.trigger[i]),
                      "%.2f" % sim.laser[i]] for i in range(len(sim.counter))))
        write_table(tmp / "images.csv", ["image", "camera_time_s"],
                    ([n, "%.3f" % c] for n, c in zip(sim.images, sim.image_clock)))
        (tmp / "truth.json").write_text(json.dumps(sim.truth, indent=1))
