"""Navigation files with records dgcal does not use (issue 30): the DJI M300 writes RINEX 3.05 headers with GLONASS
records in the older 4-line layout; such records are read for SPP (`BroadcastNav.glonass`), SBAS records skipped with
one warning, the GPS/Galileo/QZSS records read as from a file without them. A corrupt record of a system in use is
still an error naming file, line and field."""
import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import read_rinex_nav

NAV = "rinex-sept/SEPT078M.21P"

GLO_4 = ["R{prn:02d} 2021 03 19 11 45 00 -.173244997859D-04 -.909494701773D-12  .410400000000D+05",
         "     -.143158149414D+05 -.181903648376D+01  .931322574616D-09  .000000000000D+00",
         "     -.733007226562D+04 -.165002059937D+01  .000000000000D+00  .100000000000D+01",
         "      .201220751953D+05 -.227833747864D+01 -.279396772385D-08  .000000000000D+00"]
GLO_5TH = "      .000000000000D+00  .000000000000D+00  .000000000000D+00  .000000000000D+00"
SBAS = ["S27 2021 03 19 11 58 56  .000000000000D+00  .000000000000D+00  .471536000000D+06",
        "      .409574280000D+05  .000000000000D+00  .000000000000D+00  .630000000000D+02",
        "     -.112800000000D+03  .000000000000D+00  .000000000000D+00  .327670000000D+05",
        "      .000000000000D+00  .000000000000D+00  .000000000000D+00  .100000000000D+01"]


def _records(lines: list[str]) -> tuple[list[str], list[list[str]]]:
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s)
    recs, cur = [], None
    for s in lines[end + 1:]:
        if s[:1].strip():
            cur = [s]
            recs.append(cur)
        elif cur is not None and s.strip():
            cur.append(s)
    return lines[:end + 1], recs


def _dji_like(src: list[str], five_line: bool = False, sbas: bool = False) -> tuple[list[str], int, int]:
    """`src` under a 3.05 header with GLONASS records (4 lines each, or 5) before, between and after its records;
    returns the lines, the number of GLONASS records and the line number of the first."""
    head, recs = _records(src)
    head = list(head)
    head[0] = f"{3.05:9.2f}" + head[0][9:]
    glo = [s for s in GLO_4] + ([GLO_5TH] if five_line else [])
    out = list(head)
    first, n_glo = None, 0
    for k, rec in enumerate(recs):
        if k % 40 == 0:
            if first is None:
                first = len(out) + 1
            out += [s.format(prn=1 + k // 40) for s in glo]
            n_glo += 1
        out += rec
        if sbas and k == 5:
            out += SBAS
    out += [s.format(prn=24) for s in glo]
    return out, n_glo + 1, first


def _params(nav) -> list[tuple]:
    keys = ("sat", "A", "e", "M0", "deln", "omg", "cuc", "cus", "crc", "crs", "cic", "cis", "i0", "idot", "OMG0",
            "OMGd", "toes", "af0", "af1", "af2", "tgd", "sva", "svh", "mode")
    return sorted(tuple(float(getattr(e, k)) for k in keys) for e in nav.eph)


@pytest.mark.parametrize("five_line", [False, True])
def test_glonass_records_read_sbas_skipped_the_rest_read_identically(shared_data, tmp_path, five_line):
    src = (shared_data / NAV).read_text().splitlines()
    lines, n_glo, first = _dji_like(src, five_line=five_line, sbas=True)
    f = tmp_path / "dji.rnx"
    f.write_text("\n".join(lines) + "\n")
    ref = read_rinex_nav(shared_data / NAV)
    nav = read_rinex_nav(f)
    assert len(nav.eph) == len(ref.eph) > 200
    assert _params(nav) == _params(ref)
    assert np.array_equal(nav.ion_gps, ref.ion_gps) and nav.leap_seconds == ref.leap_seconds
    skipped = [w for w in nav.warnings if "skipped" in w]
    assert len(skipped) == 1, nav.warnings
    assert "GLONASS" not in skipped[0] and "1 SBAS" in skipped[0]
    assert len(nav.glonass) == n_glo and nav.glonass.line.min() == first
    assert np.all(nav.glonass.frq == 1) and np.all(nav.glonass.svh == 0)
    assert str(f) in skipped[0]
    assert [w for w in nav.warnings if "skipped" not in w] == ref.warnings


def test_corrupt_record_of_a_used_system_names_line_and_field(shared_data, tmp_path):
    src = (shared_data / NAV).read_text().splitlines()
    lines, _, _ = _dji_like(src)
    g = next(i for i, s in enumerate(lines) if s[:1] == "G" and s[1:3].isdigit())
    bad = list(lines)
    orb = bad[g + 3]
    bad[g + 3] = orb[:4 + 19 * 3] + "  .54406x41690D+04" + orb[4 + 19 * 4:]
    f = tmp_path / "bad.rnx"
    f.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as e:
        read_rinex_nav(f)
    assert e.value.line == g + 4 and e.value.field == "BROADCAST ORBIT - 3: Cis"
    # a GPS record that lost its last orbit line: named where the line is missing
    bad = list(lines)
    del bad[g + 7]
    f.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as e:
        read_rinex_nav(f)
    assert e.value.line == g + 8 and e.value.field == "BROADCAST ORBIT - 7" and "6 orbit lines" in str(e.value)
    # a line that begins no record
    bad = list(lines)
    bad[g] = "X" + bad[g][1:]
    f.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as e:
        read_rinex_nav(f)
    assert e.value.line == g + 1 and e.value.field == "SV / EPOCH / SV CLK"


def test_only_sbas_is_an_error_naming_the_systems_only_glonass_is_read(shared_data, tmp_path):
    src = (shared_data / NAV).read_text().splitlines()
    head, _ = _records(src)
    f = tmp_path / "sbas.rnx"
    f.write_text("\n".join(list(head) + SBAS) + "\n")
    with pytest.raises(InputError, match="no GPS/Galileo/BeiDou/QZSS/GLONASS ephemeris"):
        read_rinex_nav(f)
    f = tmp_path / "glo.rnx"
    f.write_text("\n".join(list(head) + [s.format(prn=3) for s in GLO_4]) + "\n")
    nav = read_rinex_nav(f)
    assert not nav.by_sat and list(nav.glonass.sat) == ["R03"]
