"""Compile dgcal's numba kernels into their cache now (`python -m dgcal.precompile`; `make venv` runs it), so
that the first real run does not spend 20-30 s compiling them: a tiny simulated campaign — plate calibration,
triangulation, tightly coupled POS with rover and base carrier phase (PPK), every mounting method, DG check —
runs through the same code, with the same argument types, as a real one. Each kernel is compiled again only
when its source file changes."""
from __future__ import annotations

import importlib
import sys
import tempfile
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Iterable

__all__ = ["load_cached_kernels", "precompile"]

# small enough to take a few seconds once compiled; carrier-phase GNSS so that PPK and the DD factors run
_TINY = dict(seed=7, gnss_mode="carrier", heights_agl=(300.0, 600.0), n_strips=2, strip_length_m=600.0, n_tie=200,
             field_images=12)


def precompile(log=sys.stderr) -> float:
    """Run the tiny campaign in a temporary folder (its outputs are discarded); returns the time taken (s)."""
    from dgcal.campaign import run_campaign
    from dgcal.sim.campaign import simulate_campaign
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dgcal-precompile-") as tmp:
        data = Path(tmp) / "data"
        simulate_campaign(data, **_TINY)
        with open(Path(tmp) / "log.txt", "w") as quiet, redirect_stdout(quiet), redirect_stderr(quiet):
            run_campaign(data / "campaign.toml", Path(tmp) / "results", log=quiet, report=False, jobs=1)
    seconds = time.perf_counter() - t0
    print(f"dgcal: numba kernels compiled and cached in {seconds:.0f} s", file=log)
    return seconds


def load_cached_kernels(modules: Iterable[str]) -> int:
    """Load the cached machine code of every serial numba kernel of `modules` into this process, for the signatures
    its cache holds; returns how many. A parent that forks steps loads them once instead of every child (numba's
    start-up and each kernel's loading, 0.2-0.6 s per step). Parallel kernels are left alone (loading one starts
    numba's thread pool, which a fork does not carry), as is any signature whose cache is stale or was built for
    another CPU (that would compile it here, seconds)."""
    from numba.core.registry import CPUDispatcher
    loaded = 0
    for name in modules:
        for kernel in vars(importlib.import_module(name)).values():
            if not isinstance(kernel, CPUDispatcher) or kernel.__module__ != name \
                    or kernel.targetoptions.get("parallel") or kernel._cache is None:
                continue
            try:
                cache, codegen = kernel._cache, kernel.targetctx.codegen()
                index = cache._cache_file._load_index()   # {} when the source file changed since it was cached
                for sig, *_ in list(index):
                    # the key names the CPU and the code's hash: only what loads without compiling
                    if cache._index_key(sig, codegen) in index and sig not in kernel.overloads:
                        kernel.compile(sig)
                        loaded += 1
            except Exception:   # noqa: BLE001  (numba's cache internals moved: each step loads its own, as before)
                continue
    return loaded


if __name__ == "__main__":
    from dgcal.fields import progress
    with progress.configured(prefix="precompile"), progress.stage("compiling dgcal's numba kernels (once, ~1 min)"):
        precompile()
