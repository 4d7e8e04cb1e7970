"""Asking a camera for a parameter its model does not have names the parameter and the model's own (issue 30)."""
import numpy as np
import pytest

from dgcal.calib.camera.conversions import AUSTRALIS_PARAMS, AustralisModel
from dgcal.calib.camera.files import read_camera, write_metashape_xml
from dgcal.calib.camera.models import Fraser7, OpenCV8, UnknownParameterError


def test_metashape_camera_unknown_parameter_is_a_clear_key_error(tmp_path):
    cam = Fraser7((4000, 3000), np.array([3500.0, 2000.0, 1500.0, -0.1, 0.05, 0, 1e-4, -2e-4, 0.3, 0]))
    write_metashape_xml(tmp_path / "cam.xml", cam)
    back = read_camera(tmp_path / "cam.xml")
    assert back["f"] == pytest.approx(3500.0)
    with pytest.raises(KeyError) as e:
        back["fx"]
    msg = str(e.value)
    assert "'fx'" in msg and "fraser7" in msg and "f, cx, cy, K1" in msg
    assert isinstance(e.value, UnknownParameterError)


def test_every_model_names_its_parameters():
    cv = OpenCV8((640, 480), np.array([500.0, 501, 320, 240] + [0.0] * 8))
    assert cv["fy"] == 501.0
    with pytest.raises(KeyError, match=r"opencv8 has no parameter 'f'; its parameters are fx, fy, cx, cy"):
        cv["f"]
    au = AustralisModel((640, 480), np.arange(10.0))
    assert au["xp"] == 1.0
    with pytest.raises(KeyError, match="Australis has no parameter 'f'; its parameters are "
                       + ", ".join(AUSTRALIS_PARAMS)):
        au["f"]
