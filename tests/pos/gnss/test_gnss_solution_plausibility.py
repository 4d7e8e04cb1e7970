"""GNSS antenna positions must lie near the Earth's surface for their frame (issue 31): a gnss.csv in kilometres or
an RTKLIB .pos with impossible heights is refused naming the row and the likely cause."""
from __future__ import annotations

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.pos.gnss.solution_files import GnssSolution, read_gnss_csv, read_rtklib_pos, write_rtklib_pos

P = np.array([-3962108.673, 3381309.574, 3668678.638])


def _csv(path, p):
    rows = ["gps_week,gps_sow,x,y,z,sx,sy,sz"] + [f"2150,{100.0 + k},{x:.4f},{y:.4f},{z:.4f},0.5,0.5,0.8"
                                                   for k, (x, y, z) in enumerate(p)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_gnss_csv_in_kilometres_is_refused_naming_it(tmp_path):
    ok = _csv(tmp_path / "ok.csv", P + np.arange(5)[:, None])
    assert len(read_gnss_csv(ok).t) == 5
    with pytest.raises(InputError) as exc:
        read_gnss_csv(_csv(tmp_path / "km.csv", (P + np.arange(5)[:, None]) / 1e3))
    msg = str(exc.value)
    assert "km.csv:2" in msg and "kilometres, not metres" in msg


def test_near_surface_limits():
    validate.ecef_near_surface(P)
    validate.ecef_near_surface(P * (1 + 8e3 / np.linalg.norm(P)))        # 8 km up: an aircraft
    with pytest.raises(InputError, match="not ECEF metres"):
        validate.ecef_near_surface(P * 2)
    with pytest.raises(InputError, match="missing or zero"):
        validate.ecef_near_surface([P[0], 0.0, P[2]])


def test_an_rtklib_pos_with_heights_in_another_unit_is_refused(tmp_path):
    n = 4
    sol = GnssSolution(np.arange(n) + 1.3e9, np.tile(P, (n, 1)), np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
                       np.ones(n, int), np.full(n, 12))
    good = tmp_path / "good.pos"
    write_rtklib_pos(good, sol)
    assert len(read_rtklib_pos(good).t) == n
    lines = good.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if not s.startswith("%"))
    parts = lines[k].split()
    parts[4] = f"{float(parts[4]) * 1e3:.4f}"            # height in mm
    lines[k] = "  ".join(parts)
    bad = tmp_path / "bad.pos"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="outside the plausible range"):
        read_rtklib_pos(bad)
