"""Forked child processes: ones that die with their parent, and a map of independent tasks over the CPUs
(what a process holds in memory — a figure, a solution — is the children's too, nothing is pickled but the
results)."""
from __future__ import annotations

import gc
import os
import signal
import sys
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence, TypeVar

__all__ = ["cpus", "die_with_parent", "fork_map", "forked_call", "frozen_heap"]

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
    import ctypes   # why: only a child needs it; not imported by a process that forks none (`dgcal pos --mode spp`)
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
    one per CPU), each taking the next task not yet taken when it is free (tasks of unequal cost share out
    evenly); a task whose child failed or died is run again here, so its exception, if any, is raised
    here. One CPU, one task or no fork (not POSIX): all run here in order."""
    jobs = min(cpus() if jobs is None else jobs, len(tasks))
    if jobs <= 1 or not hasattr(os, "fork"):
        return [t() for t in tasks]
    taken = _fork_context().Value("i", 0)   # the next task nobody has taken
    children = [_start_child(_child, tasks, taken) for _ in range(jobs - 1)]
    results: dict[int, T] = {i: tasks[i]() for i in _take(taken, len(tasks))}
    for proc, conn in children:
        try:
            got = conn.recv()
        except (EOFError, OSError):   # the child died: its tasks are run here
            got = {}
        proc.join()
        conn.close()
        results.update(got)
    return [results[i] if i in results else tasks[i]() for i in range(len(tasks))]


def _multiprocessing():
    import multiprocessing   # why: 5 ms of imports, spent by a process only when it forks (not `--no-report` SPP)
    return multiprocessing


def __getattr__(name: str):
    # `processes.multiprocessing`, as when it was imported at the top: the module, imported on first use
    if name == "multiprocessing":
        return _multiprocessing()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _fork_context():
    return _multiprocessing().get_context("fork")


def _start_child(target, *args):
    """A forked child running `target(*args, send_end, parent_pid)` (the streams flushed, the heap frozen), and the
    receiving end of its pipe."""
    ctx = _fork_context()
    recv_end, send_end = ctx.Pipe(duplex=False)
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    with frozen_heap():
        proc = ctx.Process(target=target, args=(*args, send_end, os.getpid()))
        proc.start()
    send_end.close()
    return proc, recv_end


def _take(taken, n: int) -> Iterator[int]:
    """Indices of tasks, each taken from the shared counter `taken` when the caller is ready for it."""
    while True:
        with taken.get_lock():
            i = taken.value
            taken.value = i + 1
        if i >= n:
            return
        yield i


def _quiet_child(parent_pid: int) -> None:
    """A task child's start: it dies with its parent and leaves Ctrl-C to it (the parent's KeyboardInterrupt ends
    the run, and the child with it, instead of a traceback from every child)."""
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _child(tasks, taken, conn, parent_pid: int) -> None:
    """Run tasks as they come free, send {index: result} of those that succeeded."""
    _quiet_child(parent_pid)
    out = {}
    for i in _take(taken, len(tasks)):
        try:
            out[i] = tasks[i]()
        except Exception:   # noqa: BLE001  (run again by the parent, which raises it)
            pass
    try:
        conn.send(out)
    except Exception:       # a result that does not pickle: the parent computes them all
        conn.send({})


@contextmanager
def forked_call(fn: Callable[..., T], *args) -> Iterator[Callable[[], T]]:
    """Start `fn(*args)` in a forked child now and yield a function that waits for its result, so this process
    can do other work (import a report's plotting library, say) meanwhile. If the child failed or died, the wait
    runs `fn(*args)` here, so its exception, if any, is raised here. A child still running when the block is left
    is killed. Not POSIX: `fn(*args)` runs at the wait."""
    if not hasattr(os, "fork"):
        yield lambda: fn(*args)
        return
    proc, recv_end = _start_child(_call_child, fn, args)
    got: list = []

    def wait() -> T:
        if not got:
            try:
                got.append(recv_end.recv())
            except (EOFError, OSError):   # the child died
                got.append(None)
            proc.join()
        return got[0][0] if got[0] is not None else fn(*args)

    try:
        yield wait
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
        recv_end.close()


def _call_child(fn, args, conn, parent_pid: int) -> None:
    """Send (fn(*args),), or None when it raised or its result does not pickle (the parent runs it again)."""
    _quiet_child(parent_pid)
    try:
        out = (fn(*args),)
    except Exception:       # noqa: BLE001  (run again by the parent, which raises it)
        out = None
    try:
        conn.send(out)
    except Exception:       # noqa: BLE001
        conn.send(None)
