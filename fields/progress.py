"""What a person sees of long work: a line when a stage starts, a heartbeat while it runs (its count and elapsed
time, every few seconds), its time when it ends. On a terminal the heartbeat is one line redrawn in place; in a
pipe or a log file it is a new line every `HEARTBEAT_S`. Nothing at all under `configure(quiet=True)`.

Stages nest (a verb's whole run, inside it the smoother, inside that its iterations): the heartbeat speaks of
the innermost. It comes from one small forked child per outermost stage that reads the current stage from shared
memory: the parent may sit for minutes inside compiled code that holds Python's lock (gtsam, COLMAP, numba), where
no thread of its own could speak. The child writes with `os.write` on the parent's stderr and dies with its parent.
"""
from __future__ import annotations

import mmap
import os
import select
import signal
import struct
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterable, Iterator, TypeVar

from dgcal.fields.processes import die_with_parent

__all__ = ["HEARTBEAT_S", "Stage", "configure", "configured", "quiet", "say", "stage", "track"]

T = TypeVar("T")
HEARTBEAT_S = 5.0              # a stage running longer than this says so this often (never 10 s silent)
_HEARTBEAT_ENV = "DGCAL_HEARTBEAT_S"   # another period (s), for tests and slow terminals
_HEAD = struct.Struct("qqdH")  # done, total (0: unknown), start (monotonic s), text length; the text follows
_SHARED_BYTES = 1024


@dataclass
class _Settings:
    quiet: bool = False
    prefix: str = "dgcal"
    heartbeat_s: float = float(os.environ.get(_HEARTBEAT_ENV) or HEARTBEAT_S)
    stack: list = field(default_factory=list)   # the open stages, outermost first
    shared: mmap.mmap | None = None
    ticker: tuple[int, int] | None = None        # (pid, write end of its pipe)
    tty: bool = False


_settings = _Settings()


def configure(quiet: bool | None = None, prefix: str | None = None, heartbeat_s: float | None = None) -> None:
    """Set what stages print: nothing when `quiet`; lines start with `[prefix]` (a verb's name)."""
    if quiet is not None:
        _settings.quiet = bool(quiet)
    if prefix is not None:
        _settings.prefix = prefix
    if heartbeat_s is not None:
        _settings.heartbeat_s = float(heartbeat_s)


@contextmanager
def configured(quiet: bool | None = None, prefix: str | None = None) -> Iterator[None]:
    """`configure` for the block, the previous settings back after it (a command run inside a campaign)."""
    before = (_settings.quiet, _settings.prefix)
    configure(quiet=quiet, prefix=prefix)
    try:
        yield
    finally:
        _settings.quiet, _settings.prefix = before


def quiet() -> bool:
    """True when stages print nothing."""
    return _settings.quiet


def fmt_seconds(seconds: float) -> str:
    """A duration for people: '4.2 s', '3 min 05 s'."""
    return f"{seconds:.1f} s" if seconds < 60 else f"{int(seconds // 60)} min {int(seconds % 60):02d} s"


def _counts_text(done: int, total: int) -> str:
    if total > 0:
        return f" {done}/{total}"
    return f" {done}" if done else ""


def _write_fd(fd: int, text: str) -> None:
    try:
        os.write(fd, text.encode("utf-8", "replace"))
    except OSError:   # a closed pipe: nobody reads any more
        pass


def say(text: str) -> None:
    """One line on stderr that does not collide with a heartbeat redrawn in place (unless quiet)."""
    if _settings.quiet:
        return
    sys.stdout.flush()
    print(f"\r\x1b[K{text}" if _settings.tty and _settings.ticker else text, file=sys.stderr, flush=True)


class Stage:
    """A running stage: `update(n)` adds to its count (shown by the heartbeat), `set_total` when known late."""

    def __init__(self, text: str, total: int | None):
        self.text = text
        self.now = text
        self.done = 0
        self.total = int(total or 0)
        self.t0 = self.now_t0 = time.monotonic()

    def _publish(self) -> None:
        shared = _settings.shared
        if shared is None or not _settings.stack or _settings.stack[-1] is not self:
            return
        head = f"[{_settings.prefix}] {self.now}".encode("utf-8", "replace")[:_SHARED_BYTES - _HEAD.size]
        shared.seek(0)
        shared.write(_HEAD.pack(self.done, self.total, self.now_t0, len(head)) + head)

    def update(self, n: int = 1) -> None:
        """Count `n` more items done."""
        self.done += int(n)
        self._publish()

    def set_text(self, text: str) -> None:
        """What the stage is doing now (the heartbeat says it with the time since; the end line keeps the first)."""
        self.now = text
        self.now_t0 = time.monotonic()
        self._publish()

    def set_total(self, total: int) -> None:
        """The number of items this stage will do."""
        self.total = int(total)
        self._publish()


def _ticker(read_fd: int, shared: mmap.mmap, period: float, tty: bool, parent: int) -> None:
    """The heartbeat child: every `period` s the current stage, its count and elapsed time, until the pipe closes."""
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        ready, _, _ = select.select([read_fd], [], [], period)
        if ready:   # the parent closed its end (the outermost stage ended) or died
            os._exit(0)
        shared.seek(0)
        done, total, t0, n = _HEAD.unpack(shared.read(_HEAD.size))
        head = shared.read(n).decode("utf-8", "replace")
        line = f"{head}{_counts_text(done, total)} … {fmt_seconds(time.monotonic() - t0)}"
        _write_fd(2, f"\r\x1b[K{line}" if tty else f"{line}\n")


def _start_ticker() -> None:
    if not hasattr(os, "fork"):
        return
    read_fd, write_fd = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    parent, shared = os.getpid(), _settings.shared
    pid = os.fork()
    if pid == 0:   # the child runs nothing of the parent's but the ticker
        try:
            os.close(write_fd)
            _ticker(read_fd, shared, _settings.heartbeat_s, _settings.tty, parent)
        finally:
            os._exit(0)
    os.close(read_fd)
    _settings.ticker = (pid, write_fd)


def _forget_in_child() -> None:
    """In any forked child (a campaign's step, a task of `fork_map`): no open stage, no ticker of its own; the
    parent's pipe end closed here, or the parent's ticker would never see its stage end."""
    if _settings.ticker is not None:
        try:
            os.close(_settings.ticker[1])
        except OSError:
            pass
    _settings.ticker = None
    _settings.shared = None
    _settings.stack = []


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)


def _stop_ticker() -> None:
    if _settings.ticker is None:
        return
    pid, write_fd = _settings.ticker
    _settings.ticker = None
    os.close(write_fd)
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


@contextmanager
def stage(text: str, total: int | None = None, announce: bool = True) -> Iterator[Stage]:
    """A long stage of work: `[prefix] text …` now, its count and time every few seconds while it runs (of the
    innermost open stage), `[prefix] text: done in T` at its end (or `stopped after T`). `announce=False`: only the
    heartbeat (a whole command's run: quick ones print nothing). Quiet: nothing."""
    st = Stage(text, total)
    if _settings.quiet:
        yield st
        return
    outermost = not _settings.stack
    if outermost:
        _settings.tty = sys.stderr.isatty()
        _settings.shared = mmap.mmap(-1, _SHARED_BYTES)
    if announce:
        say(f"[{_settings.prefix}] {text} …")
    _settings.stack.append(st)
    st._publish()
    if outermost:
        _start_ticker()
    ok = False
    try:
        yield st
        ok = True
    finally:
        _settings.stack.pop()
        took = fmt_seconds(time.monotonic() - st.t0)
        if announce:
            say(f"[{_settings.prefix}] {text}{_counts_text(st.done, st.total)}: "
                + (f"done in {took}" if ok else f"stopped after {took}"))
        if outermost:
            _stop_ticker()
            _settings.shared.close()
            _settings.shared = None
        elif _settings.stack:
            _settings.stack[-1]._publish()


def track(items: Iterable[T], text: str, total: int | None = None) -> Iterator[T]:
    """Iterate `items` as one stage, counting each item (total from len() where it has one)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)   # type: ignore[arg-type]
    with stage(text, total) as st:
        for item in items:
            yield item
            st.update()
