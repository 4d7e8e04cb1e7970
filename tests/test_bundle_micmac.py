"""Real data: MicMac's micmac-saisies bundle (4 images, GCP XML, SIFT tie points) against MicMac's own result."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bundle.tiepoints import extract_tie_points
from bundle.triangulation import TriangulationOptions, triangulate
from calib.camera_formats import load_camera
from fields.formats import Measurements
from fields.gcp_io import read_micmac_measurements, read_micmac_orientation, read_micmac_points


@pytest.fixture(scope="module")
def micmac(shared_data):
    d = shared_data / "micmac-saisies"
    cam = load_camera(d / "Ori-Ground_mm3d" / "AutoCal_Foc-28000_Cam-PENTAX_K5.xml")
    pts = read_micmac_points(d / "Ground-Pts3D.xml")
    gcp_meas = read_micmac_measurements(d / "GroundMeasure.xml")
    tie = extract_tie_points(d, max_features=1500, camera_K=cam.pinhole_K())
    pts.sigma[:] = 0.005            # the file's "1 1 1" are placeholders, not metres
    meas = Measurements(np.concatenate([gcp_meas.image, tie.image]), np.concatenate([gcp_meas.id, tie.id]),
                        np.concatenate([gcp_meas.xy, tie.xy]),
                        np.concatenate([np.full((len(gcp_meas), 2), 1.5), np.full((len(tie), 2), 0.5)]))
    res = triangulate(cam, pts, meas, None, TriangulationOptions())
    return d, pts, gcp_meas, tie, res


def test_micmac_readers(micmac):
    d, pts, gcp_meas, tie, res = micmac
    assert len(pts.ids) == 9 and len(gcp_meas) == 19
    assert set(gcp_meas.images()) == {"IMGP4167.JPG", "IMGP4168.JPG", "IMGP4169.JPG", "IMGP4170.JPG"}
    assert len(set(tie.id)) > 500


def test_micmac_positions_and_orientations_agree(micmac):
    d, pts, gcp_meas, tie, res = micmac
    assert len(res.images) == 4
    for i, name in enumerate(res.images):
        R_cv_to_world, C = read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{name}.xml")
        assert np.linalg.norm(res.eop.xyz[i] - C) < 0.05
        d_theta = Rotation.from_matrix(R_cv_to_world.T @ res.R_world_to_cv[i].T).as_rotvec()
        # the four images share one datum rotation of ~0.22 deg w.r.t. MicMac's, along the resection's
        # position/rotation correlation; it lies inside our own 6-D confidence region
        assert np.degrees(np.linalg.norm(d_theta)) < 0.3
        delta = np.concatenate([C - res.eop.xyz[i], d_theta])
        assert delta @ np.linalg.solve(res.bundle.cov_pose[i], delta) < 16.8   # chi2(6) at 99 %
    # relative orientations (the block's shape) agree far better than the datum
    R = [res.R_world_to_cv[i] for i in range(4)]
    Rm = [read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{n}.xml")[0].T for n in res.images]
    for i in range(4):
        for j in range(i + 1, 4):
            diff = Rotation.from_matrix((R[i] @ R[j].T) @ (Rm[i] @ Rm[j].T).T).magnitude()
            assert np.degrees(diff) < 0.1


def test_unknown_point_is_a_tie_point_and_reported(micmac):
    d, pts, gcp_meas, tie, res = micmac
    assert "u-of-You" in res.unknown_ids
    rep = {u["id"]: u for u in res.summary["unknown_points"]}
    assert rep["u-of-You"]["n_images"] == 3 and rep["u-of-You"]["xyz"] is not None
    # it sits among the control points it was measured with (I-of-I, Acute, Finger-1 are within ~1 m)
    assert np.linalg.norm(np.array(rep["u-of-You"]["xyz"]) - pts.xyz[list(pts.ids).index("Acute")]) < 1.0
    assert any("Stone-1" in w and "no image measurements" in w for w in res.warnings)
    gcp = {g["id"]: g for g in res.gcp}
    assert max(g["rms_px"] for g in gcp.values()) < 3.0
