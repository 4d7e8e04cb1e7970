"""What the 2,000-case reader fuzz run of issue 31 found accepted, each refused now with an InputError naming the file
and field: a camera parameter sigma of 1e25, a GNSS-fix velocity sigma of 1e308, a NaN height in a GNSS packet log,
an infinite laser-range sigma, an RTKLIB time tag's file position of 4.5e16 bytes, an infinite per-epoch value in a
mounting.json, an SMRMSG sigma of 3.4e12."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from dgcal.fields.errors import InputError

from test_formats_fuzz import _tag_bytes
from test_fuzz_readers import GNSS_LOG, LASER_RANGES, s_camera_json, s_gnss_fixes


def test_camera_sigma_of_1e25(tmp_path):
    from dgcal.calib.camera.files import read_camera
    d = json.loads(s_camera_json(tmp_path))
    k = next(iter(d["sigmas"]))
    d["sigmas"][k] = 1e25
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=rf"field 'sigmas\.{k}'.*implausibly large"):
        read_camera(p)


@pytest.mark.parametrize("column, value", [("s_vn", "1e308"), ("vx", "1e20"), ("s_n", "inf"), ("t_gps", "1e20")])
def test_gnss_fix_values(tmp_path, column, value):
    from dgcal.pos.lowcost.fix_files import read_gnss_fixes
    lines = s_gnss_fixes(tmp_path).decode().splitlines()
    head = lines[0].split(",")
    row = lines[2].split(",")
    row[head.index(column)] = value
    lines[2] = ",".join(row)
    p = tmp_path / "fixes.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"fixes\.csv:3: field '{column}'"):
        read_gnss_fixes(p)


def test_gnss_log_nan_height(tmp_path):
    from dgcal.pos.lowcost.logger_format import read_gnss_log
    p = tmp_path / "gnss_log.csv"
    p.write_bytes(GNSS_LOG.replace(b"120.550", b"nan"))
    assert b"nan" in p.read_bytes()
    with pytest.raises(InputError, match=r"gnss_log\.csv:\d+: field 'h'"):
        read_gnss_log(p)


@pytest.mark.parametrize("value", [b"inf", b"-1", b"1e20"])
def test_laser_range_sigma(tmp_path, value):
    from dgcal.calib.dg.single_image import read_laser_ranges
    p = tmp_path / "ranges.csv"
    p.write_bytes(LASER_RANGES.replace(b"0.05\nIMG_0002", value + b"\nIMG_0002"))
    with pytest.raises(InputError, match=r"ranges\.csv:2: field 's_range_m'"):
        read_laser_ranges(p)


def test_time_tag_file_position_beyond_any_file(tmp_path):
    from dgcal.pos.ins.time_tags import read_time_tag
    data = _tag_bytes(4)
    head, rec = data[:76], data[76:]
    recs = [struct.unpack_from("<II", rec, 8 * i) for i in range(4)]
    big = b"".join(struct.pack("<IQ", t, f if i < 3 else 45_317_500_000_000_000) for i, (t, f) in enumerate(recs))
    p = tmp_path / "imu.tag"
    p.write_bytes(head + big)
    with pytest.raises(InputError, match=r"file position 45317500000000000 at record 4 is beyond any data file"):
        read_time_tag(p, fpos_bytes=8)
    p.write_bytes(head + b"".join(struct.pack("<IQ", t, f) for t, f in recs))
    assert np.array_equal(read_time_tag(p, fpos_bytes=8).fpos, [f for _, f in recs])


@pytest.mark.parametrize("value", ["Infinity", "1e300"])
def test_mounting_per_epoch_value(tmp_path, value):
    from dgcal.calib.mounting.common import read_mounting_json
    from test_fuzz_readers import s_mounting
    text = s_mounting(tmp_path).decode()
    d = json.loads(text)
    d["per_epoch"]["lever_x"][1] = 0.125
    p = tmp_path / "mounting.json"
    p.write_text(json.dumps(d).replace("0.125", value))
    with pytest.raises(InputError, match=r"field 'per_epoch\.lever_x\[1\]'"):
        read_mounting_json(p)
    d["per_epoch"]["lever_x"][1] = float("nan")            # an epoch left out: kept
    p.write_text(json.dumps(d))
    assert np.isnan(read_mounting_json(p).per_epoch["lever_x"][1])


@pytest.mark.parametrize("value", [3.4e12, -0.5, np.nan])
def test_smrmsg_sigma(tmp_path, value):
    from dgcal.pos.ins.sbet import SMRMSG_DTYPE, read_smrmsg
    from test_fuzz_readers import s_smrmsg
    r = np.frombuffer(s_smrmsg(tmp_path), SMRMSG_DTYPE).copy()
    assert read_smrmsg(_write(tmp_path, r), 2374)[1].shape == (4, 6)
    r["s_east"][2] = value
    with pytest.raises(InputError, match=r"smrmsg\.out: field 's_east': .*record 3"):
        read_smrmsg(_write(tmp_path, r), 2374)


def _write(tmp_path, r):
    p = tmp_path / "smrmsg.out"
    p.write_bytes(r.tobytes())
    return p
