"""Precise orbits and clocks (SP3, RINEX clock) for SPP/PPK/TC, against cssrlib's reader and RTKLIB with the same
products (issue 30).

Real products: CODE's final multi-GNSS SP3 of 2021-03-19 (tests/pos/gnss/data, cropped to 11:00-13:00), the day of
../shared/data/rinex-sept and rinex-3034. CODE's 30 s clock file of that day is not available: the SP3's own
5-minute clocks are used, and the RINEX clock reader is checked on files written from broadcast clocks.
"""
import csv
import gzip
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from cssrlib.gnss import Nav, gpst2time, id2sat
from cssrlib.peph import orb2ecef, peph
from cssrlib.rinex import rnxdec

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.ephemeris import precise_group_delay_s, satellite_states, select_ephemeris
from dgcal.pos.gnss.precise import (read_antex_pco, read_precise, read_rinex_clock, read_sp3, write_rinex_clock,
                                     write_sp3)
from dgcal.pos.gnss.rinex import gps_seconds_from_calendar, read_rinex_nav, read_rinex_obs
from dgcal.pos.gnss.spp import SppOptions, spp

DATA = Path(__file__).parent / "data"
SP3 = DATA / "COD0MGXFIN_20210781100_02H_05M_ORB.SP3.gz"
REF = np.array([-3962108.673, 3381309.574, 3668678.638])
OBS = "rinex-sept/SEPT078M1.21O"
NAV = "rinex-sept/SEPT078M.21P"
T_NOON = 2149 * 604800 + 475200.0          # 2021-03-19 12:00:00 GPS time


@pytest.fixture(scope="module")
def real_obs(shared_data):
    return read_rinex_obs(shared_data / OBS)


def test_sp3_reader_equals_cssrlib_and_interpolation_equals_cssrlib(tmp_path):
    """Our SP3 reader gives cssrlib's values; our vectorised interpolation its `peph2pos` (positions to 1 mm;
    velocities to 1 mm/s, where cssrlib's 1 ms difference quotient is itself ~0.1 m/s noisy: not compared)."""
    plain = tmp_path / "orb.sp3"
    plain.write_bytes(gzip.decompress(SP3.read_bytes()))
    d = read_sp3(SP3)
    assert d.p.shape == (25, 117, 3) and d.t[0] == T_NOON - 3600.0
    nav = peph().parse_sp3(str(plain), Nav())
    sp = peph()
    for k in (0, 12, 24):
        for sid in ("G05", "E11", "C20", "J01", "R07"):
            want = nav.peph[k].pos[id2sat(sid) - 1]
            j = d.sats.index(sid)
            assert np.allclose(d.p[k, j], want[:3], atol=1e-6, rtol=0)
            assert np.isclose(d.clk[k, j], want[3], atol=1e-15, rtol=0) or (np.isnan(d.clk[k, j]) and np.isnan(want[3]))
    pr = read_precise([SP3])
    sats = ["G05", "G10", "E11", "C20", "J01"]
    for dt in (17.3, 1801.0, 3599.5):
        p, v, clk, _, ok = pr.states(sats, np.full(len(sats), T_NOON + dt))
        assert ok.all()
        for i, sid in enumerate(sats):
            rs, dts, _ = sp.peph2pos(gpst2time(2149, 475200.0 + dt), id2sat(sid), nav)
            assert np.linalg.norm(rs[:3] - p[i]) < 1e-3
            assert abs(dts[0] - clk[i]) * 299792458.0 < 0.01          # relativity from its noisier velocity
    # outside the products' span and for a satellite they lack: not ok, NaN
    p, v, clk, _, ok = pr.states(["G05", "G99"], np.array([T_NOON + 4000.0, T_NOON]))
    assert not ok.any() and np.isnan(p).all() and np.isnan(clk).all()


def test_precise_states_match_rtklib_peph2pos():
    """The same products through RTKLIB 2.4.3's own interpolation (readsp3 + peph2pos): positions to 1 mm, clocks
    (with the relativistic term, RTKLIB's -2 r.v/c^2) to 1 cm."""
    import pyrtklib as rk  # the reference peer (test extra); never beside pyrtklib5 in one process

    pr = read_precise([SP3])
    d = read_sp3(SP3)
    keep = [j for j, s in enumerate(d.sats) if s[0] in "GEJ"]      # RTKLIB 2.4.3 reads at most 85 satellites
    with tempfile.TemporaryDirectory() as tmp:
        f = str(Path(tmp) / "sub.sp3")
        write_sp3(f, d.t, [d.sats[j] for j in keep], d.p[:, keep], d.clk[:, keep])
        assert np.allclose(read_sp3(f).p, d.p[:, keep], atol=1e-6, equal_nan=True)   # the writer round-trips
        nav = rk.nav_t()
        rk.readsp3(f, nav, 0)
    sats = ["G05", "G10", "E11", "E27", "J01"]
    for dt in (17.3, 1801.0, 3599.5):
        p, v, clk, _, ok = pr.states(sats, np.full(len(sats), T_NOON + dt))
        assert ok.all()
        t = rk.gpst2time(2149, 475200.0 + dt)
        for i, sid in enumerate(sats):
            rs, dts, var = rk.Arr1Ddouble(6), rk.Arr1Ddouble(2), rk.Arr1Ddouble(1)
            assert rk.peph2pos(t, rk.satid2no(sid), nav, 1, rs, dts, var)
            assert np.linalg.norm(np.array([rs[0], rs[1], rs[2]]) - p[i]) < 1e-3
            assert np.linalg.norm(np.array([rs[3], rs[4], rs[5]]) - v[i]) < 1e-3
            assert abs(dts[0] - clk[i]) * 299792458.0 < 0.01


def test_real_spp_with_sp3_beside_rtklib_with_the_same_sp3(shared_data, real_obs, tmp_path):
    """SPP of the real minute with CODE's SP3 orbits and clocks beside RTKLIB's pntpos with the same SP3: both
    within 2 m 3D RMS of the known position, at most 0.75 m apart in any epoch (0.41 m with broadcast orbits: the
    two SPPs weight satellites differently). RTKLIB 2.4.3 reads at most 85 satellites of an SP3 file (the
    117-satellite file loses all but G01-G17 there): it is given the file's GPS/Galileo/QZSS records."""
    from dgcal.pos.gnss.rtklib import rtklib_pntpos

    nav = read_rinex_nav(shared_data / NAV, [SP3])
    assert nav.orbits == f"SP3 {SP3.name} (its own clocks)"
    assert any("orbits and clocks: SP3" in w and "antenna offsets not applied" in w for w in nav.warnings)
    sol = spp(real_obs, nav, SppOptions(systems=("G", "E", "J")))
    assert sol.ok.all()
    rms = np.sqrt(np.mean(np.sum((sol.p_ecef - REF) ** 2, axis=1)))
    d = read_sp3(SP3)
    keep = [j for j, s in enumerate(d.sats) if s[0] in "GEJ"]
    sub = tmp_path / "gej.sp3"
    write_sp3(sub, d.t, [d.sats[j] for j in keep], d.p[:, keep], d.clk[:, keep])
    t, p = rtklib_pntpos(str(shared_data / OBS), str(shared_data / NAV), sp3=[str(sub)])
    rms_rk = np.sqrt(np.mean(np.sum((p - REF) ** 2, axis=1)))
    common, ia, ib = np.intersect1d(np.round(sol.t_gps, 3), np.round(t, 3), return_indices=True)
    diff = np.linalg.norm(sol.p_ecef[ia] - p[ib], axis=1)
    print(f"SPP with SP3: dgcal {rms:.2f} m, RTKLIB {rms_rk:.2f} m 3D RMS; apart max {diff.max():.2f} m, "
          f"mean {diff.mean():.2f} m over {len(common)} epochs")
    assert len(common) == 60
    assert rms < 2.0 and rms_rk < 2.0
    assert diff.max() < 0.75


def _broadcast_products(nav, t0: float, t1: float, step: float, sats: list[str]):
    """Positions (m) and ionosphere-free clocks without the relativistic term (s) of the broadcast model at every
    `step` s, as an analysis centre would publish them: what `precise_states` turns back into broadcast states."""
    t = np.arange(t0, t1 + 0.5 * step, step)
    m, n = len(t), len(sats)
    p = np.full((m, n, 3), np.nan)
    clk = np.full((m, n), np.nan)
    for k, tk in enumerate(t):
        pk, vk, ck, _, _, ok = satellite_states(nav, sats, np.full(n, tk))
        rel = -2.0 * np.sum(pk * vk, axis=1) / 299792458.0 ** 2
        p[k, ok] = pk[ok]
        clk[k, ok] = (ck + precise_group_delay_s(nav, sats, np.full(n, tk)) - rel)[ok]
    return t, p, clk


def _one_ephemeris_each(nav, t: float):
    """`nav` reduced to the ephemeris each satellite uses at `t` (products sampled over hours from one set of
    ephemerides: the broadcast SPP switches records between 5-minute buckets, which products cannot follow)."""
    nav.by_sat = {sid: [e] for sid in list(nav.by_sat) if (e := select_ephemeris(nav, sid, t)) is not None}
    nav._toe.clear()
    return nav


def test_spp_with_products_written_from_broadcast_equals_broadcast_spp(shared_data, real_obs, tmp_path):
    """SP3 (15 min) and RINEX clock (30 s) files written from the broadcast model give the broadcast SPP back to
    a few mm: the readers, the interpolation, the relativistic term and the group delays are consistent."""
    nav_b = _one_ephemeris_each(read_rinex_nav(shared_data / NAV), T_NOON + 30.0)
    sats = sorted(s for s in nav_b.by_sat if s[0] in "GEJ")
    t, p, clk = _broadcast_products(nav_b, T_NOON - 5400.0, T_NOON + 5400.0, 900.0, sats)
    write_sp3(tmp_path / "brdc.sp3", t, sats, p, clk)
    tc, pc, cc = _broadcast_products(nav_b, T_NOON - 600.0, T_NOON + 600.0, 30.0, sats)
    write_rinex_clock(tmp_path / "brdc.clk", tc, sats, cc)
    rc = read_rinex_clock(tmp_path / "brdc.clk")
    assert rc.sats == sats and np.allclose(rc.clk, cc, atol=1e-17, rtol=1e-11, equal_nan=True)
    cn = rnxdec().decode_clk(str(tmp_path / "brdc.clk"), Nav())      # cssrlib reads what we write
    assert cn.nc == len(tc) and np.isclose(cn.pclk[3].clk[id2sat(sats[0]) - 1], cc[3, 0], rtol=1e-11, atol=0)
    nav_p = read_rinex_nav(shared_data / NAV, [tmp_path / "brdc.sp3", tmp_path / "brdc.clk"])
    assert nav_p.orbits == "SP3 brdc.sp3 + CLK brdc.clk"
    nav_p.by_sat = nav_b.by_sat                   # the same group delays
    opts = SppOptions(systems=("G", "E", "J"), model_errors=False)
    a = spp(real_obs, nav_b, opts)
    b = spp(real_obs, nav_p, opts)
    assert a.ok.all() and b.ok.all()
    assert np.abs(b.p_ecef - a.p_ecef).max() < 0.005
    assert np.abs(b.v_ecef - a.v_ecef).max() < 0.002


def test_sp3_and_clock_errors_name_file_line_field(tmp_path):
    text = SP3.read_bytes()
    lines = gzip.decompress(text).decode().splitlines()
    k = next(i for i, s in enumerate(lines) if s.startswith("PG05"))
    bad = list(lines)
    bad[k] = bad[k][:18] + "   12x45.67890" + bad[k][32:]
    f = tmp_path / "bad.sp3"
    f.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError) as e:
        read_sp3(f)
    assert e.value.line == k + 1 and e.value.field == "y (km)" and "bad.sp3" in str(e.value)
    bad = list(lines)
    bad[0] = "#aP" + bad[0][3:]
    f.write_text("\n".join(bad) + "\n")
    with pytest.raises(InputError, match="SP3 version 'a'"):
        read_sp3(f)
    c = tmp_path / "c.clk"
    write_rinex_clock(c, np.array([T_NOON]), ["G01"], np.array([[1e-4]]))
    cl = c.read_text().splitlines()
    cl[-1] = cl[-1].rsplit(" ", 1)[0] + " 1.0E-0x4"
    c.write_text("\n".join(cl) + "\n")
    with pytest.raises(InputError) as e:
        read_rinex_clock(c)
    assert e.value.line == len(cl) and e.value.field == "clock bias (s)"


def test_precise_products_need_a_broadcast_file(shared_data):
    with pytest.raises(InputError, match="broadcast navigation file"):
        read_rinex_nav(SP3)


BASE = "rinex-3034/3034078M1.21O"
BASE_ECEF = [-3959400.631, 3385704.533, 3667523.111]


def _gnss_csv(out: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with open(out / "gnss.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["gps_week"]) * 604800.0 + float(r["gps_sow"]) for r in rows])
    p = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])
    fix = np.array([r.get("fix", "single") for r in rows])
    return t, p, fix


def test_cli_spp_and_ppk_with_sp3_beside_rtklib(shared_data, tmp_path, capsys):
    """`dgcal pos --sp3` on the real minute: SPP says which orbits it used; PPK of the 5.3 km baseline with CODE's
    SP3 fixes as with broadcast orbits and agrees with RTKLIB's PPK on the same SP3 to 1 cm per fixed epoch
    (both within 2 cm of the known rover position). A file of the wrong kind after --sp3 is refused."""
    from dgcal.pos.gnss.rtklib import rtklib_ppk

    common = ["--rinex-obs", str(shared_data / OBS), "--rinex-nav", str(shared_data / NAV), "--sp3", str(SP3),
              "--no-progress", "--no-report"]
    assert main(["pos", "--mode", "spp", *common, "--out", str(tmp_path / "spp")]) == 0
    s = json.loads((tmp_path / "spp" / "gnss_summary.json").read_text())
    assert s["orbits"] == f"SP3 {SP3.name} (its own clocks)" and str(SP3) in s["rinex_nav"]
    assert any("antenna offsets not applied" in w for w in s["warnings"])
    assert main(["pos", "--mode", "ppk", *common, "--rinex-base", str(shared_data / BASE), "--base-position",
                 *map(str, BASE_ECEF), "--systems", "GEJ", "--out", str(tmp_path / "ppk")]) == 0
    t, p, fix = _gnss_csv(tmp_path / "ppk")
    fixed = fix == "fixed"
    err = np.linalg.norm(p[fixed] - REF, axis=1)
    d = read_sp3(SP3)
    keep = [j for j, sid in enumerate(d.sats) if sid[0] in "GEJ"]      # RTKLIB 2.4.3: at most 85 satellites
    sub = tmp_path / "gej.sp3"
    write_sp3(sub, d.t, [d.sats[j] for j in keep], d.p[:, keep], d.clk[:, keep])
    rk = rtklib_ppk(str(shared_data / OBS), str(shared_data / NAV), str(shared_data / BASE), BASE_ECEF,
                    systems="GEJ", precise=[str(sub)])
    rf = rk["q"] == 1
    both, ia, ib = np.intersect1d(np.round(t[fixed], 3), np.round(rk["t_gps"][rf], 3), return_indices=True)
    apart = np.linalg.norm(p[fixed][ia] - rk["p_ecef"][rf][ib], axis=1)
    err_rk = np.linalg.norm(rk["p_ecef"][rf] - REF, axis=1)
    print(f"PPK with SP3: dgcal {fixed.mean():.0%} fixed, 3D RMS {1e3 * np.sqrt(np.mean(err ** 2)):.1f} mm; "
          f"RTKLIB {rf.mean():.0%} fixed, {1e3 * np.sqrt(np.mean(err_rk ** 2)):.1f} mm; apart max "
          f"{1e3 * apart.max():.1f} mm over {len(both)} common fixed epochs")
    assert fixed.mean() >= 0.8 and rf.mean() >= 0.8 and len(both) >= 40
    assert np.sqrt(np.mean(err ** 2)) < 0.02 and np.sqrt(np.mean(err_rk ** 2)) < 0.02
    assert apart.max() < 0.01
    wrong = ["pos", "--mode", "spp", "--rinex-obs", str(shared_data / OBS), "--rinex-nav", str(shared_data / NAV),
             "--sp3", str(shared_data / NAV), "--no-progress", "--no-report", "--out", str(tmp_path / "wrong")]
    capsys.readouterr()
    assert main(wrong) == 2
    err = capsys.readouterr().err.strip()
    assert "not an SP3 orbit file" in err and "SEPT078M.21P" in err and "--sp3" in err and "\n" not in err
    assert not (tmp_path / "wrong").exists()


def test_mutated_products_are_read_or_refused_with_input_error(tmp_path):
    """300 random mutations (bytes deleted, replaced, lines dropped or doubled) of a real SP3 and of a clock file:
    each is read (every position within 1e8 m, every clock within 1 s) or refused by an `InputError`."""
    rng = np.random.default_rng(30)
    sp3 = gzip.decompress(SP3.read_bytes()).decode().splitlines()[:400]
    clk = tmp_path / "c.clk"
    write_rinex_clock(clk, T_NOON + 30.0 * np.arange(4), ["G01", "E02"], np.full((4, 2), 1e-4))
    clk_lines = clk.read_text().splitlines()
    for case in range(300):
        lines = list(sp3 if case % 2 == 0 else clk_lines)
        for _ in range(rng.integers(1, 4)):
            i = int(rng.integers(len(lines)))
            op = rng.integers(4)
            s = lines[i]
            k = int(rng.integers(len(s) + 1))
            if op == 0:
                lines[i] = s[:k] + s[k + int(rng.integers(1, 6)):]
            elif op == 1:
                lines[i] = s[:k] + rng.choice(["9", "-", "x", " ", "1e17", "nan", "999999"]) + s[k + 1:]
            elif op == 2:
                del lines[i]
            else:
                lines.insert(i, s)
        f = tmp_path / f"m{case}.{'sp3' if case % 2 == 0 else 'clk'}"
        f.write_text("\n".join(lines) + "\n")
        try:
            d = read_sp3(f) if case % 2 == 0 else read_rinex_clock(f)
        except InputError:
            continue
        if case % 2 == 0:
            assert np.all(np.abs(d.p[np.isfinite(d.p)]) <= 1e8) and np.all(np.abs(d.clk[np.isfinite(d.clk)]) <= 1.0)
        else:
            assert np.all(np.abs(d.clk[np.isfinite(d.clk)]) <= 1.0)
        assert np.all(np.diff(d.t) > 0)


def _one_record_each(nav_text: str, t_mid: float) -> str:
    """A RINEX 3 navigation file's text with one record per satellite: the one whose epoch is nearest `t_mid`."""
    lines = nav_text.splitlines()
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1
    best: dict[str, tuple[float, list[str]]] = {}
    i = end
    while i < len(lines):
        j = i + 1
        while j < len(lines) and lines[j][:4] == "    ":
            j += 1
        y, mo, d, h, mi, s = (int(x) for x in lines[i][4:23].split())
        dt = abs(gps_seconds_from_calendar(y, mo, d, h, mi, s) - t_mid)
        if lines[i][:3] not in best or dt < best[lines[i][:3]][0]:
            best[lines[i][:3]] = (dt, lines[i:j])
        i = j
    return "\n".join(lines[:end] + [s for _, rec in best.values() for s in rec]) + "\n"


def test_tc_with_products_written_from_broadcast_equals_broadcast_tc(tmp_path):
    """`dgcal pos --mode tc --sp3 --clk` on a simulated flight: with SP3/CLK files written from the broadcast
    orbits, the trajectory is the broadcast run's to a few mm (TC takes its satellites where SPP and PPK do)."""
    sim = tmp_path / "sim"
    assert main(["simulate", "pos", "--out", str(sim), "--seed", "4", "--duration", "120", "--rate", "50"]) == 0
    t0 = read_rinex_obs(sim / "obs.rnx").epochs[0].t_gps
    nav_file = tmp_path / "one.rnx"
    nav_file.write_text(_one_record_each((sim / "nav.rnx").read_text(), t0 + 60.0))
    nav = read_rinex_nav(nav_file)
    sats = sorted(nav.by_sat)
    t, p, clk = _broadcast_products(nav, t0 - 5400.0, t0 + 5400.0, 900.0, sats)
    write_sp3(tmp_path / "b.sp3", t, sats, p, clk)
    tc, _, cc = _broadcast_products(nav, t0 - 300.0, t0 + 420.0, 30.0, sats)
    write_rinex_clock(tmp_path / "b.clk", tc, sats, cc)
    common = ["pos", "--mode", "tc", "--rinex-obs", str(sim / "obs.rnx"), "--rinex-nav", str(nav_file),
              "--imu", str(sim / "imu.csv"), "--events", str(sim / "events.csv"), "--imu-grade", "adis16488",
              "--lever-arm", "0.05", "-0.1", "-0.3", "--set", "model_errors=false", "--no-progress", "--no-report"]
    assert main(common + ["--out", str(tmp_path / "brdc")]) == 0
    assert main(common + ["--sp3", str(tmp_path / "b.sp3"), "--clk", str(tmp_path / "b.clk"),
                          "--out", str(tmp_path / "prec")]) == 0
    a = np.loadtxt(tmp_path / "brdc" / "trajectory.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3, 4))
    b = np.loadtxt(tmp_path / "prec" / "trajectory.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3, 4))
    assert a.shape == b.shape and len(a) > 500 and np.array_equal(a[:, 0], b[:, 0])
    d_lat_m = (b[:, 1] - a[:, 1]) * 111320.0
    d_lon_m = (b[:, 2] - a[:, 2]) * 111320.0 * np.cos(np.radians(a[:, 1]))
    assert np.abs(d_lat_m).max() < 0.005 and np.abs(d_lon_m).max() < 0.005 and np.abs(b[:, 3] - a[:, 3]).max() < 0.01
    # the products are what TC used: without every other satellite in them the trajectory moves
    write_sp3(tmp_path / "half.sp3", t, sats[::2], p[:, ::2], clk[:, ::2])
    assert main(common + ["--sp3", str(tmp_path / "half.sp3"), "--out", str(tmp_path / "half")]) == 0
    h = np.loadtxt(tmp_path / "half" / "trajectory.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3, 4))
    assert np.abs(h[:, 3] - a[:, 3]).max() > 0.02
    # the summary names the orbits used, and without a base the navigation warnings reach it too
    import json
    s_b = json.loads((tmp_path / "brdc" / "pos_summary.json").read_text())
    s_p = json.loads((tmp_path / "prec" / "pos_summary.json").read_text())
    assert s_b["orbits"] == "broadcast" and "b.sp3" in s_p["orbits"] and "b.clk" in s_p["orbits"]
    assert any("b.sp3" in w for w in s_p["warnings"])


ATX_SATS = {"G05": {"G01": (279.0, -12.0, 2319.0), "G02": (279.0, -12.0, 2250.0)},
            "G10": {"G01": (394.0, 0.0, 1600.0), "G02": (394.0, 0.0, 1650.0)},
            "E11": {"E01": (150.0, 20.0, 900.0), "E05": (150.0, 20.0, 800.0)}}


def _antex(sats: dict) -> str:
    """A minimal ANTEX 1.4 file of satellite antennas: {sid: {frequency code: (x, y, z) mm}}, no phase variations."""
    out = [f"{'     1.4            M':<60}ANTEX VERSION / SYST", f"{'A':<60}PCV TYPE / REFANT", f"{'':60}END OF HEADER"]
    for sid, freqs in sats.items():
        out += [f"{'':60}START OF ANTENNA", f"{'BLOCK TEST':<20}{sid:<20}{sid + '0':<10}{'2009-014A':<10}"
                "TYPE / SERIAL NO", f"{'':45}0    01-JAN-21 METH / BY / # / DATE", f"{'     0.0':<60}DAZI",
                f"{'     0.0  17.0   1.0':<60}ZEN1 / ZEN2 / DZEN", f"{len(freqs):6d}{'':54}# OF FREQUENCIES",
                f"{'  2009     3    24     0     0    0.0000000':<60}VALID FROM"]
        for fc, (x, y, z) in freqs.items():
            out += [f"{'   ' + fc:<60}START OF FREQUENCY", f"{x:10.2f}{y:10.2f}{z:10.2f}{'':30}NORTH / EAST / UP",
                    "   NOAZI" + f"{0.0:8.2f}" * 18, f"{'   ' + fc:<60}END OF FREQUENCY"]
        out.append(f"{'':60}END OF ANTENNA")
    return "\n".join(out) + "\n"


_RTKLIB_SATANTOFF = """
import json, sys
import pyrtklib as rk
atx, week, sow, states = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), json.loads(sys.argv[4])
pcvs = rk.pcvs_t()
rk.readpcv(atx, pcvs)
t = rk.gpst2time(week, sow)
nav = rk.nav_t()
out, keep = {}, []
for sid, rv in states.items():
    sat = rk.satid2no(sid)
    keep.append(rk.searchpcv(sat, "", t, pcvs))
    nav.pcvs[sat - 1] = keep[-1]
    rs, dant = rk.Arr1Ddouble(6), rk.Arr1Ddouble(3)
    for k in range(6):
        rs[k] = rv[k]
    rk.satantoff(t, rs, sat, nav, dant)
    out[sid] = [dant[0], dant[1], dant[2]]
print(json.dumps(out), flush=True)
import os
os._exit(0)          # RTKLIB's nav_t would free the pcv entries assigned above a second time
"""


def test_antex_offsets_beside_cssrlib_and_rtklib(tmp_path, shared_data):
    """With an ANTEX file the SP3 positions move to the antenna phase centre: the ionosphere-free offset (GPS L1/L2,
    Galileo E1/E5a) rotated by the nominal yaw attitude, as cssrlib's `orb2ecef` and RTKLIB 2.4.3's `satantoff`
    (GPS; RTKLIB pairs Galileo's frequencies otherwise) compute it, to 1 mm. A satellite the file lacks is not used;
    the products' label names the file."""
    atx = tmp_path / "sat.atx"
    atx.write_text(_antex(ATX_SATS))
    pco = read_antex_pco(atx)
    g1, g2 = 1575.42e6 ** 2, 1227.60e6 ** 2
    assert np.allclose(pco["G05"][0][2], [0.279, -0.012, (g1 * 2.319 - g2 * 2.250) / (g1 - g2)], atol=1e-9)
    e5 = 1176.45e6 ** 2
    assert np.allclose(pco["E11"][0][2], [0.150, 0.020, (g1 * 0.900 - e5 * 0.800) / (g1 - e5)], atol=1e-9)
    com = read_precise([SP3])
    apc = read_precise([SP3], (), [atx])
    assert apc.label.endswith("+ ATX sat.atx")
    sats = ["G05", "G10", "E11", "E27"]
    dt = 17.3
    p0, v0, c0, _, ok0 = com.states(sats, np.full(4, T_NOON + dt))
    p1, v1, c1, _, ok1 = apc.states(sats, np.full(4, T_NOON + dt))
    assert ok0.all() and list(ok1) == [True, True, True, False]          # E27 is not in the ANTEX file
    assert np.array_equal(c0[:3], c1[:3])
    t = gpst2time(2149, 475200.0 + dt)
    for i, sid in enumerate(sats[:3]):
        want = pco[sid][0][2] @ orb2ecef(t, p0[i])
        assert np.linalg.norm(p1[i] - p0[i] - want) < 1e-3
        assert abs(np.linalg.norm(p1[i] - p0[i]) - np.linalg.norm(pco[sid][0][2])) < 1e-9 + 1e-3
    states = {sid: list(p0[i]) + list(v0[i]) for i, sid in enumerate(sats[:2])}
    run = subprocess.run([sys.executable, "-c", _RTKLIB_SATANTOFF, str(atx), "2149", str(475200.0 + dt),
                          json.dumps(states)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    rk = json.loads(run.stdout)
    for i, sid in enumerate(sats[:2]):
        assert np.linalg.norm(np.array(rk[sid]) - (p1[i] - p0[i])) < 1e-3, sid
    # through the navigation reader: the warning says the offsets are applied
    nav = read_rinex_nav(shared_data / NAV, [SP3, atx])
    assert nav.precise.atx_paths and any("offsets from the ANTEX file" in w for w in nav.warnings)
    # the command line: every GPS/Galileo/QZSS satellite with a 1.5 m radial offset (z), SPP moves by less than the
    # offset (nearly common to the satellites: most goes into the receiver clocks)
    band2 = {"G": "G02", "E": "E05", "J": "J02"}
    every = {sid: {sid[0] + "01": (0.0, 0.0, 1500.0), band2[sid[0]]: (0.0, 0.0, 1500.0)}
             for sid in com.sats if sid[0] in "GEJ"}
    (tmp_path / "all.atx").write_text(_antex(every))
    args = ["pos", "--mode", "spp", "--rinex-obs", str(shared_data / OBS), "--rinex-nav", str(shared_data / NAV),
            "--sp3", str(SP3), "--systems", "GEJ", "--no-progress", "--no-report"]
    assert main(args + ["--atx", str(tmp_path / "all.atx"), "--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    sa = json.loads((tmp_path / "a" / "gnss_summary.json").read_text())
    sb = json.loads((tmp_path / "b" / "gnss_summary.json").read_text())
    assert sa["orbits"].endswith("+ ATX all.atx") and sa["n_fixed"] == sb["n_fixed"] == 60
    moved = np.linalg.norm(np.array(sa["median_ecef_m"]) - np.array(sb["median_ecef_m"]))
    assert 0.0 < moved < 1.5


def test_rinex_clock_304_layout(tmp_path):
    """RINEX clock 3.04 (version F4.2 then the type in column 23, labels from column 66, 9-character names) reads
    as the 3.00 layout does, and as cssrlib reads it."""
    t = T_NOON + 30.0 * np.arange(3)
    clk = np.array([[1.5e-4, -2.25e-5], [1.5000001e-4, -2.2500002e-5], [1.5000002e-4, np.nan]])
    old = tmp_path / "c300.clk"
    write_rinex_clock(old, t, ["G01", "E02"], clk)
    lines = old.read_text().splitlines()
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s)
    new = [f"{3.04:4.2f}{'':17}C{'':19}G{'':19}{'':4}RINEX VERSION / TYPE"]
    new += [s[:60] + " " * 5 + s[60:] for s in lines[1:end + 1]]
    new += ["AS " + s[3:7] + " " * 5 + s[7:] for s in lines[end + 1:]]
    f = tmp_path / "c304.clk"
    f.write_text("\n".join(new) + "\n")
    a, b = read_rinex_clock(old), read_rinex_clock(f)
    assert b.sats == a.sats == ["E02", "G01"]
    assert np.array_equal(a.t, b.t) and np.allclose(a.clk, b.clk, equal_nan=True, rtol=0, atol=0)
    assert np.allclose(b.clk[:, 1], clk[:, 0], rtol=1e-11, atol=0)
    cn = rnxdec().decode_clk(str(f), Nav())
    assert cn.nc == 3 and np.isclose(cn.pclk[1].clk[id2sat("E02") - 1], clk[1, 1], rtol=1e-11, atol=0)


def test_consecutive_sp3_files_merge_into_one_span(tmp_path):
    """Two SP3 files of consecutive spans (here the real file cut at 12:00, the 12:00 epoch in both) interpolate
    across the join as the whole file does."""
    d = read_sp3(SP3)
    first, second = d.t <= T_NOON, d.t >= T_NOON
    write_sp3(tmp_path / "a.sp3", d.t[first], d.sats, d.p[first], d.clk[first])
    write_sp3(tmp_path / "b.sp3", d.t[second], d.sats, d.p[second], d.clk[second])
    whole, parts = read_precise([SP3]), read_precise([tmp_path / "a.sp3", tmp_path / "b.sp3"])
    assert np.array_equal(parts.t_orb, whole.t_orb) and parts.sats == whole.sats
    sats = ["G05", "E11", "C20", "J01"]
    for dt in (-1234.5, -10.0, 0.0, 17.3, 2000.0):
        a = whole.states(sats, np.full(4, T_NOON + dt))
        b = parts.states(sats, np.full(4, T_NOON + dt))
        assert np.allclose(a[0], b[0], atol=1e-6, rtol=0) and np.allclose(a[2], b[2], atol=1e-15, rtol=0)
