"""The RTK-drone block family of dgcal.sim.block and `dgcal simulate block` (issue 29)."""
import json

import numpy as np
import pytest

from dgcal.fields.io.centres import read_centres
from dgcal.cli import main
from dgcal.fields.io.formats import read_eop, read_measurements, read_points
from dgcal.sim.block import RTK_CENTRE_SIGMA_M, p1_35mm_camera, simulate_rtk_block


def test_rtk_family_geometry_and_centre_noise():
    cam = p1_35mm_camera()
    assert cam.image_size == (8192, 5460)
    assert abs(cam["f"] * 4.4e-3 - 35.0) < 0.01            # 35 mm lens on 4.4 um pixels
    sim = simulate_rtk_block(4, n_images=96, n_control=5, n_check=8)
    assert len(sim.images) == 96
    h_ground = sim.poses.C_world[:, 2]
    assert abs(np.median(h_ground) - 150.0) < 2.0            # above the mean terrain (world Up at the site)
    # overlaps: along-track base 20 % of the 5460 px footprint, strips 30 % of the 8192 px one
    gsd = 150.0 / cam["f"]
    d = np.diff(sim.poses.C_world[:16, 1])
    assert abs(np.median(np.abs(d)) - 0.2 * 5460 * gsd) < 1.0
    # the centres: truth plus 2/2/5 cm noise (96 draws per axis), sigmas as simulated, angles unknown
    e = sim.centres.xyz - sim.eop.xyz
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    assert np.all(np.abs(rms / RTK_CENTRE_SIGMA_M - 1) < 0.3), rms
    assert np.isnan(sim.centres.opk).all() and np.allclose(sim.centres.sigma[:, :3], RTK_CENTRE_SIGMA_M)
    roles = sim.points.role.tolist()
    assert roles.count("control") == 5 and roles.count("check") == 8


def test_simulate_block_cli_writes_centres_readable_by_triangulate(tmp_path, capsys):
    out = tmp_path / "rtk"
    assert main(["simulate", "block", "--rtk", "--out", str(out), "--seed", "2", "--images", "24", "--gcps", "3"]) == 0
    for f in ("measurements.csv", "gcp.csv", "camera.json", "centres.csv", "truth_eop.csv", "truth.json"):
        assert (out / f).is_file()
    c = read_centres(out / "centres.csv")
    t = read_eop(out / "truth_eop.csv")
    assert list(c.image) == list(t.image) and np.abs(c.xyz - t.xyz).max() < 0.3
    assert np.isnan(c.opk).all() and np.allclose(c.sigma[:, :3], RTK_CENTRE_SIGMA_M)
    pts = read_points(out / "gcp.csv")
    assert list(pts.role).count("control") == 3
    truth = json.loads((out / "truth.json").read_text())
    assert truth["centre_sigma_m"] == list(RTK_CENTRE_SIGMA_M) and len(truth["images"]) == 24
    assert len(read_measurements(out / "measurements.csv").id) > 24 * 300
    # the generic block: 20 mm, 300 m, 4 strips of 15 in opposite headings, 12 GCPs, no centres
    gen = tmp_path / "gen"
    assert main(["simulate", "block", "--out", str(gen), "--seed", "1"]) == 0
    assert not (gen / "centres.csv").exists() and len(read_eop(gen / "truth_eop.csv").image) == 60
    assert list(read_points(gen / "gcp.csv").role).count("control") == 12
    with pytest.raises(SystemExit) as e:
        main(["simulate", "block", "--out", str(tmp_path / "x"), "--gcps", "-1"])
    assert e.value.code == 2 and "must be >= 0" in capsys.readouterr().err
