"""`dgcal pos --mode ppk`: rover and base RINEX -> carrier-phase PPK of every rover epoch (`run_ppk`), single-point
where PPK has no solution; dgcal.reports.ppk.write_ppk_outputs writes its files."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from dgcal.fields.errors import InputError
from dgcal.pos.base_station import read_base
from dgcal.pos.gnss.carrier import carrier_observations
from dgcal.pos.gnss.ppk import PpkOptions, PpkResult, ppk, ppk_summary
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.gnss.spp import solve_epoch
from dgcal.pos.mode_options import PpkModeOptions


def check_ppk_options(popts: PpkOptions) -> None:
    """The PPK options' choices and ranges (InputError naming the field)."""
    if popts.dynamics not in ("kinematic", "static"):
        raise InputError(f"must be kinematic or static, not {popts.dynamics!r}", field="ppk.dynamics")
    if popts.solution not in ("combined", "forward", "backward"):
        raise InputError(f"must be combined, forward or backward, not {popts.solution!r}", field="ppk.solution")
    if not 1 <= int(popts.n_freq) <= 3:
        raise InputError(f"must be 1, 2 or 3, not {popts.n_freq}", field="ppk.n_freq")
    if not popts.ratio_threshold >= 1.0:
        raise InputError(f"must be a number >= 1, not {popts.ratio_threshold}", field="ppk.ratio_threshold")
    bad = [s for s in popts.systems if s not in "GECJ"]
    if bad or not popts.systems:
        raise InputError(f"constellations are letters of G, E, C, J, not {popts.systems!r}", field="ppk.systems")


@dataclass
class PpkRun:
    """`dgcal pos --mode ppk`: the PPK result (single epochs filled by SPP), its summary and warnings."""

    result: PpkResult
    summary: dict
    base_ecef: np.ndarray
    reference_ecef: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)



def run_ppk(opts: PpkModeOptions) -> PpkRun:
    """`dgcal pos --mode ppk`: carrier-phase PPK of the rover RINEX against the base RINEX at the given base
    position (ECEF m, or geodetic, or the base header's APPROX POSITION with a warning); epochs without
    double differences are SPP ('single'). Checks (`read_base`): common epochs, same day, the base position against
    the base's own SPP. Returns the solution and the summary (with the 3D RMS against `reference_ecef` if given)."""
    rover, sopts, popts = opts.rover, opts.spp, opts.ppk
    for name, val in (("rinex_obs", rover.rinex_obs), ("rinex_nav", rover.rinex_nav), ("base.rinex", opts.base.rinex)):
        if not val:
            raise InputError("required for --mode ppk", field=name)
    check_ppk_options(popts)
    warnings: list[str] = []
    nav = read_rinex_nav(rover.rinex_nav[0], list(rover.rinex_nav[1:]))
    warnings += nav.warnings
    rover_rx = read_obs_file(rover.rinex_obs, t_start=rover.t_start, t_end=rover.t_end, systems=popts.systems)
    bs = read_base(opts.base, rover_rx, nav, sopts, popts.systems, popts.max_age_s)
    base_rx, base, src, base_spp, d_spp = bs.rinex, bs.ecef, bs.source, bs.spp_ecef, bs.minus_spp_m
    warnings += list(rover_rx.warnings) + list(base_rx.warnings) + bs.warnings
    # rover: SPP of the first epochs (start of the filter) and of epochs without double differences
    rover_raw = read_rinex_obs(rover.rinex_obs, systems=sopts.systems, rinex=rover_rx)
    p_init = None
    guess = rover_raw.p_approx_ecef if np.all(np.isfinite(rover_raw.p_approx_ecef)) else None
    for ep in rover_raw.epochs[:10]:
        s = solve_epoch(ep, nav, guess, sopts)
        if s.ok:
            p_init = s.p_ecef
            break
    if p_init is None:
        p_init = guess if guess is not None else base
    rover_co = carrier_observations(rover_rx, popts.systems, popts.n_freq)
    base_obs = carrier_observations(base_rx, popts.systems, popts.n_freq)
    t_run = time.perf_counter()
    with threadpool_limits(1):        # small matrices: BLAS threads only cost
        res = ppk(rover_co, base_obs, nav, base, popts, p_init=p_init)
    t_run = time.perf_counter() - t_run
    # 'single' epochs: SPP where PPK has no solution
    t_raw = {round(ep.t_gps, 3): ep for ep in rover_raw.epochs}
    guess = p_init
    for k in np.nonzero(res.status == 0)[0]:
        ep = t_raw.get(round(float(res.t_gps[k]), 3))
        if ep is None:
            continue
        s = solve_epoch(ep, nav, guess, sopts)
        if s.ok:
            res.status[k], res.p[k], res.P[k], res.n_sat[k] = 1, s.p_ecef, s.cov_p, s.n_sat
            guess = s.p_ecef
    ref = np.asarray(opts.reference_ecef, float) if opts.reference_ecef is not None else None
    summary = ppk_summary(res, ref)
    summary.update({"rinex_obs": str(rover.rinex_obs), "rinex_base": str(opts.base.rinex),
                    "rinex_nav": nav.source, "base_ecef_m": base.tolist(), "base_position_source": src,
                    "base_spp_ecef_m": base_spp.tolist() if base_spp is not None else None,
                    "base_minus_spp_m": d_spp, "ionosphere_model": nav.ion_source, "orbits": nav.orbits,
                    "run_time_s": round(t_run, 2),
                    "time_per_epoch_ms": round(1e3 * t_run / max(len(res.t_gps), 1), 2),
                    "warnings": warnings})
    return PpkRun(res, summary, base, ref, warnings)
