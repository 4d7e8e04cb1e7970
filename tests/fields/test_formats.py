import numpy as np
import pytest

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.fields.errors import InputError
from dgcal.fields.io import formats as F

rng = np.random.default_rng(3)


def test_points_round_trip(tmp_path):
    pts = F.Points(np.array(["a", "b", "c"], dtype=object), rng.normal(size=(3, 3)) * 100,
                   np.full((3, 3), 0.01), np.array(["control", "check", "control"], dtype=object))
    F.write_points(tmp_path / "p.csv", pts)
    back = F.read_points(tmp_path / "p.csv")
    assert list(back.ids) == ["a", "b", "c"] and list(back.role) == ["control", "check", "control"]
    np.testing.assert_allclose(back.xyz, pts.xyz, atol=1e-6)
    np.testing.assert_allclose(back.sigma, pts.sigma)


def test_points_errors_name_line_and_field(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("id,x,y,z\n1,0,0,0\n2,0,zero,0\n")
    with pytest.raises(InputError, match=r"g.csv:3: field 'y': not a number"):
        F.read_points(p)
    p.write_text("id,x,z\n1,0,0\n")
    with pytest.raises(InputError, match=r"g.csv:1: missing column\(s\) y"):
        F.read_points(p)
    p.write_text("id,x,y,z\n1,0,0,0\n1,1,1,1\n")
    with pytest.raises(InputError, match=r"g.csv:3: field 'id': duplicate point id '1'"):
        F.read_points(p)
    p.write_text("id,x,y,z,role\n1,0,0,0,ctrl\n")
    with pytest.raises(InputError, match=r"g.csv:2: field 'role'"):
        F.read_points(p)
    with pytest.raises(InputError, match="file not found"):
        F.read_points(tmp_path / "nope.csv")


def test_measurements_round_trip_and_duplicates(tmp_path):
    m = F.Measurements(np.array(["i1", "i1", "i2"], dtype=object), np.array(["1", "2", "1"], dtype=object),
                       rng.uniform(0, 4000, (3, 2)), np.full((3, 2), np.nan))
    F.write_measurements(tmp_path / "m.csv", m)
    back = F.read_measurements(tmp_path / "m.csv")
    np.testing.assert_allclose(back.xy, m.xy, atol=1e-4)
    assert back.images() == ["i1", "i2"]
    (tmp_path / "d.csv").write_text("image,id,x,y\na,1,1,1\na,1,2,2\n")
    with pytest.raises(InputError, match=r"d.csv:3: field 'id': point '1' measured twice"):
        F.read_measurements(tmp_path / "d.csv")


def test_trajectory_and_events_round_trip(tmp_path):
    n = 5
    t = 2150 * SECONDS_PER_WEEK + 300000.0 + np.arange(n) * 0.5
    tr = F.Trajectory(t, 23 + rng.uniform(0, 0.01, n), 120 + rng.uniform(0, 0.01, n), 300 + rng.normal(size=n),
                      rng.normal(size=(n, 3)), rng.uniform(-10, 10, (n, 3)) + [0, 0, 180], np.full((n, 6), 0.02))
    F.write_trajectory(tmp_path / "t.csv", tr)
    back = F.read_trajectory(tmp_path / "t.csv")
    np.testing.assert_allclose(back.t, t, atol=1e-6)
    np.testing.assert_allclose(back.lat, tr.lat, atol=1e-10)
    np.testing.assert_allclose(back.rph, tr.rph, atol=1e-6)
    np.testing.assert_allclose(back.sigma, tr.sigma, atol=1e-6)
    assert back.image is None
    tr.image = np.array([f"IMG_{i}.JPG" for i in range(n)], dtype=object)
    F.write_trajectory(tmp_path / "e.csv", tr)
    assert (tmp_path / "e.csv").read_text().startswith("image,gps_week")
    assert list(F.read_trajectory(tmp_path / "e.csv").image) == list(tr.image)
    ev = F.Events(tr.image, t)
    F.write_events(tmp_path / "ev.csv", ev)
    eb = F.read_events(tmp_path / "ev.csv")
    np.testing.assert_allclose(eb.t, t, atol=1e-6)
    assert int(eb.week[0]) == 2150 and abs(eb.sow[0] - 300000.0) < 1e-9


def test_trajectory_time_must_increase(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text(",".join(F.TRAJECTORY_COLUMNS) + "\n" + "2150,10,23,120,0,0,0,0,0,0,0\n2150,9,23,120,0,0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"t.csv:3: field 'gps_sow': time does not increase"):
        F.read_trajectory(p)


def test_eop_round_trip(tmp_path):
    n = 4
    e = F.EOP(np.array([f"im{i}" for i in range(n)], dtype=object), rng.normal(size=(n, 3)) * 1e5,
              rng.uniform(-180, 180, (n, 3)), np.full((n, 6), 0.01))
    F.write_eop(tmp_path / "eop.csv", e)
    b = F.read_eop(tmp_path / "eop.csv")
    np.testing.assert_allclose(b.xyz, e.xyz, atol=1e-6)
    np.testing.assert_allclose(b.opk, e.opk, atol=1e-6)
    np.testing.assert_allclose(b.sigma, e.sigma, atol=1e-5)
    assert (tmp_path / "eop.csv").read_text().split("\n")[0] == ("image,X,Y,Z,omega,phi,kappa,"
                                                                "sX,sY,sZ,somega,sphi,skappa")


def test_columns_written_as_table_rows_with_quoting(tmp_path):
    """write_columns gives what write_table gives for the same cells (names with commas and quotes quoted), and
    refuses a column count that does not match the header."""
    from dgcal.fields.io.csv_tables import formatted, read_table, write_columns, write_table
    names = ['IMG_1.JPG', 'a,b', 'say "x"']
    x = np.array([1.0, -2.5, 1e-7])
    write_columns(tmp_path / "c.csv", ["image", "x"], [names, formatted(x, "%.10g")])
    write_table(tmp_path / "t.csv", ["image", "x"], zip(names, x.tolist()))
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "t.csv").read_bytes()
    back = read_table(tmp_path / "c.csv", ("image", "x"))
    assert list(back["image"]) == names and np.array_equal(back["x"], x)
    with pytest.raises(ValueError, match="2 columns for 3 header names"):
        write_columns(tmp_path / "bad.csv", ["image", "x", "y"], [names, formatted(x, "%g")])
    assert not (tmp_path / "bad.csv").exists()
