"""Forked child processes: ones that die with their parent, and a map of independent tasks over the CPUs
(what a process holds in memory — a figure, a solution — is the children's too, nothing is pickled but the
results)."""
from __future__ import annotations

import ctypes
import gc
import multiprocessing
import os
import signal
import sys
from contextlib import contextmanager
from typing import Callable, Sequence, TypeVar

__all__ = ["cpus", "die_with_parent", "fork_map", "frozen_heap"]

T = TypeVar("T")
_PR_SET_PDEATHSIG = 1   # linux/prctl.h


def cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def die_with_parent(parent_pid: int) -> None:
    """Ask Linux to SIGKILL this (child) process when its parent dies; exit now if it already has."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):   # not Linux: the child may outlive a killed parent
        pass
    if os.getppid() != parent_pid:
        os._exit(137)


@contextmanager
def frozen_heap():
    """Around a fork: this process's objects moved out of the garbage collector's reach (gc.freeze) while children
    are forked, and back after. A child's collections then never walk the inherited objects, which would write to
    every page holding one (copy-on-write: the child would copy much of the parent's memory)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def fork_map(tasks: Sequence[Callable[[], T]], jobs: int | None = None) -> list[T]:
    """The results of `tasks` in order, computed by this process and up to `jobs` - 1 forked children (default:
    one per CPU); a task whose child failed or died is run again here, so its exception, if any, is raised
    here. One CPU, one task or no fork (not POSIX): all run here in order."""
    jobs = min(cpus() if jobs is None else jobs, len(tasks))
    if jobs <= 1 or not hasattr(os, "fork"):
        return [t() for t in tasks]
    ctx = multiprocessing.get_context("fork")
    groups = [list(range(k, len(tasks), jobs)) for k in range(jobs)]   # round robin: neighbours are alike
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    children = []
    with frozen_heap():
        for group in groups[1:]:
            recv_end, send_end = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(tasks, group, send_end, os.getpid()))
            proc.start()
            send_end.close()
            children.append((proc, recv_end))
    results: dict[int, T] = {i: tasks[i]() for i in groups[0]}
    for proc, conn in children:
        try:
            got = conn.recv()
        except (EOFError, OSError):   # the child died: its tasks are run here
            got = {}
        proc.join()
        conn.close()
        results.update(got)
    return [results[i] if i in results else tasks[i]() for i in range(len(tasks))]


def _child(tasks, group: list[int], conn, parent_pid: int) -> None:
    """Run the tasks of `group`, send {index: result} of those that succeeded."""
    die_with_parent(parent_pid)
    out = {}
    for i in group:
        try:
            out[i] = tasks[i]()
        except Exception:   # noqa: BLE001  (run again by the parent, which raises it)
            pass
    try:
        conn.send(out)
    except Exception:       # a result that does not pickle: the parent computes them all
        conn.send({})
