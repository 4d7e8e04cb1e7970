"""`dgcal pos`: one entry for every mode, dispatched on the type of its options (`dgcal.pos.mode_options`).

- `SppModeOptions` -> `dgcal.pos.gnss.spp_mode.run_spp` (code single-point positioning);
- `PpkModeOptions` -> `dgcal.pos.ppk_mode.run_ppk` (carrier phase against a base station);
- `InsModeOptions` (tc, lc) and `UkfModeOptions` -> `dgcal.pos.gnss_ins.run_gnss_ins` (GNSS/INS smoother, UKF).
dgcal.reports.gnss, dgcal.reports.ppk, dgcal.reports.pos and dgcal.reports.ukf write their files.
"""
from __future__ import annotations

from dgcal.pos.gnss.spp import SppRun
from dgcal.pos.gnss.spp_mode import SppModeOptions, run_spp
from dgcal.pos.gnss_ins import PosResult, run_gnss_ins
from dgcal.pos.lowcost.ukf_pos import UkfPosResult
from dgcal.pos.mode_options import InsModeOptions, PosModeOptions, PpkModeOptions
from dgcal.pos.ppk_mode import PpkRun, run_ppk


def run_pos(opts: PosModeOptions) -> SppRun | PpkRun | PosResult | UkfPosResult:
    """Run the `dgcal pos` mode that `opts` configures (its type says which) and return its result."""
    if isinstance(opts, SppModeOptions):
        return run_spp(opts)
    if isinstance(opts, PpkModeOptions):
        return run_ppk(opts)
    if isinstance(opts, InsModeOptions):
        return run_gnss_ins(opts)
    raise TypeError(f"not the options of a dgcal pos mode: {type(opts).__name__}")
