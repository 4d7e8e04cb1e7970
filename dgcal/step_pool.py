"""Campaign steps run side by side: each in a forked child process (so it shares the parent's imports and
runs on its own core), at most `jobs` at a time; the parent alone writes the campaign's state file.

A child dies with its parent (PR_SET_PDEATHSIG), so `kill -9` of `dgcal run` stops every step it started,
as it would stop the one step of a sequential run; the output folders are then absent, old or new as ever
(dgcal.fields.io.atomic), and the next run cleans up and resumes."""
from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import time
from dataclasses import dataclass, field
from typing import Callable

from threadpoolctl import threadpool_limits

from dgcal.fields.processes import cpus, die_with_parent, frozen_heap

__all__ = ["Outcome", "StepPool", "default_jobs"]


def default_jobs() -> int:
    """Steps a campaign runs at once by default: one per CPU this process may use, at most 4 (the chain rarely
    offers more)."""
    return max(1, min(4, cpus()))


@dataclass
class Outcome:
    """How a step ended: its exit status, or the exception its runner raised; wall time (s)."""

    name: str
    rc: int = 0
    error: BaseException | None = None
    seconds: float = 0.0


@dataclass
class _Running:
    process: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection
    started: float = field(default_factory=time.perf_counter)


class StepPool:
    """Start steps (`start(name, argv)`) in forked children running `runner(argv)`; `wait()` returns the
    outcome of the next one to finish."""

    def __init__(self, runner: Callable[[list[str]], int], blas_threads: int = 1):
        self.runner = runner
        self.blas_threads = blas_threads
        self.running: dict[str, _Running] = {}
        self._ctx = multiprocessing.get_context("fork")

    def __len__(self) -> int:
        return len(self.running)

    def start(self, name: str, argv: list[str], nice: int = 0) -> None:
        """Fork a child that runs the step (at niceness `nice` above this process's); returns at once."""
        for stream in (sys.stdout, sys.stderr):   # nothing buffered is printed twice by the child
            stream.flush()
        parent_end, child_end = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=_child, name=f"dgcal-{name}", daemon=False,
                                 args=(self.runner, list(argv), child_end, os.getpid(), self.blas_threads, nice))
        with frozen_heap():
            proc.start()
        child_end.close()
        self.running[name] = _Running(proc, parent_end)

    def wait(self) -> Outcome:
        """Block until a running step ends; its outcome (a child killed by a signal: an error naming it)."""
        by_sentinel = {r.process.sentinel: n for n, r in self.running.items()}
        ready = multiprocessing.connection.wait(list(by_sentinel) + [r.conn for r in self.running.values()])
        name = next((by_sentinel[s] for s in ready if s in by_sentinel), None)
        if name is None:   # the child's message came first: its process ends right after sending it
            name = next(n for n, r in self.running.items() if r.conn in ready)
        run = self.running.pop(name)
        try:
            message = run.conn.recv() if run.conn.poll() else None
        except EOFError:           # the child died without a word
            message = None
        except Exception as exc:   # an exception that pickled but does not unpickle
            message = ("error", RuntimeError(f"the step's error could not be read back ({exc})"))
        run.process.join()
        run.conn.close()
        seconds = time.perf_counter() - run.started
        if message is None:
            code = run.process.exitcode
            why = f"killed by signal {-code}" if code is not None and code < 0 else f"ended with exit {code}"
            return Outcome(name, error=RuntimeError(f"the step's process {why} before reporting"), seconds=seconds)
        kind, value = message
        return Outcome(name, rc=value, seconds=seconds) if kind == "rc" else Outcome(name, error=value,
                                                                                    seconds=seconds)

    def stop(self) -> None:
        """Terminate every running step (on an interrupt of the parent) and reap it."""
        for run in self.running.values():
            run.process.terminate()
        for run in self.running.values():
            run.process.join()
            run.conn.close()
        self.running.clear()


def _child(runner: Callable[[list[str]], int], argv: list[str], conn, parent_pid: int, blas_threads: int,
           nice: int = 0) -> None:
    """The step in the child: its exit status or its exception goes back through `conn`."""
    die_with_parent(parent_pid)
    # the steps side by side share the CPUs: OpenBLAS threads that spin-wait for a busy core slow a step 2-3x
    threadpool_limits(limits=blas_threads, user_api="blas")
    if nice:
        os.nice(nice)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        message = ("rc", int(runner(argv) or 0))
    except BaseException as exc:   # noqa: BLE001  (the parent decides what a crash means)
        message = ("error", exc)
    try:
        conn.send(message)
    except Exception:   # an exception that does not pickle: its type and text
        conn.send(("error", RuntimeError(f"{type(message[1]).__name__}: {message[1]}")))
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
