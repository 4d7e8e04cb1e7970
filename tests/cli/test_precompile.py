"""`python -m dgcal.precompile` (run by `make venv`) reaches every compiled kernel a calibration campaign calls,
so that their cache is filled before the first real run."""
from __future__ import annotations

import importlib
import io

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
            if not kernel.signatures:
                missing.append(f"{module}.{name}")
    assert not missing, f"not compiled by dgcal.precompile: {missing}"
