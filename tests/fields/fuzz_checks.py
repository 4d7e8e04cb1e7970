"""What every fuzzed read must satisfy (issue 31), shared by the reader fuzz tests: it returns within `HANG_S`
seconds, it fails only with one InputError line naming the file, and what it accepts holds no infinite or absurdly
large number (|x| > `MAX_ABS`) and no NaN where the valid sample's result has none (when the mutation wrote one;
optional sigmas and covariances may be NaN: "not given").

`FuzzStats` counts per reader the cases, the InputErrors, the results accepted and the slowest case; with
DGCAL_FUZZ_STATS=FILE set, `record` appends one JSON line per reader to FILE (the figures of a long run)."""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import time
from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError

HANG_S = 10.0            # a read taking longer is a hang (the acceptance of issue 31)
# NaN is "not given" in optional uncertainty columns (docs/formats.md: a blank sigma), however the file wrote it
OPTIONAL_NAN = ("sigma", "cov", "p_approx")   # p_approx: a RINEX header's approximate position, NaN = not given
# laser ranges: {image: (range m, sigma m or NaN: not given)}; camera centres: angles NaN when not given; RINEX
# observations: any field of a record may be blank (NaN: not observed)
NAN_NOT_GIVEN = {"laser-ranges", "centres-csv", "rinex-obs-2", "rinex-obs-3", "rinex-obs-crinex", "rinex-obs-gzip"}
# out-of-range values the fuzz runs found in readers, left open (named in issue 31's notes): reader -> prefixes of the
# result paths; such a value is counted (FuzzStats.known_open), not failed. Empty: every reader holds.
KNOWN_OPEN: dict[str, tuple[str, ...]] = {}
MAX_ABS = 1e12           # no quantity dgcal reads is this large in its units (GPS s ~1.5e9, ECEF m ~6.4e6)


class Hang(BaseException):
    """A read that did not return within HANG_S seconds (a BaseException: a reader's `except Exception` that turns
    library failures into InputErrors must not hide it)."""


def _alarm(signum, frame):
    raise Hang(f"no result after {HANG_S:g} s")


def numbers(obj, prefix: str = "", depth: int = 0, seen: set | None = None):
    """(path, float array) of every number held by a reader's result (arrays, floats, lists, records)."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 4:
        return
    seen.add(id(obj))
    if isinstance(obj, (bool, np.bool_, str, bytes, Path)) or obj is None:
        return
    if isinstance(obj, (int, float, np.integer, np.floating)):
        yield prefix, np.array([float(obj)])
    elif isinstance(obj, np.ndarray):
        if obj.dtype.kind in "fiu" and obj.size:
            yield prefix, obj.astype(float).ravel()
        elif obj.dtype.kind == "O" and obj.size:
            for i, v in enumerate(obj.ravel()[:20]):
                yield from numbers(v, f"{prefix}[{i}]", depth + 1, seen)
        elif obj.dtype.names:
            for name in obj.dtype.names:
                yield from numbers(obj[name], f"{prefix}.{name}", depth + 1, seen)
    elif isinstance(obj, dict):
        for k, v in list(obj.items())[:200]:
            yield from numbers(v, f"{prefix}.{k}", depth + 1, seen)
    elif isinstance(obj, (list, tuple)):
        if obj and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in obj):
            yield prefix, np.array(obj, float)
        else:
            for i, v in enumerate(obj[:200]):
                yield from numbers(v, f"{prefix}[{i}]", depth + 1, seen)
    elif dataclasses.is_dataclass(obj) or hasattr(obj, "__dict__"):
        fields = vars(obj) if hasattr(obj, "__dict__") else {f.name: getattr(obj, f.name)
                                                             for f in dataclasses.fields(obj)}
        for k, v in fields.items():
            if not callable(v):
                yield from numbers(v, f"{prefix}.{k}", depth + 1, seen)


def nan_fields(result) -> set[str]:
    """The paths of `result` holding a NaN (a valid sample's optional values not given)."""
    return {p for p, a in numbers(result) if np.isnan(a).any()}


def bad_values(result, allowed_nan: set[str], wrote_nan: bool, skip: tuple[str, ...] = (),
               stats_reader: str = "") -> str | None:
    """What is wrong with the numbers a read accepted, or None: an inf, |x| > MAX_ABS, or (when the mutation
    wrote a NaN) a NaN at a path the valid sample holds none at; paths starting with one of `skip` are not looked at."""
    for path, a in numbers(result):
        if path.startswith(skip) and skip:
            continue
        with np.errstate(invalid="ignore"):
            if np.isinf(a).any():
                return f"{path or 'result'}: inf accepted"
            big = np.abs(a) > MAX_ABS
        if big.any():
            return f"{path or 'result'}: {a[big][0]:.6g} accepted (|x| > {MAX_ABS:g})"
        optional = any(k in path.lower() for k in OPTIONAL_NAN) or stats_reader in NAN_NOT_GIVEN
        if wrote_nan and np.isnan(a).any() and not optional and not any(path.startswith(p) or p.startswith(path)
                                                                        for p in allowed_nan):
            return f"{path or 'result'}: NaN accepted"
    return None


@dataclasses.dataclass
class FuzzStats:
    """Figures of one reader's fuzz run."""

    reader: str
    cases: int = 0
    input_errors: int = 0
    accepted: int = 0
    known_open: int = 0
    slowest_s: float = 0.0

    def record(self) -> None:
        """Append the figures as a JSON line to $DGCAL_FUZZ_STATS (when set)."""
        out = os.environ.get("DGCAL_FUZZ_STATS")
        if out:
            with open(out, "a") as fh:
                fh.write(json.dumps(dataclasses.asdict(self)) + "\n")


def check_read(reader, p: Path, data: bytes, stats: FuzzStats, allowed_nan: set[str] = frozenset(),
               names: tuple[str, ...] = ()) -> None:
    """Write `data` to `p` and read it: within HANG_S, a result with sound numbers or one InputError line naming
    the file (`p`, or one of `names`: a companion file the reader also reads)."""
    p.write_bytes(data)
    stats.cases += 1
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    t0 = time.perf_counter()
    try:
        result = reader(p)
    except InputError as exc:
        stats.input_errors += 1
        msg = str(exc)
        assert "\n" not in msg and msg.strip(), repr(msg)
        assert str(p) in msg or p.name in msg or any(n in msg for n in names), msg
        return
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        stats.slowest_s = max(stats.slowest_s, time.perf_counter() - t0)
    stats.accepted += 1
    wrote_nan = b"nan" in data.lower()
    open_paths = KNOWN_OPEN.get(stats.reader, ())
    if open_paths and bad_values(result, allowed_nan, wrote_nan, stats_reader=stats.reader) is not None:
        stats.known_open += 1
    problem = bad_values(result, allowed_nan, wrote_nan, open_paths, stats.reader)
    assert problem is None, problem
