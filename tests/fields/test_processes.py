"""fields.processes.fork_map: the results of the tasks in order, the same as run here; a task that fails or
whose child dies is run again in the parent (its exception raised there)."""
from __future__ import annotations

import contextlib
import gc
import os
import resource
import signal

import numpy as np
import pytest

import dgcal.fields.processes as processes
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


def _collect_in_child():
    """Minor page faults and seconds of a full garbage collection in a forked child."""
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    gc.collect()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0


@pytest.mark.skipif(processes.cpus() < 2, reason="fork_map runs everything in this process on one CPU")
def test_a_forked_childs_collection_leaves_the_inherited_heap_shared(monkeypatch):
    """fork_map forks with the parent's objects frozen: a full collection in the child touches none of their pages
    (without the freeze it writes to every page holding an object and copies it)."""
    heap = [[i, str(i)] for i in range(500_000)]        # ~60 MB of small objects
    frozen = fork_map([lambda: 0, _collect_in_child])[1]
    monkeypatch.setattr(processes, "frozen_heap", contextlib.nullcontext)
    walked = fork_map([lambda: 0, _collect_in_child])[1]
    assert len(heap) and walked > 5000 and frozen < walked / 10
    assert gc.get_freeze_count() == 0                   # the parent's objects are collectable again
