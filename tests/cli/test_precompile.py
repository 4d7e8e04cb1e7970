"""`python -m dgcal.precompile` (run by `make venv`) reaches every compiled kernel a calibration campaign calls,
so that their cache is filled before the first real run."""
from __future__ import annotations

import importlib
import io
import json
import subprocess
import sys

from numba.core.registry import CPUDispatcher

from dgcal.precompile import precompile

# the kernels of the demo's chain (camera, triangulation, TC with PPK, the mounting methods, DG check); the
# others serve large blocks (sparse Schur, parallel pose-pose sums) and globals with free points
CAMPAIGN_KERNELS = {
    "dgcal.bundle.solver.kernels": {"accumulate_items", "coupling_dot", "coupling_tdot", "pose_point_jacobians",
                                    "redundancy_quadratic", "to_camera"},
    "dgcal.pos.smoother.recursions": {"schur_inverses", "rts_covariances", "rts_step", "information_filter"},
    "dgcal.pos.gnss.ambiguity": {"_ldl", "_reduce", "_search"},
    "dgcal.pos.gnss.carrier": {"_mw_jumps"},
    "dgcal.pos.gnss.carrier_model": {"at_reception", "zero_difference_rows"},   # receiver_terms: inside the latter
    "dgcal.pos.gnss.ppk_design": {"dd_rows", "dd_system"},
}

PARALLEL_KERNELS = {"dgcal.bundle.solver.kernels.pose_pose_schur", "dgcal.bundle.solver.kernels.pose_pose_schur_blocks"}


def test_the_tiny_campaign_compiles_every_campaign_kernel():
    log = io.StringIO()
    precompile(log=log)
    assert "numba kernels compiled and cached" in log.getvalue()
    missing = []
    for module, names in CAMPAIGN_KERNELS.items():
        mod = importlib.import_module(module)
        for name in names:
            kernel = getattr(mod, name)
            assert isinstance(kernel, CPUDispatcher), f"{module}.{name} is not a numba kernel any more"
            # compiled here or in a forked child of the run (fork_map's tasks go to whichever process is free):
            # what counts is the machine code in numba's cache on disk, which the next process loads
            if not kernel.signatures and not kernel._cache._cache_file._load_index():
                missing.append(f"{module}.{name}")
    assert not missing, f"not compiled by dgcal.precompile: {missing}"


def test_a_runner_loads_the_cached_serial_kernels_without_compiling_or_starting_threads():
    """What `dgcal run --jobs N` loads before it forks: every serial campaign kernel, from the cache the test
    above filled, in a fresh process that starts no thread pool of numba's (a fork would not carry it)."""
    script = (
        "import json, os, time\n"
        "from numba.core.registry import CPUDispatcher\n"
        "from dgcal.campaign import PRELOAD_KERNELS\n"
        "from dgcal.precompile import load_cached_kernels\n"
        "import importlib\n"
        "mods = [importlib.import_module(m) for m in PRELOAD_KERNELS]\n"
        "threads = len(os.listdir('/proc/self/task'))\n"
        "t = time.perf_counter(); n = load_cached_kernels(PRELOAD_KERNELS); dt = time.perf_counter() - t\n"
        "sigs = {f'{m.__name__}.{k}': len(v.signatures) for m in mods for k, v in vars(m).items()\n"
        "        if isinstance(v, CPUDispatcher) and v.__module__ == m.__name__}\n"
        "print(json.dumps({'n': n, 'seconds': dt, 'sigs': sigs,\n"
        "                  'new_threads': len(os.listdir('/proc/self/task')) - threads}))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    serial = {f"{m}.{k}" for m, names in CAMPAIGN_KERNELS.items() for k in names} - PARALLEL_KERNELS
    assert not [k for k in serial if got["sigs"].get(k, 0) == 0], got["sigs"]
    assert all(got["sigs"].get(k, 0) == 0 for k in PARALLEL_KERNELS)
    assert got["new_threads"] == 0
    assert got["seconds"] < 10.0     # loaded, not compiled (compiling these takes over 20 s)
