"""fields.processes.fork_map: the results of the tasks in order, the same as run here, each task taken by the
first process free; a task that fails or whose child dies is run again in the parent (its exception raised there).
forked_call: one call in a child beside the parent's own work, with the same fallbacks."""
from __future__ import annotations

import contextlib
import gc
import os
import resource
import signal
import time

import numpy as np
import pytest

import dgcal.fields.processes as processes
from dgcal.fields.processes import fork_map, forked_call

PARENT = os.getpid()


def _square(k: int, seconds: float = 0.0):
    def task():
        time.sleep(seconds)
        return k * k, os.getpid()
    return task


def _together(n: int):
    """A barrier of `n` processes: a task that passes it was taken while every process held one (so the test does
    not depend on how fast the host starts a child)."""
    return processes.multiprocessing.get_context("fork").Barrier(n, timeout=60)


def _after(barrier, task):
    def wait_then_run():
        barrier.wait()
        return task()
    return wait_then_run


def test_results_in_order_and_computed_in_children():
    met = _together(3)
    out = fork_map([_after(met, _square(k)) for k in range(3)] + [_square(k) for k in range(3, 7)], jobs=3)
    assert [v for v, _ in out] == [k * k for k in range(7)]
    pids = {pid for _, pid in out}
    assert PARENT in pids and len(pids) == 3          # the parent's share and two children's
    assert fork_map([_square(k) for k in range(7)], jobs=1) == [(k * k, PARENT) for k in range(7)]


def test_tasks_of_unequal_cost_share_out_evenly():
    """Each process takes the next task when it is free: the one that took the long task runs nothing else (a
    fixed round robin would give it two of the short ones as well). The long task lasts until the four short ones
    are done, so the test does not depend on how fast the host starts a child."""
    done = processes.multiprocessing.get_context("fork").Semaphore(0)

    def short(k):
        def task():
            done.release()
            return k * k, os.getpid()
        return task

    def long():
        for _ in range(4):
            assert done.acquire(timeout=60), "the short tasks were not run beside the long one"
        return 0, os.getpid()
    out = fork_map([long] + [short(k) for k in range(1, 5)], jobs=2)
    assert [v for v, _ in out] == [0, 1, 4, 9, 16]
    long_pid, short_pids = out[0][1], {pid for _, pid in out[1:]}
    assert short_pids == {next(iter(short_pids))} and long_pid not in short_pids


def test_large_results_come_back_whole():
    arrays = fork_map([lambda k=k: np.full(300_000, k, float) for k in range(4)], jobs=2)
    assert [a.shape for a in arrays] == [(300_000,)] * 4 and [a[0] for a in arrays] == [0, 1, 2, 3]


def test_a_failing_task_raises_in_the_parent():
    def bad():
        raise ValueError("no good")
    with pytest.raises(ValueError, match="no good"):
        fork_map([_square(1), bad, _square(3)], jobs=3)


def test_a_dead_child_costs_only_time():
    """The child dies in whichever task it takes; the parent runs that task again. The parent's own task waits until
    the child has taken one (a child that starts late must not find both tasks done)."""
    took = processes.multiprocessing.get_context("fork").Event()

    def dies_in_a_child(k: int):
        def task():
            if os.getpid() != PARENT:
                took.set()
                os.kill(os.getpid(), signal.SIGKILL)
            assert took.wait(timeout=60), "no child took a task"
            return k * k, os.getpid()
        return task
    assert fork_map([dies_in_a_child(2), dies_in_a_child(3)], jobs=2) == [(4, PARENT), (9, PARENT)]


def _collect_in_child():
    """Minor page faults of a full garbage collection in a forked child."""
    assert os.getpid() != PARENT
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    gc.collect()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0


@pytest.mark.skipif(processes.cpus() < 2, reason="fork_map runs everything in this process on one CPU")
def test_a_forked_childs_collection_leaves_the_inherited_heap_shared(monkeypatch):
    """fork_map forks with the parent's objects frozen: a full collection in the child touches none of their pages
    (without the freeze it writes to every page holding an object and copies it)."""
    heap = [[i, str(i)] for i in range(500_000)]        # ~60 MB of small objects
    def collected():
        met = _together(2)                              # one task each: the child's collects

        def task():
            met.wait()
            return None if os.getpid() == PARENT else _collect_in_child()
        return next(v for v in fork_map([task, task]) if v is not None)
    frozen = collected()
    monkeypatch.setattr(processes, "frozen_heap", contextlib.nullcontext)
    walked = collected()
    assert len(heap) and walked > 5000 and frozen < walked / 10
    assert gc.get_freeze_count() == 0                   # the parent's objects are collectable again


def test_forked_call_computes_in_a_child_while_the_parent_works():
    with forked_call(_square(6, 0.3)) as result:
        here = sum(range(10_000))                        # the parent's own work, meanwhile
        value, pid = result()
    assert here == 49_995_000 and value == 36 and pid != PARENT
    assert result() == (36, pid)                         # the result is kept


def test_forked_call_raises_a_failure_in_the_parent_and_survives_a_dead_child():
    def bad():
        raise ValueError("no good")
    with forked_call(bad) as result, pytest.raises(ValueError, match="no good"):
        result()

    def dies_in_a_child():
        if os.getpid() != PARENT:
            os.kill(os.getpid(), signal.SIGKILL)
        return "here", os.getpid()
    with forked_call(dies_in_a_child) as result:
        assert result() == ("here", PARENT)


def test_leaving_forked_call_kills_a_child_still_running():
    with forked_call(time.sleep, 60):
        pass
    assert not [p for p in processes.multiprocessing.active_children()]


def test_children_leave_ctrl_c_to_the_parent():
    """A task child ignores SIGINT: the parent's KeyboardInterrupt ends the run (its children die with it), no
    child prints a traceback of its own."""
    def handler():
        return signal.getsignal(signal.SIGINT), os.getpid()
    here = signal.getsignal(signal.SIGINT)
    with forked_call(handler) as result:
        assert result()[0] == signal.SIG_IGN and result()[1] != PARENT
    met = _together(2)
    got = fork_map([_after(met, handler), _after(met, handler)], jobs=2)
    assert {pid != PARENT for _, pid in got} == {True, False}
    assert [h for h, pid in got if pid != PARENT] == [signal.SIG_IGN]
    assert signal.getsignal(signal.SIGINT) is here                 # the parent keeps its own
