"""Real data: MicMac's micmac-saisies bundle (4 images, GCP XML, SIFT tie points) against MicMac's own result."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.bundle.datum_check import gcp_datum_step
from dgcal.bundle.tiepoints import extract_tie_points
from dgcal.bundle.triangulation import TriangulationOptions, triangulate
from dgcal.calib.camera.files import load_camera
from dgcal.fields.io.formats import Measurements
from dgcal.fields.io.gcp_files import read_micmac_measurements, read_micmac_orientation, read_micmac_points


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


def _agreement(d, res) -> tuple[np.ndarray, np.ndarray]:
    """Centre distance (m) and rotation angle (deg) of every adjusted image to MicMac's Ori-Ground_mm3d."""
    dC, dR = [], []
    for i, name in enumerate(res.images):
        R_cam_to_world, C = read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{name}.xml")
        dC.append(np.linalg.norm(res.eop.xyz[i] - C))
        dR.append(np.degrees(Rotation.from_matrix(R_cam_to_world.T @ res.R_world_to_cam[i].T).magnitude()))
    return np.array(dC), np.array(dR)


@pytest.mark.xfail(strict=True, reason="issue 3 acceptance (< 0.2 deg) is not reachable by any least-squares "
                   "adjustment of these GCP measurements: MicMac's published block is 0.30 deg (chi2(7) = 16) off "
                   "the least-squares datum of its own shape on them; ours differs from MicMac's by 0.20-0.27 deg "
                   "(see test_micmac_orientation_gap_is_micmacs_datum, docs/triangulation.md)")
def test_micmac_positions_and_orientations_agree(micmac):
    d, pts, gcp_meas, tie, res = micmac
    assert len(res.images) == 4
    dC, dR = _agreement(d, res)
    assert np.all(dC < 0.05)
    assert np.all(dR < 0.2)


def test_micmac_positions_agree_and_relative_orientations(micmac):
    d, pts, gcp_meas, tie, res = micmac
    dC, dR = _agreement(d, res)
    assert np.all(dC < 0.05)
    # relative orientations (the block's shape, from the tie points) agree far better than the datum
    R = [res.R_world_to_cam[i] for i in range(4)]
    Rm = [read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{n}.xml")[0].T for n in res.images]
    for i in range(4):
        for j in range(i + 1, 4):
            diff = Rotation.from_matrix((R[i] @ R[j].T) @ (Rm[i] @ Rm[j].T).T).magnitude()
            assert np.degrees(diff) < 0.1


def test_micmac_orientation_gap_is_micmacs_datum(micmac):
    """Why the 0.2 deg acceptance is not met: MicMac's datum is not the least-squares datum of these GCPs."""
    d, pts, gcp_meas, tie, res = micmac
    cam = res.camera
    names = list(res.images)
    ori = [read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{n}.xml") for n in names]
    for i in range(4):
        # with the GCPs at 5 mm our rotation sigmas are 0.37/0.38/0.16 deg: MicMac's answer is inside 1 sigma
        sig_deg = np.degrees(np.sqrt(np.diag(res.bundle.cov_pose[i])[3:]))
        assert np.sum(sig_deg > 0.3) == 2
        d_theta = Rotation.from_matrix(ori[i][0].T @ res.R_world_to_cam[i].T).as_rotvec()
        assert d_theta @ np.linalg.solve(res.bundle.cov_pose[i][3:, 3:], d_theta) < 3.5   # chi2(3) at 68 %
    # MicMac's own orientations fit the GCP measurements worse than ours (its RMS 1.01 px, ours 0.66 px)
    ids = list(pts.ids)
    known = np.array([p in ids for p in gcp_meas.id])
    X = np.array([pts.xyz[ids.index(p)] for p in gcp_meas.id[known]])
    k = np.array([names.index(n) for n in gcp_meas.image[known]])
    R_mm = np.array([o[0] for o in ori])
    C_mm = np.array([o[1] for o in ori])
    X_cam = np.einsum("nji,nj->ni", R_mm[k], X - C_mm[k])
    rms_mm = np.sqrt(np.mean((cam.project(X_cam) - gcp_meas.xy[known]) ** 2))
    r_ours = np.concatenate([[m["residual_px"] for m in g["measurements"]] for g in res.gcp])
    assert rms_mm > 0.9 and np.sqrt(np.mean(r_ours ** 2)) < 0.8
    # MicMac's block is not at the least-squares datum of these GCP measurements: the best similarity of its
    # block (its own shape, so no tie point can matter) moves it by 0.30 deg and 2.3 cm and the GCP RMS from
    # 1.01 to 0.73 px; leaving out any one GCP still leaves a step >= 0.22 deg
    obs = dict(obs_image=k, X_world=X, uv=gcp_meas.xy[known])
    step = gcp_datum_step(cam, R_mm, C_mm, **obs)
    assert step.angle_deg > 0.25 and step.rms_after_px < 0.8 < step.rms_before_px
    for g in set(gcp_meas.id[known]):
        keep = gcp_meas.id[known] != g
        assert gcp_datum_step(cam, R_mm, C_mm, k[keep], X[keep], gcp_meas.xy[known][keep]).angle_deg > 0.2
    # MicMac's block moved to that datum agrees with ours far inside the acceptance (0.08-0.11 deg, < 1 cm)
    for i, _name in enumerate(names):
        assert np.linalg.norm(step.C_world[i] - res.eop.xyz[i]) < 0.015
        assert np.degrees(Rotation.from_matrix(step.R_cam_to_world[i].T @ res.R_world_to_cam[i].T).magnitude()) < 0.15


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
