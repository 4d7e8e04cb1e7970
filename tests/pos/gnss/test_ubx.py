"""u-blox UBX raw logs read directly (`dgcal.pos.gnss.ubx`), checked against RTKLIB's own converter.

The data are the first 60 s of a real u-blox log (`data/walk_0827_60s.ubx`, see the data README): RXM-RAWX at 4 Hz,
RXM-SFRBX subframes and NMEA sentences in between. RTKLIB 2.4.3's convbin engine (pyrtklib ``convrnx``) turns the
same bytes into RINEX 3.04; dgcal's reader must give the same epochs, satellites, values and loss-of-lock flags, and
the same ephemerides field for field (Galileo against rtklibexplorer's demo5 fork, pyrtklib5: 2.4.3 decodes none of
this log's Galileo pages).
"""
from __future__ import annotations

import gzip
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.rinex import read_rinex_nav
from dgcal.pos.gnss.rinex_obs import read_obs_file
from dgcal.pos.gnss.spp import SppOptions, spp_files
from dgcal.pos.gnss.ubx import RAWX_HEAD, RAWX_MEAS, _klobuchar, read_ubx, ubx_frame, ubx_frames

UBX = Path(__file__).parent / "data" / "walk_0827_60s.ubx"
EPH_FIELDS = ("af0", "af1", "af2", "iode", "crs", "deln", "M0", "cuc", "e", "cus", "A", "toes", "cic", "OMG0", "cis",
              "i0", "crc", "omg", "OMGd", "idot", "week", "sva", "svh", "tgd", "tgd_b", "iodc", "code", "fit")


def _convrnx(rk, ubx: Path, out: Path) -> tuple[Path, Path]:
    """RINEX 3.04 observation and navigation files of a UBX log by an RTKLIB engine (as bench/ublox_walk.py)."""
    opt = rk.rnxopt_t()
    opt.rnxver = 304
    opt.navsys = rk.SYS_GPS | rk.SYS_GAL | rk.SYS_QZS | rk.SYS_CMP | rk.SYS_GLO
    opt.obstype = rk.OBSTYPE_PR | rk.OBSTYPE_CP | rk.OBSTYPE_DOP | rk.OBSTYPE_SNR
    opt.freqtype = 0xFF
    out.mkdir(parents=True, exist_ok=True)
    obs, nav = out / "walk.obs", out / "walk.nav"
    assert rk.convrnx(rk.STRFMT_UBX, opt, str(ubx), [str(obs), str(nav)] + [""] * 7) == 1
    return obs, nav


@pytest.fixture(scope="module")
def rtklib(tmp_path_factory):
    rk = pytest.importorskip("pyrtklib")
    return _convrnx(rk, UBX, tmp_path_factory.mktemp("rtklib"))


def _frames_of(data: bytes, keep) -> bytes:
    """The log re-framed with only the messages `keep(class, id)` accepts."""
    return b"".join(ubx_frame(c, i, p) for c, i, p in ubx_frames(data).messages if keep(c, i))


def test_observations_equal_rtklib_convrnx(rtklib, tmp_path):
    """Every epoch, satellite, code/phase/Doppler/SNR value and LLI flag of RTKLIB's RINEX, from the UBX log."""
    ours, ref = read_obs_file(UBX), read_obs_file(rtklib[0])
    assert len(ours.t_gps) == len(ref.t_gps) == 240
    assert np.abs(ours.t_gps - ref.t_gps).max() < 1e-6
    n_compared = 0
    for s, so in ref.systems.items():
        mine = ours.systems[s]
        assert mine.sats == so.sats
        for k, code in enumerate(so.codes):
            a, b = mine.val[:, :, mine.column(code)], so.val[:, :, k]
            assert np.array_equal(np.isfinite(a), np.isfinite(b)), code
            ok = np.isfinite(b)
            assert np.abs(a[ok] - b[ok]).max() <= 1e-3 + 1e-9, code      # RINEX F14.3 both
            if code[0] == "L":
                assert np.array_equal(mine.lli[:, :, mine.column(code)][ok], so.lli[:, :, k][ok]), code
            n_compared += int(ok.sum())
    assert n_compared > 17000
    # signals RTKLIB 2.4.3 does not map (L5, E5a/E6, BeiDou B3I/B1C/B2a) come as well
    assert {"C5Q", "L5Q"} <= set(ours.systems["G"].codes) and "C6I" in ours.systems["C"].codes
    assert "C" not in ref.systems


def _same_ephemerides(ours, ref, systems: str) -> int:
    mine = {(sid, e.toes, e.iode, int(e.code) & 0x300): e for sid, es in ours.by_sat.items() for e in es}
    n = 0
    for sid, es in ref.by_sat.items():
        if sid[0] not in systems:
            continue
        for e in es:
            m = mine.get((sid, e.toes, e.iode, int(e.code) & 0x300))
            if m is None:
                continue
            for f in EPH_FIELDS:
                assert float(getattr(m, f)) == pytest.approx(float(getattr(e, f)), rel=1e-11, abs=0.0), (sid, f)
            assert (m.toc.time, m.toc.sec, m.toe.time) == (e.toc.time, e.toc.sec, e.toe.time), sid
            n += 1
    return n


def test_ephemerides_equal_rtklib_field_for_field(rtklib):
    """GPS LNAV and BeiDou D1 records: the same set as RTKLIB 2.4.3 and every field equal (the transmission time
    aside: the first complete subframe set differs, see docs/gnss.md)."""
    ours, ref = read_rinex_nav(UBX), read_rinex_nav(rtklib[1])
    gc = sorted(s for s in ref.by_sat if s[0] in "GC")
    assert gc == sorted(s for s in ours.by_sat if s[0] in "GC") and len(gc) == 11
    assert _same_ephemerides(ours, ref, "GC") == sum(len(ref.by_sat[s]) for s in gc)
    assert not any(s[0] == "E" for s in ref.by_sat) and sum(s[0] == "E" for s in ours.by_sat) == 6


def test_galileo_ephemerides_equal_demo5(tmp_path):
    """Galileo I/NAV and F/NAV records against rtklibexplorer's demo5 converter (pyrtklib5, in its own process: the
    two bindings cannot share one), field for field."""
    if importlib.util.find_spec("pyrtklib5") is None:
        pytest.skip("pyrtklib5 (demo5) not installed")
    script = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import pyrtklib5; "
              f"from test_ubx import _convrnx; from pathlib import Path; "
              f"_convrnx(pyrtklib5, Path({str(UBX)!r}), Path({str(tmp_path)!r}))")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, timeout=120)
    ref = read_rinex_nav(tmp_path / "walk.nav")
    ours = read_rinex_nav(UBX)
    assert _same_ephemerides(ours, ref, "E") >= 4
    assert _same_ephemerides(ours, ref, "G") >= 2


def test_spp_from_the_log_equals_spp_from_rtklib_rinex(rtklib, tmp_path):
    """SPP (GPS + Galileo) from the UBX log alone is SPP from RTKLIB's RINEX observations with the log's navigation
    records, and with RTKLIB's navigation file in front (its GPS and BeiDou records are the log's)."""
    opts = SppOptions()
    opts.systems = "GE"
    a = spp_files(UBX, [UBX], opts).solution
    b = spp_files(rtklib[0], [UBX], opts).solution
    c = spp_files(rtklib[0], [rtklib[1], UBX], opts).solution
    assert a.ok.sum() > 200 and np.array_equal(a.ok, b.ok) and np.array_equal(a.ok, c.ok)
    assert np.abs(a.p_ecef[a.ok] - b.p_ecef[b.ok]).max() < 1e-6
    # RTKLIB prints 12 significant digits (.344484578818D-03), cssrlib's encoder 13: 0.1 mm apart at most
    assert np.abs(a.p_ecef[a.ok] - c.p_ecef[c.ok]).max() < 1e-3


def test_corrupt_and_truncated_logs_read_what_is_intact(tmp_path):
    data = UBX.read_bytes()
    full = read_ubx(data)
    assert full.skipped == 0 and full.junk_bytes > 0            # NMEA sentences between the frames
    bad = bytearray(data)
    j = data.find(b"\xb5\x62\x02\x15", 200000)
    bad[j + 500] ^= 0xFF                                           # one byte of one RAWX message
    cut = bytes(bad[:len(bad) - 700])                              # and the last message cut off
    log = read_ubx(cut)
    assert log.bad_checksum == 1 and log.truncated == 1
    assert log.n_rawx == full.n_rawx - 2 and len(log.eph) == len(full.eph)
    p = tmp_path / "cut.ubx"
    p.write_bytes(cut)
    obs = read_obs_file(p)
    assert len(obs.t_gps) == full.n_rawx - 2
    lines = p.read_bytes()
    assert lines[:2] == b"\xb5\x62"
    for trash in (b"\xb5\x62", b"\xb5\x62\x02\x15\xff\xff", data[:2000]):
        q = tmp_path / "trash.ubx"
        q.write_bytes(trash)
        with pytest.raises(InputError, match="RAWX"):
            read_obs_file(q)


def test_logs_without_rawx_or_sfrbx_and_files_neither_rinex_nor_ubx(tmp_path):
    data = UBX.read_bytes()
    only_nav = tmp_path / "sfrbx.ubx"
    only_nav.write_bytes(_frames_of(data, lambda c, i: (c, i) != (0x02, 0x15)))
    with pytest.raises(InputError, match="enable UBX-RXM-RAWX") as e:
        read_obs_file(only_nav)
    assert str(only_nav) in str(e.value)
    only_obs = tmp_path / "rawx.ubx"
    only_obs.write_bytes(_frames_of(data, lambda c, i: (c, i) == (0x02, 0x15)))
    assert len(read_obs_file(only_obs).t_gps) == 240
    with pytest.raises(InputError, match="no ephemerides in the log: give --rinex-nav a navigation file") as e:
        read_rinex_nav(only_obs)
    assert str(only_obs) in str(e.value)
    gz = tmp_path / "walk.ubx.gz"                                  # a compressed log is a log too
    gz.write_bytes(gzip.compress(data))
    assert np.array_equal(read_obs_file(gz).t_gps, read_obs_file(UBX).t_gps)
    junk = tmp_path / "photo.jpg"
    junk.write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)) * 8)
    for reader in (read_obs_file, read_rinex_nav):
        with pytest.raises(InputError) as e:
            reader(junk)
        assert str(junk) in str(e.value)


def test_glonass_frequency_numbers_and_rinex_codes(tmp_path):
    """A synthetic RAWX epoch: GLONASS channels in the header, u-blox signal ids as RINEX 3 codes, phase only with
    trkStat's valid bit, LLI half-cycle bit from trkStat bit 2."""
    rows = [  # gnssId, svId, sigId, freqId, trkStat, pr, cp
        (6, 3, 0, 7 + 5, 0x0F, 2.1e7, 1.1e8), (6, 3, 2, 7 + 5, 0x03, 2.1e7, 0.9e8), (6, 9, 0, 7 - 2, 0x01, 2.2e7, 0.0),
        (0, 5, 0, 0, 0x07, 2.0e7, 1.0e8), (5, 1, 0, 0, 0x0F, 3.6e7, 1.9e8), (2, 11, 6, 0, 0x0F, 2.5e7, 1.2e8),
    ]
    meas = np.zeros(len(rows), RAWX_MEAS)
    for i, (g, sv, sig, frq, trk, pr, cp) in enumerate(rows):
        meas[i] = (pr, cp, -100.0, g, sv, sig, frq, 5000, 40, 3, 2, 3, trk, 0)
    data = b""
    for k in range(3):
        head = np.array([(400000.0 + k, 2381, 18, len(rows), 1, 1, (0, 0))], RAWX_HEAD)
        data += ubx_frame(0x02, 0x15, head.tobytes() + meas.tobytes())
    p = tmp_path / "glo.ubx"
    p.write_bytes(data)
    obs = read_obs_file(p)
    assert obs.glonass_k == {"R03": 5, "R09": -2}
    assert obs.obs_types["R"][:8] == ["C1C", "L1C", "D1C", "S1C", "C2C", "L2C", "D2C", "S2C"]
    assert obs.obs_types["J"][:2] == ["C1C", "L1C"] and obs.obs_types["E"][:2] == ["C7Q", "L7Q"]
    r = obs.systems["R"]
    assert np.isnan(r.val[0, r.sats.index("R09"), r.column("L1C")])           # trkStat: phase not valid
    assert r.val[1, r.sats.index("R03"), r.column("L2C")] == pytest.approx(0.9e8)
    g = obs.systems["G"]
    assert g.lli[1, 0, g.column("L1C")] == 0 and obs.systems["J"].sats == ["J01"]
    assert r.lli[0, r.sats.index("R03"), r.column("L1C")] == 1                 # first epoch: slip (convrnx)
    assert r.lli[1, r.sats.index("R03"), r.column("L2C")] == 2                 # half cycle unresolved


def test_klobuchar_from_subframe_4_page_18():
    alpha = np.array([0.1118e-07, 0.2235e-07, -0.5960e-07, -0.1192e-06])
    beta = np.array([0.9830e+05, 0.1147e+06, -0.1311e+06, -0.3932e+06])
    raw = np.round(np.r_[alpha / [2.0 ** -30, 2.0 ** -27, 2.0 ** -24, 2.0 ** -24],
                         beta / [2.0 ** 11, 2.0 ** 14, 2.0 ** 16, 2.0 ** 16]]).astype(int)
    bits = np.zeros(320, dtype=int)

    def put(pos, n, v):
        bits[pos:pos + n] = [(v >> (n - 1 - i)) & 1 for i in range(n)]
    put(2, 8, 0x8B)
    put(53, 3, 4)
    put(68, 6, 56)
    for pos, v in zip((74, 82, 98, 106, 114, 130, 138, 146), raw):
        put(pos, 8, int(v) & 0xFF)
    words = np.packbits(bits).tobytes()
    ion = _klobuchar(words)
    assert ion is not None
    assert np.allclose(ion, raw.reshape(2, 4) * np.array([[2.0 ** -30, 2.0 ** -27, 2.0 ** -24, 2.0 ** -24],
                                                          [2.0 ** 11, 2.0 ** 14, 2.0 ** 16, 2.0 ** 16]]))
    put(68, 6, 55)
    assert _klobuchar(np.packbits(bits).tobytes()) is None


def test_cli_spp_on_the_log(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(UBX), "--rinex-nav", str(UBX), "--no-progress",
                 "--no-report", "--out", str(out)]) == 0
    rows = (out / "gnss.csv").read_text().splitlines()
    assert len(rows) > 200
    junk = tmp_path / "x.ubx"
    junk.write_bytes(_frames_of(UBX.read_bytes(), lambda c, i: (c, i) == (0x02, 0x15)))
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(junk), "--rinex-nav", str(junk), "--no-progress",
                 "--no-report", "--out", str(tmp_path / "p")]) == 2
    assert "no ephemerides in the log" in capsys.readouterr().err


def test_ppk_with_the_log_as_rover_and_base(tmp_path):
    """PPK reads a UBX rover and a UBX base (here the same log: a zero baseline): every epoch fixed, at the base."""
    base = [-1276965.2487, -4717231.7278, 4087230.1460]
    out = tmp_path / "ppk"
    assert main(["pos", "--mode", "ppk", "--rinex-obs", str(UBX), "--rinex-nav", str(UBX), "--rinex-base", str(UBX),
                 "--base-position", *map(str, base), "--no-progress", "--no-report", "--out", str(out)]) == 0
    rows = np.genfromtxt(out / "gnss.csv", delimiter=",", names=True, dtype=None, encoding="ascii")
    assert len(rows) == 240 and np.all(rows["fix"] == "fixed") and np.median(rows["n_sat"]) >= 12
    d = np.c_[rows["x"], rows["y"], rows["z"]] - base
    assert np.abs(d).max() < 1e-3


def test_log_with_nmea_before_its_first_frame_and_its_own_navigation(tmp_path):
    """Loggers write NMEA sentences (or a frame cut at the start) before the first whole UBX frame: such a log is
    still told by content; without --rinex-nav a UBX log's own ephemerides are used; bytes that merely contain the
    sync characters are not taken for a log."""
    from dgcal.pos.gnss.gnss_files import is_ubx_file, looks_like_ubx
    data = UBX.read_bytes()
    lead = tmp_path / "nmea_first.ubx"
    lead.write_bytes(b"$GNRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n" + data[3:4000]
                     + data)
    assert is_ubx_file(lead) and is_ubx_file(UBX)
    assert read_obs_file(lead).t_gps.tolist() == read_obs_file(UBX).t_gps.tolist()
    assert not looks_like_ubx(b"noise \xb5\x62 more noise" + bytes(100))
    assert not looks_like_ubx(b"     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n"
                              + b"\xb5\x62" + bytes(20))
    out_own, out_given = tmp_path / "own", tmp_path / "given"
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(lead), "--no-progress", "--no-report",
                 "--out", str(out_own)]) == 0
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(UBX), "--rinex-nav", str(UBX), "--no-progress",
                 "--no-report", "--out", str(out_given)]) == 0
    assert (out_own / "gnss.csv").read_text() == (out_given / "gnss.csv").read_text()
