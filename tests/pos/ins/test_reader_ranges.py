"""Readers refuse values no sensor or orbit can have (issue 31: the IMU, SBET and RINEX navigation readers took
1e20): an IMU sample beyond any IMU's range and an SBET field out of range name their line/record and field; a
navigation record with an impossible orbit is left out with a warning naming the satellite."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.pos.ins.imu_data import ImuData, read_imu_csv, write_imu_csv
from dgcal.pos.ins.sbet import SBET_DTYPE, read_sbet


def test_an_imu_sample_of_1e20_names_its_line_and_column(tmp_path):
    n, rate = 200, 100.0
    t = 1.3e9 + np.arange(1, n + 1) / rate
    imu = ImuData(t, np.full((n, 3), 1e-4), np.tile([0.0, 0.0, -9.8 / rate], (n, 1)), rate)
    p = tmp_path / "imu.csv"
    write_imu_csv(p, imu)
    assert len(read_imu_csv(p)) == n
    lines = p.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if s and s[0].isdigit()) + 50
    parts = lines[k].split(",")
    parts[-1] = "1e20"
    lines[k] = ",".join(parts)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as exc:
        read_imu_csv(p)
    assert f"imu.csv:{k + 1}" in str(exc.value) and "beyond any IMU's range" in str(exc.value)


def test_an_sbet_field_out_of_range_names_record_and_field(tmp_path):
    r = np.zeros(5, dtype=SBET_DTYPE)
    r["time"] = 1000.0 + np.arange(5)
    r["lat"], r["lon"], r["alt"] = 0.6, 2.1, 120.0
    p = tmp_path / "a.out"
    r.tofile(p)
    assert len(read_sbet(p, 2150).trajectory.t) == 5
    r["lat"][3] = 1e20
    r.tofile(p)
    with pytest.raises(InputError) as exc:
        read_sbet(p, 2150)
    assert exc.value.field == "lat" and "record 4" in str(exc.value)


def test_a_navigation_record_with_an_impossible_orbit_is_left_out(shared_data, tmp_path):
    from dgcal.pos.gnss.rinex import read_rinex_nav
    src = shared_data / "rinex-sept" / "SEPT078M.21P"
    clean = read_rinex_nav(src)
    lines = src.read_text().splitlines()
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s)
    k = next(i for i in range(end + 1, len(lines)) if lines[i].startswith("G"))
    row = lines[k + 2]                                   # Cuc, e, Cus, sqrt(A)
    lines[k + 2] = row[:61] + "1.000000000000E+20"
    p = tmp_path / "nav.rnx"
    p.write_text("\n".join(lines) + "\n")
    nav = read_rinex_nav(p)
    sid = lines[k][:3]
    assert len(nav.by_sat.get(sid, [])) == len(clean.by_sat[sid]) - 1
    assert any(sid in w and "impossible orbit" in w for w in nav.warnings)
