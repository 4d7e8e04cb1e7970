"""Has the mounting changed? Differences of two calibrations against their combined covariance (chi-square)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import chdtrc   # chi2.sf without importing scipy.stats (0.5-0.8 s)

from dgcal.calib.mounting.common import MountingResult, read_mounting_json
from dgcal.fields.pose import so3_log


@dataclass
class CompareOptions:
    """Inputs of `dgcal compare`: an earlier and a newer mounting.json, and the test's significance level."""

    old: Path
    new: Path
    alpha: float = 0.01


def compare_mountings(old: MountingResult, new: MountingResult, alpha: float = 0.01) -> dict:
    """Differences new - old [delay s, lever arm m, boresight rad about body axes], z-scores, and a chi-square
    test of "no change" at significance `alpha` (the two calibrations taken as independent)."""
    d = np.r_[new.delay_s - old.delay_s, new.lever_arm_m - old.lever_arm_m,
              so3_log(new.R_cam_to_body @ old.R_cam_to_body.T)]
    C = old.cov + new.cov
    var = np.diag(C)
    use = var > 0
    z = np.where(use, d / np.sqrt(np.where(use, var, 1.0)), np.nan)
    Cu = C[np.ix_(use, use)]
    stat = float(d[use] @ np.linalg.pinv(Cu) @ d[use]) if use.any() else float("nan")
    dof = int(np.linalg.matrix_rank(Cu)) if use.any() else 0
    p = float(chdtrc(dof, stat)) if dof else float("nan")
    names = MountingResult.PARAM_NAMES
    unfixed = [n for n, u in zip(names, use) if not u]
    return {
        "difference": {"delay_s": float(d[0]), "lever_arm_m": d[1:4].tolist(),
                       "boresight_deg": np.degrees(d[4:]).tolist()},
        "combined_sigma": {"delay_s": float(np.sqrt(var[0])), "lever_arm_m": np.sqrt(var[1:4]).tolist(),
                           "boresight_deg": np.degrees(np.sqrt(var[4:])).tolist()},
        "z": {n: (None if not np.isfinite(v) else float(v)) for n, v in zip(names, z)},
        "chi2": stat, "dof": dof, "p_value": p, "alpha": alpha,
        "changed": bool(dof and p < alpha),
        "not_tested": unfixed,
        "methods": [old.method, new.method],
    }


def compare_mounting_files(opts: CompareOptions) -> dict:
    """`dgcal compare`: `compare_mountings` of the two mounting.json files of `opts`."""
    return compare_mountings(read_mounting_json(opts.old), read_mounting_json(opts.new), opts.alpha)
