"""Real data: intersect micmac-saisies ground points from MicMac's own orientations and calibration."""
import numpy as np

from dgcal.bundle.intersection import intersect
from dgcal.calib.camera.files import load_camera
from dgcal.fields.io.gcp_files import read_micmac_measurements, read_micmac_orientation, read_micmac_points


def test_micmac_ground_points_from_micmac_orientations(shared_data):
    d = shared_data / "micmac-saisies"
    cam = load_camera(d / "Ori-Ground_mm3d" / "AutoCal_Foc-28000_Cam-PENTAX_K5.xml")
    pts = read_micmac_points(d / "Ground-Pts3D.xml")
    meas = read_micmac_measurements(d / "GroundMeasure.xml")
    images = meas.images()
    ori = [read_micmac_orientation(d / "Ori-Ground_mm3d" / f"Orientation-{n}.xml") for n in images]
    R = np.array([o[0] for o in ori])
    C = np.array([o[1] for o in ori])
    ids = list(dict.fromkeys(str(k) for k in meas.id))
    res = intersect(cam, C, R, np.array([images.index(str(k)) for k in meas.image]),
                    np.array([ids.index(str(k)) for k in meas.id]), meas.xy, np.full(meas.xy.shape, 1.0), len(ids))
    pidx = pts.index()
    checked = 0
    for j, k in enumerate(ids):
        if res.ok[j] and k in pidx:
            # MicMac fitted these points as control: the intersection must land on them (cm level, ~15 m range)
            assert np.linalg.norm(res.xyz[j] - pts.xyz[pidx[k]]) < 0.03, k
            assert res.rms_px[j] < 3.0
            checked += 1
    assert checked >= 6
