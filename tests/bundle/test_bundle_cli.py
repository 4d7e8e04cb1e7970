"""`dgcal triangulate`: outputs, exports, and clear errors or report warnings on bad input."""
import json

import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.io.formats import read_eop, read_measurements, read_points, write_measurements, write_points
from dgcal.sim.flight import simulate_block_flight


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    truth = simulate_block_flight(d, seed=3, render=False, heights=(80.0,), n_strips=(3,), n_images=(7,), n_control=8,
                                  n_check=6, n_tie=250)
    return d, truth


def _run(args):
    return main(["triangulate", *map(str, args)])


def test_cli_writes_eops_report_and_exports(small, tmp_path):
    d, truth = small
    out = tmp_path / "out"
    rc = _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
               d / "measurements_all.csv", "--image-size", 1200, 800, "--out", out])
    assert rc == 0
    eop = read_eop(out / "eop.csv")
    te = read_eop(d / "truth_eop.csv")
    idx = {k: i for i, k in enumerate(te.image)}
    ti = [idx[k] for k in eop.image]
    z = (eop.xyz - te.xyz[ti]) / eop.sigma[:, :3]
    assert np.abs(z).max() < 4.5 and eop.sigma is not None
    s = json.loads((out / "summary.json").read_text())
    assert s["n_oriented"] == len(truth["images"]) and s["check_rmse_m"]["n"] >= 5
    html = (out / "report.html").read_text()
    assert "data:image/png;base64" in html and "Check points" in html
    for f in ("colmap/images.txt", "pix4d_external_orientation.txt", "metashape_opk.csv", "geo.txt"):
        assert (out / "exports" / f).is_file()
    # every export reads back (dgcal.reports.exports.eop readers) to the EOPs of eop.csv
    from dgcal.reports.exports.eop import read_colmap, read_metashape, read_odm_geo, read_pix4d
    ex = out / "exports"
    for back in (read_pix4d(ex / "pix4d_external_orientation.txt"), read_metashape(ex / "metashape_opk.csv"),
                 read_odm_geo(ex / "geo.txt")[0], read_colmap(ex / "colmap")[0]):
        assert list(back.image) == list(eop.image)
        np.testing.assert_allclose(back.xyz, eop.xyz, atol=2e-6)
        np.testing.assert_allclose((back.opk - eop.opk + 180) % 360 - 180, 0, atol=2e-6)


def test_colmap_export_reprojects_gcps(small, tmp_path):
    import pycolmap
    d, truth = small
    out = tmp_path / "out"
    assert _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
                 d / "measurements_all.csv", "--out", out]) == 0
    rec = pycolmap.Reconstruction(str(out / "exports" / "colmap"))
    assert rec.num_images() == len(truth["images"]) and rec.num_points3D() > 0
    errs = []
    for im in rec.images.values():
        cam = rec.cameras[im.camera_id]
        for p2 in im.points2D:
            if p2.has_point3D():
                uv = cam.img_from_cam(im.cam_from_world() * rec.points3D[p2.point3D_id].xyz)
                errs.append(np.linalg.norm(uv - p2.xy))
    # adjusted GCPs reproject onto their measurements up to the noise (0.3 px) and the camera conversion
    assert np.sqrt(np.mean(np.square(errs))) < 1.0


def test_wrong_crs_is_a_clear_error(small, tmp_path, capsys):
    d, _ = small
    rc = _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", "EPSG:4326", "--measurements",
               d / "measurements_all.csv", "--out", tmp_path / "o"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "gcp.csv" in err and "EPSG:4326" in err
    assert not (tmp_path / "o" / "eop.csv").exists()
    assert _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", "EPSG:99999999", "--measurements",
                 d / "measurements_all.csv", "--out", tmp_path / "o"]) == 2
    assert "--crs" in capsys.readouterr().err


def test_image_size_mismatch_and_missing_folder(small, tmp_path, capsys):
    d, truth = small
    base = ["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--out", tmp_path / "o"]
    assert _run(base + ["--measurements", d / "measurements_all.csv", "--image-size", 1000, 800]) == 2
    assert "image-size" in capsys.readouterr().err
    assert _run(base + ["--images", tmp_path / "nowhere"]) == 2
    err = capsys.readouterr().err
    assert "the image folder does not exist" in err and "--images" in err


def test_unmeasured_gcp_and_single_image_gcp_are_reported(small, tmp_path):
    d, truth = small
    pts = read_points(d / "gcp.csv")
    meas = read_measurements(d / "measurements_all.csv")
    # an extra GCP nobody measured, and a control point left with one measurement
    pts.ids = np.append(pts.ids, "GHOST")
    pts.xyz = np.vstack([pts.xyz, pts.xyz[0] + 5])
    pts.sigma = np.vstack([pts.sigma, pts.sigma[0]])
    pts.role = np.append(pts.role, "control")
    write_points(tmp_path / "gcp.csv", pts, with_role=True)
    ctrl = str(pts.ids[np.nonzero(pts.role == "control")[0][0]])
    rows = np.nonzero(meas.id.astype(str) == ctrl)[0]
    keep = np.ones(len(meas), bool)
    keep[rows[1:]] = False
    write_measurements(tmp_path / "m.csv", meas.subset(keep))
    out = tmp_path / "out"
    assert _run(["--camera", d / "camera.json", "--gcp", tmp_path / "gcp.csv", "--crs", truth["crs"],
                 "--measurements", tmp_path / "m.csv", "--out", out]) == 0
    w = json.loads((out / "summary.json").read_text())["warnings"]
    assert any("GHOST" in x and "no image measurements" in x for x in w)
    assert any(ctrl in x and "one image only" in x for x in w)
    html = (out / "report.html").read_text()
    assert "GHOST" in html


def test_check_point_seen_once_and_missing_images_are_warnings(small, tmp_path):
    d, truth = small
    meas = read_measurements(d / "measurements_all.csv")
    chk = [i for i in dict.fromkeys(meas.id.astype(str)) if i.startswith("CHK")][0]
    rows = np.nonzero(meas.id.astype(str) == chk)[0]
    keep = np.ones(len(meas), bool)
    keep[rows[1:]] = False
    write_measurements(tmp_path / "m.csv", meas.subset(keep))
    img_dir = tmp_path / "imgs"
    img_dir.mkdir()
    import cv2
    cv2.imwrite(str(img_dir / "other.png"), np.zeros((800, 1200), np.uint8))
    out = tmp_path / "out"
    assert _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
                 tmp_path / "m.csv", "--images", img_dir, "--out", out]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert any(chk in x and "not evaluated" in x for x in s["warnings"])
    assert any("not in" in x and "without tie points" in x for x in s["warnings"])
    assert any("other.png" in x and "no measurements" in x for x in s["warnings"])


def test_approximate_eops_fixed_gcps_and_bad_refine(small, tmp_path, capsys):
    d, truth = small
    te = read_eop(d / "truth_eop.csv")
    rng = np.random.default_rng(2)
    te.xyz = te.xyz + rng.normal(0, 2.0, te.xyz.shape)       # GNSS-grade approximate positions
    te.opk = te.opk + rng.normal(0, 1.0, te.opk.shape)
    from dgcal.fields.io.formats import write_eop
    write_eop(tmp_path / "approx.csv", te)
    base = ["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
            d / "measurements_all.csv"]
    assert _run(base + ["--approx", tmp_path / "approx.csv", "--fixed-gcps", "--out", tmp_path / "a"]) == 0
    assert _run(base + ["--fixed-gcps", "--out", tmp_path / "p"]) == 0
    eop, ref = read_eop(tmp_path / "a" / "eop.csv"), read_eop(tmp_path / "p" / "eop.csv")
    idx = {k: i for i, k in enumerate(ref.image)}
    # started 2 m / 1 deg away, the same minimum as when started from PnP
    assert np.abs(eop.xyz - ref.xyz[[idx[k] for k in eop.image]]).max() < 1e-3
    truth_eop = read_eop(d / "truth_eop.csv")
    z = (eop.xyz - truth_eop.xyz[[idx[k] for k in eop.image]]) / eop.sigma[:, :3]
    assert np.abs(z).max() < 4.5
    assert _run(base + ["--refine", "f,Q7", "--out", tmp_path / "b"]) == 2
    assert "unknown camera parameter 'Q7'" in capsys.readouterr().err


def test_odm_gcp_list_plus_tie_csv(small, tmp_path, capsys):
    """GCPs from an ODM gcp_list.txt (points and CRS inside), tie points from a CSV: the same EOPs."""
    from dgcal.fields.io.gcp_files import write_odm_gcp_list
    d, truth = small
    pts = read_points(d / "gcp.csv")
    ctrl = pts.subset(pts.role == "control")
    gm = read_measurements(d / "measurements.csv")
    write_odm_gcp_list(tmp_path / "gcp_list.txt", truth["crs"], ctrl, gm)
    rc = _run(["--camera", d / "camera.json", "--crs", truth["crs"], "--measurements", tmp_path / "gcp_list.txt",
               d / "tie_measurements.csv", "--sigma-px", 0.3, "--gcp-sigma", 0.01, 0.01, 0.02, "--out", tmp_path / "o"])
    assert rc == 0
    assert _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
                 d / "measurements.csv", d / "tie_measurements.csv", "--out", tmp_path / "r"]) == 0
    a, b = read_eop(tmp_path / "o" / "eop.csv"), read_eop(tmp_path / "r" / "eop.csv")
    # the reference also has check points measured (they do not enter the adjustment): same EOPs
    np.testing.assert_allclose(a.xyz, b.xyz, atol=0.02)
    assert _run(["--camera", d / "camera.json", "--crs", "EPSG:32650", "--measurements", tmp_path / "gcp_list.txt",
                 d / "tie_measurements.csv", "--out", tmp_path / "x"]) == 2
    assert "differs from --crs" in capsys.readouterr().err


def test_refined_intrinsics_are_written_as_a_camera_and_exported(small, tmp_path):
    import json

    from dgcal.calib.camera.files import read_camera
    d, truth = small
    out = tmp_path / "r"
    assert _run(["--camera", d / "camera.json", "--gcp", d / "gcp.csv", "--crs", truth["crs"], "--measurements",
                 d / "measurements_all.csv", "--refine", "f,cx,cy", "--no-progress", "--out", out]) == 0
    refined = json.loads((out / "camera_refined.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    cam = read_camera(out / "camera_refined.json")
    for k in ("f", "cx", "cy"):
        assert cam[k] == pytest.approx(summary["camera"]["params"][k])
        assert summary["camera"]["sigmas"][k] > 0
    assert refined["correlation"]["parameters"] == ["f", "cx", "cy"]
    # the COLMAP export carries the refined camera, not the one given
    colmap = read_camera(out / "exports" / "colmap" / "cameras.txt", "fraser7")
    assert colmap["f"] == pytest.approx(cam["f"], abs=1e-3)
