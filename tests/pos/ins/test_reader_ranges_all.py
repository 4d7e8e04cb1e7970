"""Every number of the IMU text readers and of SBET records bounded (issue 31): 1e20, -1e20, inf and nan put in
each number of a valid file, one at a time, are refused with an InputError naming the file - never accepted into
the samples (a week or time of 1e20 made GPS times of 6e25 s)."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.pos.ins.sbet import SBET_DTYPE, read_sbet

from fuzz_checks import bad_values
from test_formats_fuzz import IMU_CSV, _imu_reader
from test_fuzz_readers import _imp, _numeric_tokens, s_imu_csv, s_kf_gins

BAD = (b"1e20", b"-1e20", b"inf", b"nan")


def _every_number_bounded(tmp_path, name: str, data: bytes, reader, every: int = 1) -> int:
    """Each numeric token (every `every`-th) replaced by each of BAD: refused, or accepted with sound numbers."""
    tried = 0
    for s, e in _numeric_tokens(data)[::every]:
        for v in BAD:
            p = tmp_path / name
            p.write_bytes(data[:s] + v + data[e:])
            try:
                res = reader(p)
            except InputError as exc:
                assert name in str(exc)
            else:
                problem = bad_values(res, set(), True)
                assert problem is None, (data[max(0, s - 20):e], v, problem)
            tried += 1
    return tried


@pytest.mark.parametrize("kind", ["imu-csv", "kf-gins", "imu-description"])
def test_imu_text_readers(tmp_path, kind):
    if kind == "imu-csv":
        data, reader = s_imu_csv(tmp_path), _imp("dgcal.pos.ins.imu_data", "read_imu_csv")(tmp_path)
    elif kind == "kf-gins":
        data, reader = s_kf_gins(tmp_path), _imp("dgcal.pos.ins.imu_data", "read_kf_gins")(tmp_path)
    else:
        data, reader = IMU_CSV.encode(), _imu_reader(tmp_path)
    assert _every_number_bounded(tmp_path, "input.csv", data, reader, every=3) >= 100


@pytest.mark.parametrize("field", SBET_DTYPE.names)
@pytest.mark.parametrize("value", [1e20, -1e20, np.inf, np.nan])
def test_every_sbet_field(tmp_path, field, value):
    r = np.zeros(4, SBET_DTYPE)
    r["time"] = 243258.5 + np.arange(4)
    r["lat"], r["lon"], r["alt"] = np.radians(40.1), np.radians(-105.1), 1601.0
    p = tmp_path / "sbet.out"
    r.tofile(p)
    assert len(read_sbet(p, 2374).trajectory.t) == 4
    r[field][2] = value
    r.tofile(p)
    try:
        res = read_sbet(p, 2374)
    except InputError as exc:
        assert "sbet.out" in str(exc)
    else:
        assert bad_values(res, set(), True) is None, field
