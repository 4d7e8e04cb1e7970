"""`dgcal georef`: pixels + EOPs + height / DEM / laser ranges -> ground points and per-point averages."""
import numpy as np
import pytest

from dgcal.calib.camera.files import write_camera_json
from dgcal.calib.camera.models import Fraser7
from dgcal.calib.dg.dem import Dem, write_geotiff_dem
from dgcal.cli import main
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.io.formats import EOP, Measurements, write_eop, write_measurements
from dgcal.fields.frames import R_cam_to_map_from_opk

CRS = "EPSG:32617"


@pytest.fixture()
def campaign(tmp_path):
    rng = np.random.default_rng(0)
    cam = Fraser7.from_dict((1000, 700), {"f": 900.0, "cx": 502.0, "cy": 347.0, "K1": -0.05})
    write_camera_json(tmp_path / "camera.json", cam)
    P = {"H1": np.array([588010.0, 4390020.0, 301.5]), "H2": np.array([587990.0, 4389985.0, 302.0])}
    names, xyz, opk, rows_img, rows_id, xy = [], [], [], [], [], []
    for k in range(6):
        C = np.array([588000.0 + 8 * k - 20, 4390000.0 + rng.normal(0, 3), 410.0])
        a = np.array([rng.normal(0, 2), rng.normal(0, 2), rng.uniform(0, 360)])
        names.append(f"IMG_{k}.JPG")
        xyz.append(C)
        opk.append(a)
        R = R_cam_to_map_from_opk(*a)
        for pid, X in P.items():
            uv = cam.project(((X - C) @ R)[None])[0]
            rows_img.append(names[-1])
            rows_id.append(pid)
            xy.append(uv)
    eop = EOP(np.array(names), np.array(xyz), np.array(opk), np.tile([0.05, 0.05, 0.08, 0.01, 0.01, 0.02], (6, 1)))
    write_eop(tmp_path / "eop.csv", eop)
    m = Measurements(np.array(rows_img), np.array(rows_id), np.array(xy), np.full((len(xy), 2), np.nan))
    write_measurements(tmp_path / "pix.csv", m)
    return tmp_path, P, eop, cam


def _avg(out):
    t = read_table(out / "georef_average.csv", ("id", "x", "y", "z", "sx", "sy", "n_images"))
    return {str(i): (np.array([x, y]), np.array([sx, sy]), n) for i, x, y, sx, sy, n in
            zip(t["id"], t["x"], t["y"], t["sx"], t["sy"], t["n_images"])}


def test_georef_dem_and_height(campaign):
    d, P, eop, cam = campaign
    x = np.arange(587900.0, 588100.0, 2.0)
    y = np.arange(4390100.0, 4389900.0, -2.0)
    X, Y = np.meshgrid(x, y)
    H = 300.0 + 0.01 * (X - 587900.0) + 0.02 * (Y - 4389900.0)  # a plane through H1 (shifted below)
    H = H - (300.0 + 0.01 * (P["H1"][0] - 587900.0) + 0.02 * (P["H1"][1] - 4389900.0)) + P["H1"][2]
    write_geotiff_dem(d / "dem.tif", Dem(H, np.array([[2.0, 0.0, x[0]], [0.0, -2.0, y[0]]]), CRS))
    assert main(["georef", "--camera", str(d / "camera.json"), "--measurements", str(d / "pix.csv"), "--crs", CRS,
                 "--eop", str(d / "eop.csv"), "--dem", str(d / "dem.tif"), "--sigma-px", "0.3",
                 "--out", str(d / "out_dem")]) == 0
    assert (d / "out_dem" / "georef.html").stat().st_size > 5000
    av = _avg(d / "out_dem")
    xy, s, n = av["H1"]
    assert n == 6 and np.abs(xy - P["H1"][:2]).max() < 0.01 and np.all(s > 0) and np.all(s < 0.2)
    assert main(["georef", "--camera", str(d / "camera.json"), "--measurements", str(d / "pix.csv"), "--crs", CRS,
                 "--eop", str(d / "eop.csv"), "--height", "302.0", "--out", str(d / "out_h")]) == 0
    assert np.abs(_avg(d / "out_h")["H2"][0] - P["H2"][:2]).max() < 0.01


def test_georef_ranges_and_errors(campaign, capsys):
    d, P, eop, cam = campaign
    # level ground at 301.5 m: ranges along each optical axis
    lines = ["image,range_m"]
    for name, C, a in zip(eop.image, eop.xyz, eop.opk):
        dz = R_cam_to_map_from_opk(*a)[:, 2]
        lines.append(f"{name},{(301.5 - C[2]) / dz[2]:.4f}")
    (d / "ranges.csv").write_text("\n".join(lines) + "\n")
    assert main(["georef", "--camera", str(d / "camera.json"), "--measurements", str(d / "pix.csv"), "--crs", CRS,
                 "--eop", str(d / "eop.csv"), "--ranges", str(d / "ranges.csv"), "--out", str(d / "out_r")]) == 0
    assert np.abs(_avg(d / "out_r")["H1"][0] - P["H1"][:2]).max() < 0.01
    (d / "bad.csv").write_text("image,range_m\nIMG_0.JPG,-3\n")
    rc = main(["georef", "--camera", str(d / "camera.json"), "--measurements", str(d / "pix.csv"), "--crs", CRS,
               "--eop", str(d / "eop.csv"), "--ranges", str(d / "bad.csv"), "--out", str(d / "out_bad")])
    assert rc == 2 and not (d / "out_bad").exists()
    err = capsys.readouterr().err
    assert "bad.csv" in err and "range_m" in err
