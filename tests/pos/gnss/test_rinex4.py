"""RINEX 4 (`pos/gnss/rinex_nav._rinex4_as_3`, `rinex_obs.rinex_version_type`): a navigation file written as RINEX 4
(record-type lines, Klobuchar in ION records, CNAV and STO records beside) reads to the same ephemerides and
coefficients as its RINEX 3 original; real RINEX 4.02 files of cssrlib-data agree with cssrlib's own RINEX 4 decoder;
observation files of version 4 read as 3.x; errors name line and field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cssrlib.gnss import Nav
from cssrlib.rinex import rnxdec

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs

DATA = Path(__file__).parent / "data"
NAV3 = "rinex-sept/SEPT078M.21P"
OBS3 = "rinex-sept/SEPT078M1.21O"
REAL4 = DATA / "233h_rnx_part.nav"     # cssrlib-data doy2025-233, RINEX 4.02, the first records of each message


def _d(x: float) -> str:
    m, e = f"{x:.12E}".split("E")
    return f"{m:>15}E{int(e):+03d}"


def as_rinex4(lines: list[str]) -> list[str]:
    """A RINEX 3 navigation file rewritten as RINEX 4.02: `> EPH` lines, the header's GPSA/GPSB and QZSA/QZSB as
    `> ION` records, one STO record and a CNAV copy of the first GPS record (which a reader must leave out)."""
    head, body, end = [], [], next(i for i, x in enumerate(lines) if "END OF HEADER" in x)
    coef = {}
    for x in lines[1:end]:
        if "IONOSPHERIC CORR" in x:       # Klobuchar pairs become ION records (Galileo's NeQuick is not used)
            if x[:4] in ("GPSA", "GPSB", "QZSA", "QZSB"):
                coef[x[:4]] = [float(x[5 + 12 * k:17 + 12 * k].replace("D", "E")) for k in range(4)]
        else:
            head.append(x)
    out = [f"{4.02:9.2f}{'':11}{'NAVIGATION DATA':<20}{'M':<20}RINEX VERSION / TYPE"] + head + [lines[end]]
    epoch = "    2021 03 19 10 00 00"
    for sys, a, b in (("G", "GPSA", "GPSB"), ("J", "QZSA", "QZSB")):
        if a in coef:
            al, be = coef[a], coef[b]
            out += [f"> ION {sys}01 LNAV", epoch + "".join(_d(v) for v in al[:3]),
                    "    " + "".join(_d(v) for v in [al[3]] + be[:3]), "    " + _d(be[3])]
    out += ["> STO G01 LNAV", epoch + " GPUT", "    " + "".join(_d(v) for v in (345600.0, 1e-9, 0.0, 0.0))]
    i, first_gps = end + 1, True
    while i < len(lines):
        j = i + 1
        while j < len(lines) and lines[j][:4] == "    ":
            j += 1
        sys, rec = lines[i][0], lines[i:j]
        if sys == "E":
            src = int(float(rec[5][23:42].replace("D", "E")))
            msg = "FNAV" if src & 2 else "INAV"
        else:
            msg = {"G": "LNAV", "J": "LNAV", "R": "FDMA", "C": "D1", "S": "SBAS"}[sys]
        if sys == "G" and first_gps:
            body += [f"> EPH {lines[i][:3]} CNAV"] + rec + ["    " + _d(0.0)]     # 9 lines: not RINEX 3's layout
            first_gps = False
        body += [f"> EPH {lines[i][:3]} {msg}"] + rec
        i = j
    return out + body


def test_rinex4_navigation_reads_as_its_rinex3_original(shared_data, tmp_path):
    lines = (shared_data / NAV3).read_text().splitlines()
    p4 = tmp_path / "SEPT078M.rnx"
    p4.write_text("\n".join(as_rinex4(lines)) + "\n")
    n3, n4 = read_rinex_nav(shared_data / NAV3), read_rinex_nav(p4)
    key = [(e.sat, e.toe.time, e.toe.sec, e.A, e.e, e.M0, e.af0, e.tgd) for e in n3.eph]
    assert [(e.sat, e.toe.time, e.toe.sec, e.A, e.e, e.M0, e.af0, e.tgd) for e in n4.eph] == key
    np.testing.assert_allclose(n4.ion_gps, n3.ion_gps, rtol=1e-12)
    assert n4.ion_source == n3.ion_source == "GPSA/GPSB"
    assert any("1 GPS CNAV" in w for w in n4.warnings)
    # SPP on either file: the same positions
    obs = str(shared_data / OBS3)
    for nav, out in ((shared_data / NAV3, "o3"), (p4, "o4")):
        assert main(["pos", "--mode", "spp", "--rinex-obs", obs, "--rinex-nav", str(nav), "--no-progress",
                     "--no-report", "--out", str(tmp_path / out)]) == 0
    assert (tmp_path / "o3" / "gnss.csv").read_text() == (tmp_path / "o4" / "gnss.csv").read_text()


def test_real_rinex4_file_agrees_with_cssrlibs_own_decoder():
    """cssrlib reads RINEX 4 itself (every message); dgcal's RINEX 3 layout of it keeps exactly the LNAV, I/NAV,
    F/NAV messages among them, field for field, and its GLONASS FDMA records."""
    ours = read_rinex_nav(REAL4)
    ref = rnxdec().decode_nav(str(REAL4), Nav())
    def key(e):
        return (e.sat, e.toe.time, e.toe.sec, e.A, e.e, e.i0, e.OMG0, e.omg, e.M0, e.af0, e.af1)
    theirs = {key(e) for e in ref.eph}
    assert len(ours.eph) >= 10 and {key(e) for e in ours.eph} <= theirs
    systems = {e.sat for e in ours.eph}
    assert len(systems) >= 3
    assert ours.glonass is not None and len(ours.glonass.sat) >= 1
    assert any("RINEX 4 messages RINEX 3 does not carry left out" in w and "GPS CNAV" in w for w in ours.warnings)


def test_rinex4_observation_file_reads_as_3(shared_data, tmp_path):
    lines = (shared_data / OBS3).read_text().splitlines()
    lines[0] = f"{4.02:9.2f}" + lines[0][9:]
    p = tmp_path / "SEPT078M1.rnx"
    p.write_text("\n".join(lines) + "\n")
    a, b = read_rinex_obs(shared_data / OBS3), read_rinex_obs(p)
    assert len(a.epochs) == len(b.epochs) == 60
    assert all(x.sat == y.sat and np.array_equal(x.pr_m, y.pr_m) for x, y in zip(a.epochs, b.epochs))


def test_rinex4_errors_name_line_and_field(shared_data, tmp_path):
    v4 = as_rinex4((shared_data / NAV3).read_text().splitlines())
    ion = v4.index("> ION G01 LNAV")
    bad = list(v4)
    bad[ion + 2] = bad[ion + 2][:4] + "    x.xxxE+00      " + bad[ion + 2][23:]
    p = tmp_path / "bad.rnx"
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError, match=f"bad.rnx:{ion + 3}: field 'ION G LNAV alpha3'"):
        read_rinex_nav(p)
    stray = list(v4)
    stray.insert(ion, "G01 this is not a record line")
    p.write_text("\n".join(stray) + "\n")
    with pytest.raises(InputError, match=f":{ion + 1}: field 'record type'"):
        read_rinex_nav(p)
    late = list(v4)
    late[0] = f"{5.0:9.2f}" + late[0][9:]
    p.write_text("\n".join(late) + "\n")
    with pytest.raises(InputError, match="need 2.10-4.02"):
        read_rinex_nav(p)
