"""SBET/SMRMSG binary round trips and DJI MRK parsing, with errors naming file, line/record and field."""
import numpy as np
import pytest

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Trajectory, read_events, write_events
from dgcal.pos.events import make_events, match_events_to_images, read_mrk, write_mrk
from dgcal.pos.ins.sbet import (SBET_DTYPE, read_sbet, read_sbet_with_sigmas, read_smrmsg, write_sbet, write_smrmsg)

WEEK = 2300


def _traj(n=500, seed=0):
    rng = np.random.default_rng(seed)
    t = WEEK * SECONDS_PER_WEEK + 604790.0 + np.arange(n) * 0.05  # crosses the week boundary
    return Trajectory(t=t, lat=23.0 + rng.normal(0, 1e-3, n), lon=120.2 + rng.normal(0, 1e-3, n),
                      h=300 + rng.normal(0, 5, n), v_ned=rng.normal(0, 20, (n, 3)),
                      rph=np.column_stack([rng.normal(0, 10, n), rng.normal(0, 5, n), rng.uniform(0, 360, n)]),
                      sigma=np.abs(rng.normal(0.05, 0.01, (n, 6))))


def test_sbet_round_trip(tmp_path):
    tr = _traj()
    acc, w = np.random.default_rng(1).normal(0, 1, (2, len(tr.t), 3))
    write_sbet(tmp_path / "sbet.out", tr, accel_b=acc, omega_b=w)
    assert (tmp_path / "sbet.out").stat().st_size == 136 * len(tr.t)
    sb = read_sbet(tmp_path / "sbet.out", gps_week=WEEK)
    b = sb.trajectory
    np.testing.assert_allclose(b.t, tr.t, atol=1e-6)
    np.testing.assert_allclose(b.lat, tr.lat, atol=1e-12)
    np.testing.assert_allclose(b.h, tr.h, atol=1e-9)
    np.testing.assert_allclose(b.v_ned, tr.v_ned, atol=1e-12)
    d = (b.rph - tr.rph + 180) % 360 - 180
    assert np.abs(d).max() < 1e-10
    np.testing.assert_allclose(sb.accel_b, acc)
    np.testing.assert_allclose(sb.omega_b, w)


def test_sbet_wander_angle_rotates_velocity(tmp_path):
    rec = np.zeros(3, dtype=SBET_DTYPE)
    rec["time"] = [1.0, 2.0, 3.0]
    rec["vx"], rec["vy"], rec["vz"] = 10.0, 0.0, -1.0
    rec["wander"] = np.radians([0.0, 90.0, 30.0])
    (tmp_path / "w.out").write_bytes(rec.tobytes())
    v = read_sbet(tmp_path / "w.out", gps_week=WEEK).trajectory.v_ned
    np.testing.assert_allclose(v, [[10, 0, -1], [0, 10, -1], [10 * np.cos(np.radians(30)), 5, -1]], atol=1e-12)


def test_smrmsg_round_trip_and_merge(tmp_path):
    tr = _traj()
    write_sbet(tmp_path / "sbet.out", tr)
    write_smrmsg(tmp_path / "smrmsg.out", tr)
    t, sig = read_smrmsg(tmp_path / "smrmsg.out", WEEK)
    np.testing.assert_allclose(sig, tr.sigma, rtol=1e-12)
    sb = read_sbet_with_sigmas(tmp_path / "sbet.out", tmp_path / "smrmsg.out", WEEK)
    np.testing.assert_allclose(sb.trajectory.sigma, tr.sigma, rtol=1e-9)


def test_sbet_errors(tmp_path):
    tr = _traj(10)
    p = tmp_path / "sbet.out"
    write_sbet(p, tr)
    p.write_bytes(p.read_bytes()[:-8])
    with pytest.raises(InputError, match=r"sbet.out: .*record 10 is truncated"):
        read_sbet(p, WEEK)
    rec = np.zeros(2, dtype=SBET_DTYPE)
    rec["time"] = [1.0, 2.0]
    rec["pitch"][1] = np.nan
    p.write_bytes(rec.tobytes())
    with pytest.raises(InputError, match="field 'pitch': non-finite value in record 2"):
        read_sbet(p, WEEK)
    with pytest.raises(InputError, match="file not found"):
        read_sbet(tmp_path / "none.out", WEEK)


MRK = ("1\t282401.669089\t[2404]\t   101,N\t   107,E\t   129,V\t22.77995359,Lat\t114.10089118,Lon\t139.231,Ellh\t"
       "0.002967, 0.003104, 0.007622\t50,Q\n"
       "2\t282403.670021\t[2404]\t    99,N\t   -12,E\t   130,V\t22.77999001,Lat\t114.10090001,Lon\t139.301,Ellh\t"
       "0.003000, 0.003100, 0.007700\t50,Q\n"
       "\n"
       "3\t282405.671500\t[2404]\t    98,N\t   -14,E\t   131,V\t22.78002001,Lat\t114.10091001,Lon\t139.401,Ellh\t"
       "0.013000, 0.013100, 0.027700\t34,Q\n")


def test_mrk_parse_and_round_trip(tmp_path):
    p = tmp_path / "100_0001_Timestamp.MRK"
    p.write_text(MRK)
    m = read_mrk(p)
    assert list(m.index) == [1, 2, 3] and list(m.lines) == [1, 2, 4]
    assert m.t[0] == pytest.approx(2404 * SECONDS_PER_WEEK + 282401.669089)
    np.testing.assert_allclose(m.offset_nev_m[0], [0.101, 0.107, 0.129])
    np.testing.assert_allclose(m.sigma_nev_m[2], [0.013, 0.0131, 0.0277])
    assert list(m.quality) == [50, 50, 34] and m.lat[1] == pytest.approx(22.77999001)
    ev = m.events()
    assert list(ev.image) == ["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"]
    write_events(tmp_path / "events.csv", ev)
    back = read_events(tmp_path / "events.csv")
    np.testing.assert_allclose(back.t, m.t, atol=1e-6)
    write_mrk(tmp_path / "again.MRK", m)
    m2 = read_mrk(tmp_path / "again.MRK")
    np.testing.assert_allclose(m2.t, m.t, atol=1e-6)
    np.testing.assert_allclose(m2.offset_nev_m, m.offset_nev_m)
    np.testing.assert_allclose(m2.lat, m.lat, atol=1e-9)


@pytest.mark.parametrize("bad, line, field", [
    (MRK.replace("107,E", "107"), 1, "E offset"),
    (MRK.replace("[2404]\t    99", "2404\t    99"), 2, "[week]"),
    (MRK.replace("22.78002001,Lat", "x22.7,Lat"), 4, "Lat"),
    (MRK.replace("50,Q\n", "50\n", 1), 1, "Q"),
    (MRK.replace("282405.671500", "282400.000000"), 4, "seconds of week"),
])
def test_mrk_errors_name_line_and_field(tmp_path, bad, line, field):
    p = tmp_path / "bad.MRK"
    p.write_text(bad)
    with pytest.raises(InputError) as exc:
        read_mrk(p)
    assert f"bad.MRK:{line}:" in str(exc.value) and f"field '{field}'" in str(exc.value)


def test_make_and_match_events():
    ev = make_events([1.0, 2.0, 3.0])
    assert list(ev.image) == ["IMG_0001.JPG", "IMG_0002.JPG", "IMG_0003.JPG"]
    m = match_events_to_images(ev, ["c.jpg", "a.jpg", "b.jpg"])
    assert list(m.image) == ["a.jpg", "b.jpg", "c.jpg"] and list(m.t) == [1.0, 2.0, 3.0]
    with pytest.raises(InputError, match="3 events but 2 images"):
        match_events_to_images(ev, ["a", "b"])
