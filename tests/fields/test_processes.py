"""fields.processes.fork_map: the results of the tasks in order, the same as run here; a task that fails or
whose child dies is run again in the parent (its exception raised there)."""
from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from dgcal.fields.processes import fork_map

PARENT = os.getpid()


def _square(k: int):
    return lambda: (k * k, os.getpid())


def test_results_in_order_and_computed_in_children():
    out = fork_map([_square(k) for k in range(7)], jobs=3)
    assert [v for v, _ in out] == [k * k for k in range(7)]
    pids = {pid for _, pid in out}
    assert PARENT in pids and len(pids) == 3          # the parent's share and two children's
    assert fork_map([_square(k) for k in range(7)], jobs=1) == [(k * k, PARENT) for k in range(7)]


def test_large_results_come_back_whole():
    arrays = fork_map([lambda k=k: np.full(300_000, k, float) for k in range(4)], jobs=2)
    assert [a.shape for a in arrays] == [(300_000,)] * 4 and [a[0] for a in arrays] == [0, 1, 2, 3]


def test_a_failing_task_raises_in_the_parent():
    def bad():
        raise ValueError("no good")
    with pytest.raises(ValueError, match="no good"):
        fork_map([_square(1), bad, _square(3)], jobs=3)


def test_a_dead_child_costs_only_time():
    def dies_in_a_child():
        if os.getpid() != PARENT:
            os.kill(os.getpid(), signal.SIGKILL)
        return "here"
    assert fork_map([_square(2), dies_in_a_child], jobs=2) == [(4, PARENT), "here"]
