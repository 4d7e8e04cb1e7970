import os
import sys
from pathlib import Path

import pytest

# Two cores shared by two test workers: BLAS threads would only thrash (a 190x190 solve took 170 ms
# threaded against 0.8 ms single-threaded). Set before numpy is imported by the tests.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

# The test folders mirror the packages (tests/pos/gnss/ tests dgcal.pos.gnss, ...). Test modules share helpers
# across folders (`from test_gnss_rinex2 import OBS_304`): every folder is importable, as pytest's default
# rootdir-relative import would make only the importing module's own folder. Basenames are unique.
TESTS = Path(__file__).resolve().parent
sys.path[:0] = [str(d) for d in sorted(TESTS.rglob("*")) if d.is_dir() and d.name != "__pycache__"
                and str(d) not in sys.path]


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real data sets of ../shared/data (read in place, never copied)."""
    if not SHARED_DATA.is_dir():
        pytest.fail(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA
