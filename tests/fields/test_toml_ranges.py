"""Numbers in every TOML file dgcal reads are bounded at read time (issue 31): a 20-digit integer, nan, inf or 1e300
in a campaign, board, logger-format, IMU-format or IMU-datasheet file is refused with one InputError naming the
file, the line and the key - instead of an overflow (TypeError, OverflowError) or a poisoned result later."""
from __future__ import annotations

import re
import tomllib

import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.validate import MAX_TOML_NUMBER, toml_numbers_in_range

from test_formats_fuzz import GRADE, IMU_TOML
from test_fuzz_readers import BOARD, CAMPAIGN, LOGGER_FORMAT


def _readers():
    from dgcal.campaign import load_campaign
    from dgcal.fields.targets.boards import read_board
    from dgcal.pos.ins.error_model import read_imu_datasheet
    from dgcal.pos.ins.imu_formats import imu_format
    from dgcal.pos.lowcost.logger_format import read_logger_format
    return {"campaign": (CAMPAIGN, load_campaign, "pos.base_position[1]", b"5029425.6965"),
            "board": (BOARD, read_board, "columns", b"7"),
            "logger-format": (LOGGER_FORMAT, read_logger_format, "signals.trigger_level", b"0.5"),
            "imu-format": (IMU_TOML.encode(), imu_format, "axes.mounting_deg[2]", b"5.35"),
            "imu-datasheet": (GRADE.encode(), read_imu_datasheet, "gyro.turn_on_deg_s", b"0.2")}


@pytest.mark.parametrize("bad", [b"123456789012345678901", b"-99999999999999999999", b"nan", b"-inf", b"1e300"])
@pytest.mark.parametrize("kind", ["campaign", "board", "logger-format", "imu-format", "imu-datasheet"])
def test_out_of_range_number_named_by_file_line_key(tmp_path, kind, bad):
    text, read, key, value = _readers()[kind]
    assert text.count(value) >= 1
    i = text.index(value)
    line = text[:i].count(b"\n") + 1
    p = tmp_path / f"{kind}.toml"
    p.write_bytes(text[:i] + bad + text[i + len(value):])
    with pytest.raises(InputError) as exc:
        read(p)
    msg = str(exc.value)
    # the campaign's own key checks (check_campaign) come first and name the key without the index
    assert msg.startswith(f"{p}:{line}: field '{key if kind != 'campaign' else key.split('[')[0]}"), msg
    assert re.search("not a finite number|out of range|outside the plausible range", msg), msg


def test_helper_keeps_valid_files_and_names_nested_keys():
    text = "a = 1.5\nb = [1, 2]\n[t]\nx = -3\n[[r]]\ny = [0.5, 1e13]\n"
    with pytest.raises(InputError, match=r"f\.toml:6: field 'r\[0\]\.y\[1\]': 1e\+13 is out of range"):
        toml_numbers_in_range(tomllib.loads(text), "f.toml", text)
    ok = "a = 1.5\nb = [1, 2]\nc = true\nd = 2025-01-01\n[t]\nx = -3\n"
    assert toml_numbers_in_range(tomllib.loads(ok), "f.toml", ok)["t"]["x"] == -3
    assert MAX_TOML_NUMBER >= 1e10    # GPS seconds (1.5e9) and ECEF metres fit
