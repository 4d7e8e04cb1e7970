"""The RAIM test's chi-square points: the table for the default false-alarm probability is scipy's, anything off
the table goes to scipy, and a single-point run never imports scipy (the table's reason)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
from scipy.special import chdtri

from dgcal.pos.gnss.chi2_points import TABLE, TABLE_ALPHA, chi2_limit


def test_the_table_is_scipys():
    dof = np.arange(1, len(TABLE) + 1)
    np.testing.assert_allclose(TABLE, chdtri(dof, TABLE_ALPHA), rtol=1e-14)
    np.testing.assert_allclose(chi2_limit(dof, TABLE_ALPHA), chdtri(dof, TABLE_ALPHA), rtol=1e-14)


def test_off_the_table_and_without_degrees_of_freedom():
    dof = np.array([0.0, -2.0, np.nan, 1.0, 7.0, 100.0])
    got = chi2_limit(dof, TABLE_ALPHA)
    assert np.all(np.isnan(got[:3])) and np.allclose(got[3:], chdtri(dof[3:], TABLE_ALPHA), rtol=1e-14)
    for d, alpha in (([2.5, 4.0], TABLE_ALPHA), ([150.0, 3.0], TABLE_ALPHA), ([1.0, 12.0], 0.01)):
        np.testing.assert_allclose(chi2_limit(np.array(d), alpha), chdtri(np.array(d), alpha), rtol=1e-14)
    assert chi2_limit(np.array(5), TABLE_ALPHA).shape == ()


def test_a_single_point_run_does_not_import_scipy(shared_data):
    code = ("import sys; from dgcal.pos.gnss.spp import SppOptions, spp_files; "
            f"spp_files({str(shared_data / 'rinex-sept' / 'SEPT078M1.21O')!r}, "
            f"[{str(shared_data / 'rinex-sept' / 'SEPT078M.21P')!r}], SppOptions()); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
