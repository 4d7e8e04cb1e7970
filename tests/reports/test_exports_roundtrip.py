"""EOP exports: round trips (1e-6 m, 1e-6 deg) and the COLMAP model reprojecting points to the same pixels."""
import numpy as np
import pytest

from dgcal.calib.dg.eop import dg_eop
from dgcal.calib.mounting.common import MountingResult
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.reports.exports.eop import (export_all, read_colmap, read_metashape, read_odm_geo, read_pix4d)
from dgcal.sim.mounting import simulate_mounting


@pytest.fixture(scope="module")
def data():
    sim = simulate_mounting(4, n_ground=25)
    mount = MountingResult("truth", sim.lever_arm_m, sim.R_cam_to_body, sim.delay_s, np.zeros((7, 7)))
    g = MapGrid(sim.crs)
    eop, _, _ = dg_eop(g, sim.mapping.traj, sim.mapping.events, mount)
    return sim, g, eop


def _angle_diff(a, b):
    return np.abs((a - b + 180) % 360 - 180)


def test_text_exports_round_trip(data, tmp_path):
    sim, g, eop = data
    paths = export_all(tmp_path, eop, g, sim.camera, formats=("pix4d", "metashape", "odm", "eop"))
    for reader in (lambda: read_pix4d(paths["pix4d"]), lambda: read_metashape(paths["metashape"]),
                   lambda: read_odm_geo(paths["odm"])[0]):
        e2 = reader()
        assert list(e2.image) == [str(s) for s in eop.image]
        assert np.max(np.abs(e2.xyz - eop.xyz)) < 1e-6
        assert np.max(_angle_diff(e2.opk, eop.opk)) < 1e-6
    assert read_odm_geo(paths["odm"])[1].crs.to_epsg() == 32651


def test_colmap_round_trip_and_reprojection(data, tmp_path):
    import pycolmap
    sim, g, eop = data
    mp = sim.mapping
    pts = {str(i): x for i, x in zip(sim.ground.ids, sim.ground.xyz)}
    obs = [(mp.measurements.image[k], mp.measurements.id[k], *mp.measurements.xy[k])
           for k in range(len(mp.measurements))]
    export_all(tmp_path, eop, g, sim.camera, formats=("colmap",), points_map=pts, observations=obs)
    e2, g2 = read_colmap(tmp_path / "colmap")
    assert np.max(np.abs(e2.xyz - eop.xyz)) < 1e-6
    assert np.max(_angle_diff(e2.opk, eop.opk)) < 1e-6
    rec = pycolmap.Reconstruction(str(tmp_path / "colmap"))
    assert rec.num_images() == len(eop.image) and rec.num_points3D() == len(set(mp.measurements.id))
    # pixels of the ground points through pycolmap vs dgcal's camera model with the same DG EOPs
    from dgcal.fields.crs import LocalENU
    from dgcal.fields.world import World
    import json
    geo = json.loads((tmp_path / "colmap" / "georef.json").read_text())
    world = World(g, LocalENU(*geo["origin_lat_lon_h"]))
    poses = world.eop_to_poses(eop.xyz, eop.opk)
    C_world, R_cam_to_world = poses.C_world, poses.R_cam_to_world
    X_world = world.to_world(sim.ground.xyz)
    worst = 0.0
    n = 0
    for img in rec.images.values():
        k = [str(s) for s in eop.image].index(img.name)
        Xc = (X_world - C_world[k]) @ R_cam_to_world[k]
        ours = sim.camera.project(Xc)
        inside = (Xc[:, 2] > 0) & (ours[:, 0] > 0) & (ours[:, 0] < 5616) & (ours[:, 1] > 0) & (ours[:, 1] < 3744)
        for j in np.nonzero(inside)[0]:
            theirs = img.project_point(X_world[j])
            worst = max(worst, float(np.max(np.abs(np.asarray(theirs) - 0.5 - ours[j]))))
            n += 1
    assert n > 100 and worst < 1e-6


def test_readers_name_bad_lines(tmp_path):
    p = tmp_path / "geo.txt"
    p.write_text("EPSG:32651\nIMG_1.JPG 1 2 3 0 0 0\nIMG_2.JPG 1 x 3 0 0 0\n")
    with pytest.raises(InputError) as e:
        read_odm_geo(p)
    assert "geo.txt:3" in str(e.value)
    p2 = tmp_path / "geo2.txt"
    p2.write_text("not a crs at all\nIMG_1.JPG 1 2 3 0 0 0\n")
    with pytest.raises(InputError):
        read_odm_geo(p2)
