"""The image path end to end: rendered flight -> pycolmap SIFT tie points -> triangulation vs truth."""
import numpy as np

from dgcal.bundle.tiepoints import extract_tie_points
from dgcal.fields.io.image_folders import list_image_names
from dgcal.bundle.triangulation import triangulate
from dgcal.calib.camera.files import load_camera
from dgcal.fields.io.formats import Measurements, read_eop, read_measurements, read_points
from dgcal.sim.flight import simulate_block_flight


def test_rendered_flight_with_sift_tie_points(tmp_path):
    truth = simulate_block_flight(tmp_path, seed=5, render=True, heights=(80.0,), n_strips=(2,), n_images=(5,),
                                  n_control=8, n_check=4, n_tie=10, image_size=(600, 400))
    cam = load_camera(tmp_path / "camera.json")
    names = list_image_names(tmp_path / "images")
    assert len(names) == 10
    tie = extract_tie_points(tmp_path / "images", names, max_features=1500, camera_K=cam.pinhole_K())
    assert len(set(tie.id)) > 300
    gcp = read_measurements(tmp_path / "measurements.csv")
    tie.sigma[:] = 0.3
    meas = Measurements(np.concatenate([gcp.image, tie.image]), np.concatenate([gcp.id, tie.id]),
                        np.concatenate([gcp.xy, tie.xy]), np.concatenate([gcp.sigma, tie.sigma]))
    res = triangulate(cam, read_points(tmp_path / "gcp.csv"), meas, truth["crs"])
    assert len(res.images) == 10
    te = read_eop(tmp_path / "truth_eop.csv")
    idx = {k: i for i, k in enumerate(te.image)}
    ti = [idx[k] for k in res.eop.image]
    z = np.column_stack([res.eop.xyz - te.xyz[ti], (res.eop.opk - te.opk[ti] + 180) % 360 - 180]) / res.eop.sigma
    assert np.abs(z).max() < 4.0
    gsd = 80.0 / cam["f"]
    d = np.array([c["dENU_m"] for c in res.check if c["evaluated"]])
    assert len(d) >= 3
    assert np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)) < 1.5 * gsd
    assert np.sqrt(np.mean(d[:, 2] ** 2)) < 2.5 * gsd


def test_aruco_gcp_targets_are_detected_where_they_project(tmp_path):
    from dgcal.bundle.gcp_targets import detect_gcp_targets
    truth = simulate_block_flight(tmp_path, seed=8, render=True, heights=(80.0,), n_strips=(1,), n_images=(3,),
                                  n_control=6, n_check=3, n_tie=10, targets="aruco")
    names = [im["image"] for im in truth["images"]]
    det = detect_gcp_targets(tmp_path / "images", names, "DICT_4X4_50")
    exact = read_measurements(tmp_path / "measurements_exact.csv")
    ref = {(a, b): xy for a, b, xy in zip(exact.image, exact.id, exact.xy)}
    d = np.array([det.xy[i] - ref[(det.image[i], det.id[i])] for i in range(len(det))])
    inner = [(a, b) for a, b, (x, y) in zip(exact.image, exact.id, exact.xy) if 40 < x < 1160 and 40 < y < 760]
    found = set(zip(det.image, det.id))
    assert sum(k in found for k in inner) >= 0.9 * len(inner)   # markers cut by the frame edge may be missed
    assert np.abs(d).max() < 1.5 and np.sqrt(np.mean(d ** 2)) < 0.5
    assert set(det.id) <= {str(i) for i in range(9)}
