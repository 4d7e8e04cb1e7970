"""Restore the time axis of a logged stream after packet loss (seed 000, section 3.1).

Two clocks can stretch a stream back to its true length: GNSS time tags inside the packets,
or a free-running counter driven by the logger's crystal. Missing packets are filled with a
copy of the previous packet (the seed's choice) and flagged, so later steps can skip them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgcal.fields.errors import InputError


@dataclass
class RestoredAxis:
    """A gap-free time axis: `t` (s), `source` (index of the recorded packet filling each slot), `filled` (bool)."""

    t: np.ndarray
    source: np.ndarray
    filled: np.ndarray

    @property
    def n_lost(self) -> int:
        return int(self.filled.sum())

    def gaps(self) -> list[tuple[float, int]]:
        """(start time, number of missing packets) of every gap."""
        f = self.filled.astype(int)
        starts = np.nonzero(np.diff(np.r_[0, f]) == 1)[0]
        ends = np.nonzero(np.diff(np.r_[f, 0]) == -1)[0]
        return [(float(self.t[s]), int(e - s + 1)) for s, e in zip(starts, ends)]

    def fill(self, values: np.ndarray) -> np.ndarray:
        """Values of the recorded packets spread onto the restored axis (lost slots repeat the previous packet)."""
        return np.asarray(values)[self.source]


def _packet_error(message: str, what: str, index: int) -> InputError:
    """An InputError about recorded packet `index` (its `packet` attribute), for the reader to name the file line."""
    e = InputError(message, field=what)
    e.packet = index
    return e


def _restore(ticks: np.ndarray, what: str) -> RestoredAxis:
    """Slots from integer tick numbers of recorded packets (strictly increasing)."""
    steps = np.diff(ticks)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0)) + 1
        raise _packet_error(f"{what} does not increase at packet {i} (step {steps[i - 1]})", what, i)
    n = int(ticks[-1] - ticks[0]) + 1
    slot = (ticks - ticks[0]).astype(int)
    source = np.zeros(n, dtype=int)
    source[slot] = np.arange(len(ticks))
    # each lost slot takes the most recent recorded packet before it
    source = np.maximum.accumulate(np.where(np.isin(np.arange(n), slot), source, 0))
    filled = np.ones(n, dtype=bool)
    filled[slot] = False
    return RestoredAxis(np.arange(n, dtype=float), source, filled)


def restore_from_time_tags(t_tag: np.ndarray, dt: float) -> RestoredAxis:
    """Gap-free axis (GPS s) of a stream whose packets carry time tags `t_tag` (s) at nominal interval `dt` (s)."""
    t_tag = np.asarray(t_tag, float)
    ticks = np.round((t_tag - t_tag[0]) / dt).astype(np.int64)
    resid = (t_tag - t_tag[0]) - ticks * dt
    if np.max(np.abs(resid)) > 0.25 * dt:
        i = int(np.argmax(np.abs(resid)))
        raise _packet_error(f"time tag of packet {i} is {resid[i]:+.4f} s off the {dt} s grid", "time tag", i)
    ax = _restore(ticks, "time tag")
    ax.t = t_tag[0] + ax.t * dt
    return ax


def restore_from_counter(counter: np.ndarray, dt: float, bits: int | None = None) -> RestoredAxis:
    """Gap-free axis (logger s, from 0) of a stream whose packets carry a free-running counter.

    `bits` is the counter width for wrap-around (e.g. 16 or 32); None means it never wraps.
    """
    c = np.asarray(counter, dtype=np.int64)
    if bits is not None:
        step = np.diff(c) % (1 << bits)
        c = np.r_[0, np.cumsum(step)] + c[0]
    ax = _restore(c, "counter")
    ax.t = ax.t * dt
    return ax
