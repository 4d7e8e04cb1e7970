# ruff: noqa: E501  (RINEX 3 observation records are longer than 120 characters)
"""RINEX 2.11 observation and navigation files (hand-written, exact format) read equal to their RINEX 3.04 twins;
every RINEX 3 code (receiver channels X1); one-line errors naming file, line and field; missing ionosphere."""
import json

import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.rinex_obs import read_obs_file, rinex2_code

OBS_211 = """\
     2.11           OBSERVATION DATA    M (MIXED)           RINEX VERSION / TYPE
dgcal test                              20210319 120000 UTC PGM / RUN BY / DATE
TEST                                                        MARKER NAME
 -3962108.4557  3381308.8777  3668678.1749                  APPROX POSITION XYZ
        0.0000        0.0000        0.0000                  ANTENNA: DELTA H/E/N
     1     1                                                WAVELENGTH FACT L1/2
     7    C1    L1    L2    P2    S1    S2    D1            # / TYPES OF OBSERV
     1.000                                                  INTERVAL
  2021     3    19    12     0    0.0000000     GPS         TIME OF FIRST OBS
                                                            END OF HEADER
 21 03 19 12 00  0.0000000  0  3G05 12E11
  23629347.915   124173415.678 8  96758494.221 6  23629351.430          48.000
        38.500       -1234.567
  21420119.208   112563011.349 9  87711402.116 7  21420122.012          51.250
        44.000        2345.125
  25653954.884   134812488.325 7                                        42.500
                     -3456.250
 21 03 19 12 00  0.5000000  4  1
an event record: one comment line                           COMMENT
 21 03 19 12 00  1.0000000  0  3G05G12E11
  23629582.101   124174646.30118  96759453.119 6  23629585.602          47.750
        38.250       -1234.125
  21419673.504   112560669.012 9  87709577.007 7  21419676.321          51.000
        44.250        2345.500
  25654605.032   134815905.444 7                                        42.000
                     -3456.000
"""

OBS_304 = """\
     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE
dgcal test                              20210319 120000 UTC PGM / RUN BY / DATE
TEST                                                        MARKER NAME
 -3962108.4557  3381308.8777  3668678.1749                  APPROX POSITION XYZ
        0.0000        0.0000        0.0000                  ANTENNA: DELTA H/E/N
G    8 C1C L1C L2W C2W S1C S2W D1C X1                       SYS / # / OBS TYPES
E    5 C1X L1X S1X D1X X1                                   SYS / # / OBS TYPES
     1.000                                                  INTERVAL
  2021     3    19    12     0    0.0000000     GPS         TIME OF FIRST OBS
                                                            END OF HEADER
> 2021 03 19 12 00  0.0000000  0  3
G05  23629347.915   124173415.678 8  96758494.221 6  23629351.430          48.000          38.500       -1234.567           7.000
G12  21420119.208   112563011.349 9  87711402.116 7  21420122.012          51.250          44.000        2345.125           7.000
E11  25653954.884   134812488.325 7        42.500       -3456.250          12.000
> 2021 03 19 12 00  1.0000000  0  3
G05  23629582.101   124174646.30118  96759453.119 6  23629585.602          47.750          38.250       -1234.125           7.000
G12  21419673.504   112560669.012 9  87709577.007 7  21419676.321          51.000          44.250        2345.500           7.000
E11  25654605.032   134815905.444 7        42.000       -3456.000          12.000
"""

NAV_211 = """\
     2.11           N: GPS NAV DATA                         RINEX VERSION / TYPE
dgcal test                              20210319 120000 UTC PGM / RUN BY / DATE
     .1118D-07   .7451D-08  -.5960D-07  -.5960D-07          ION ALPHA
     .9011D+05   .0000D+00  -.1966D+06  -.6554D+05          ION BETA
    18                                                      LEAP SECONDS
                                                            END OF HEADER
 3 21 03 19 12 00 00.0 -.112356152385D-03 -.105728759081D-10  .000000000000D+00
     .370000000000D+02 -.265625000000D+01  .456911889357D-08  .634492237240D+00
    -.396743416786D-06  .332982675172D-02  .693649053574D-05  .515363021851D+04
     .475200000000D+06 -.316649675369D-07 -.114852075735D+01  .521540641785D-07
     .968334075252D+00  .251343750000D+03  .830273530968D+00 -.808605110220D-08
     .331442377334D-09  .100000000000D+01  .214900000000D+04  .000000000000D+00
     .200000000000D+01  .000000000000D+00  .186264514923D-08  .370000000000D+02
     .471606000000D+06  .400000000000D+01
"""

NAV_304 = """\
     3.04           N: GNSS NAV DATA    M: Mixed            RINEX VERSION / TYPE
dgcal test                              20210319 120000 UTC PGM / RUN BY / DATE
GPSA    .1118D-07   .7451D-08  -.5960D-07  -.5960D-07       IONOSPHERIC CORR
GPSB    .9011D+05   .0000D+00  -.1966D+06  -.6554D+05       IONOSPHERIC CORR
    18    18  2031     7                                    LEAP SECONDS
                                                            END OF HEADER
G03 2021 03 19 12 00 00 -.112356152385D-03 -.105728759081D-10  .000000000000D+00
      .370000000000D+02 -.265625000000D+01  .456911889357D-08  .634492237240D+00
     -.396743416786D-06  .332982675172D-02  .693649053574D-05  .515363021851D+04
      .475200000000D+06 -.316649675369D-07 -.114852075735D+01  .521540641785D-07
      .968334075252D+00  .251343750000D+03  .830273530968D+00 -.808605110220D-08
      .331442377334D-09  .100000000000D+01  .214900000000D+04  .000000000000D+00
      .200000000000D+01  .000000000000D+00  .186264514923D-08  .370000000000D+02
      .471606000000D+06  .400000000000D+01
"""


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_rinex2_observations_equal_rinex3(tmp_path):
    a = read_obs_file(_write(tmp_path, "t.21o", OBS_211))
    b = read_obs_file(_write(tmp_path, "t.rnx", OBS_304))
    assert a.version == 2.11 and b.version == 3.04
    np.testing.assert_allclose(a.t_gps, b.t_gps)          # the event record (flag 4) is skipped
    np.testing.assert_allclose(np.diff(a.t_gps), 1.0)
    np.testing.assert_allclose(a.p_approx_ecef, [-3962108.4557, 3381308.8777, 3668678.1749])
    assert a.systems["G"].sats == ["G05", "G12"]          # ' 12' (blank system) is GPS in RINEX 2
    assert a.systems["G"].codes == ["C1C", "L1C", "L2W", "C2W", "S1C", "S2W", "D1C"]
    assert a.systems["E"].codes == ["C1X", "L1X", "S1X", "D1X"]
    assert b.systems["G"].codes[-1] == "X1"              # receiver channel numbers are an observation type
    np.testing.assert_allclose(b.systems["G"].val[:, :, -1], 7.0)
    for s in ("G", "E"):
        A, B = a.systems[s], b.systems[s]
        assert A.sats == B.sats
        for c in A.codes:
            i, j = A.column(c), B.column(c)
            np.testing.assert_array_equal(np.isnan(A.val[:, :, i]), np.isnan(B.val[:, :, j]))
            np.testing.assert_allclose(np.nan_to_num(A.val[:, :, i]), np.nan_to_num(B.val[:, :, j]), rtol=0,
                                       atol=1e-9)
            np.testing.assert_array_equal(A.lli[:, :, i], B.lli[:, :, j])
            np.testing.assert_array_equal(A.ssi[:, :, i], B.ssi[:, :, j])
    g = a.systems["G"]
    assert g.lli[1, 0, g.column("L1C")] == 1 and g.ssi[0, 1, g.column("L1C")] == 9
    # the single-frequency reader (SPP/TC) reads both versions alike
    ra, rb = read_rinex_obs(tmp_path / "t.21o"), read_rinex_obs(tmp_path / "t.rnx")
    assert ra.signals == rb.signals == {"G": "C1C", "E": "C1X"}
    for ea, eb in zip(ra.epochs, rb.epochs):
        assert ea.sat == eb.sat
        np.testing.assert_allclose(ea.pr_m, eb.pr_m)
        np.testing.assert_allclose(ea.doppler_hz, eb.doppler_hz)


def test_rinex2_code_table():
    assert rinex2_code("G", "P2", 2.11) == "C2W" and rinex2_code("G", "C2", 2.11) == "C2X"
    assert rinex2_code("G", "L2", 2.11) == "L2W" and rinex2_code("G", "L5", 2.11) == "L5X"
    assert rinex2_code("E", "C1", 2.11) == "C1X" and rinex2_code("E", "L7", 2.11) == "L7X"
    assert rinex2_code("J", "C1", 2.11) == "C1C" and rinex2_code("E", "L2", 2.11) is None


def test_rinex2_navigation_equals_rinex3(tmp_path):
    a = read_rinex_nav(_write(tmp_path, "t.21n", NAV_211))
    b = read_rinex_nav(_write(tmp_path, "t.21p", NAV_304))
    np.testing.assert_allclose(a.ion_gps, b.ion_gps)
    assert a.warnings == [] and a.leap_seconds == 18
    ea, eb = a.by_sat["G03"][0], b.by_sat["G03"][0]
    for k in ("A", "e", "M0", "deln", "omg", "cuc", "cus", "crc", "crs", "cic", "cis", "i0", "idot", "OMG0",
              "OMGd", "toes", "af0", "af1", "af2", "tgd", "iode", "iodc", "svh", "sva", "week"):
        assert float(getattr(ea, k)) == float(getattr(eb, k)), k
    assert ea.toe.time == eb.toe.time and ea.toc.time == eb.toc.time


def test_rinex2_errors_name_file_line_field(tmp_path):
    lines = OBS_211.splitlines(keepends=True)
    lines[13] = lines[13][:20] + "x" + lines[13][21:]          # first record line of G12: its L1 field
    p = _write(tmp_path, "bad.21o", "".join(lines))
    with pytest.raises(InputError) as ei:
        read_obs_file(p)
    msg = str(ei.value)
    assert "bad.21o:14" in msg and "L1C" in msg and "\n" not in msg
    nl = NAV_211.splitlines(keepends=True)
    nl[9] = nl[9][:30] + "x" + nl[9][31:]                        # BROADCAST ORBIT - 3, OMEGA0
    q = _write(tmp_path, "bad.21n", "".join(nl))
    with pytest.raises(InputError) as ei:
        read_rinex_nav(q)
    assert "bad.21n:10" in str(ei.value) and "BROADCAST ORBIT - 3" in str(ei.value)
    with pytest.raises(InputError, match="bad.21o:11.*EPOCH"):
        read_obs_file(_write(tmp_path, "bad.21o", OBS_211.replace(" 21 03 19 12 00  0.0000000", " 21 13 19 12 00  "
                                                                  "0.0000000", 1)))
    with pytest.raises(InputError, match="not an observation file"):
        read_obs_file(_write(tmp_path, "t.21n", NAV_211))


def test_missing_ionosphere_falls_back_with_a_warning(tmp_path, shared_data):
    text = "".join(s for s in NAV_304.splitlines(keepends=True) if "IONOSPHERIC" not in s)
    nav = read_rinex_nav(_write(tmp_path, "noion.21p", text))
    assert nav.ion_source == "default" and nav.ion_gps is not None and np.any(nav.ion_gps)
    assert len(nav.warnings) == 1 and "default Klobuchar" in nav.warnings[0]
    # the warning reaches the SPP summary (and report)
    from dgcal.cli import main
    full = (shared_data / "rinex-sept/SEPT078M.21P").read_text().splitlines(keepends=True)
    q = _write(tmp_path, "noion_full.21p", "".join(s for s in full if "IONOSPHERIC CORR" not in s or "GAL" in s))
    out = tmp_path / "out"
    rc = main(["pos", "--mode", "spp", "--rinex-obs", str(shared_data / "rinex-sept/SEPT078M1.21O"), "--rinex-nav",
               str(q), "--out", str(out), "--no-progress"])
    assert rc == 0
    s = json.loads((out / "gnss_summary.json").read_text())
    assert s["ionosphere_model"] == "default" and "default Klobuchar" in s["warnings"][0]
    assert "default Klobuchar" in (out / "gnss_report.html").read_text()
