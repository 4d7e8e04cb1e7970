"""Campaign steps run side by side: each in a forked child process (so it shares the parent's imports and
runs on its own core), at most `jobs` at a time; the parent alone writes the campaign's state file.

A child dies with its parent (PR_SET_PDEATHSIG), so `kill -9` of `dgcal run` stops every step it started,
as it would stop the one step of a sequential run; the output folders are then absent, old or new as ever
(dgcal.fields.io.atomic), and the next run cleans up and resumes."""
from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import re
import signal
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from threadpoolctl import threadpool_limits

from dgcal.fields.processes import cpus, die_with_parent, frozen_heap

__all__ = ["Outcome", "StepPool", "default_jobs", "log_notes", "output_to_log"]


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


@contextmanager
def output_to_log(path: Path | None) -> Iterator[None]:
    """File descriptors 1 and 2 into `path` for the block: the step's own lines and those of the compiled libraries
    it calls (COLMAP, gtsam) go to its log file, not between the campaign's lines. None: left alone."""
    if path is None:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    saved_fds, saved_streams = (os.dup(1), os.dup(2)), (sys.stdout, sys.stderr)
    log = open(path, "w", encoding="utf-8", buffering=1)   # noqa: SIM115  (closed below, after the fds are back)
    try:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        sys.stdout = sys.stderr = log   # Python's streams too, where they are not the process's (a test's capture)
        yield
    finally:
        log.flush()
        sys.stdout, sys.stderr = saved_streams
        os.dup2(saved_fds[0], 1)
        os.dup2(saved_fds[1], 2)
        os.close(saved_fds[0])
        os.close(saved_fds[1])
        log.close()


_WARNING = re.compile(r"\b(warning:|\w*Warning:)", re.IGNORECASE)   # dgcal's "warning: ..." and Python's warnings


def log_notes(path: Path | None, limit: int = 20) -> tuple[list[str], str | None]:
    """The warning lines of a step's log (at most `limit`) and its last error line (None: no log or no error)."""
    if path is None or not path.is_file():
        return [], None
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    warnings = [ln.strip() for ln in lines if _WARNING.search(ln)]
    errors = [ln.strip() for ln in lines if ": error:" in ln or "internal error" in ln]
    return warnings[:limit], (errors[-1] if errors else None)


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

    def start(self, name: str, argv: list[str], nice: int = 0, log: Path | None = None) -> None:
        """Fork a child that runs the step (at niceness `nice` above this process's, its output into `log`);
        returns at once."""
        for stream in (sys.stdout, sys.stderr):   # nothing buffered is printed twice by the child
            stream.flush()
        parent_end, child_end = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=_child, name=f"dgcal-{name}", daemon=False,
                                 args=(self.runner, list(argv), child_end, os.getpid(), self.blas_threads, nice, log))
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
           nice: int = 0, log: Path | None = None) -> None:
    """The step in the child: its exit status or its exception goes back through `conn`."""
    die_with_parent(parent_pid)
    # the steps side by side share the CPUs: OpenBLAS threads that spin-wait for a busy core slow a step 2-3x
    threadpool_limits(limits=blas_threads, user_api="blas")
    if nice:
        os.nice(nice)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with output_to_log(log):
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
