"""GNSS-supported aerial triangulation (issue 29): RTK camera centres as the datum with 0, 1, 3 or 5 GCPs, the
datum stated, a weak datum warned about, the focal length-height correlation of nadir blocks, early refusal
without any datum, images left with too few rays named, warnings through Python's `warnings`.

The RTK-drone family of `dgcal.sim.block` at a small scale (48 images, 4 strips of 12, 35 mm on 8192 x 5460 px at
150 m over +-50 m hills, centres 2/2/5 cm); the approximate EOPs are the truth perturbed by 1 m and 0.5 deg, and
one test starts from the centres alone."""
import json
from pathlib import Path
import warnings

import numpy as np
import pytest

from dgcal.bundle import inputs as inputs_mod
from dgcal.bundle.inputs import TriangulateOptions, gather_inputs
from dgcal.fields.io.centres import read_centres
from dgcal.bundle.triangulation import TriangulationOptions, triangulate
from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Measurements, Points, write_eop
from dgcal.sim.block import BlockPattern, simulate_block, simulate_rtk_block, write_block

RTK = (0.02, 0.02, 0.05)


def approx_of(sim, seed=1, dpos=1.0, dang=0.5) -> EOP:
    """The truth EOPs perturbed (m, deg)."""
    rng = np.random.default_rng(seed)
    n = len(sim.images)
    return EOP(sim.eop.image.copy(), sim.eop.xyz + rng.normal(0, dpos, (n, 3)),
               sim.eop.opk + rng.normal(0, dang, (n, 3)))


def triangulate_block_cli(sim, tmp_path, refine: str) -> tuple[int, Path]:
    """`dgcal triangulate` on the block written to files (camera, GCPs, measurements, centres, approximate EOPs),
    `--refine REFINE`: (exit status, output folder)."""
    d = tmp_path / "blk"
    write_block(sim, d)
    write_eop(d / "approx.csv", approx_of(sim))
    out = tmp_path / "out"
    rc = main(["triangulate", "--camera", str(d / "camera.json"), "--gcp", str(d / "gcp.csv"), "--crs", sim.crs,
               "--measurements", str(d / "measurements.csv"), "--image-size", "8192", "5460", "--gnss",
               str(d / "centres.csv"), "--approx", str(d / "approx.csv"), "--refine", refine, "--out", str(out)])
    return rc, out


def eop_z(sim, res) -> np.ndarray:
    """(n,6) EOP errors over their sigmas."""
    idx = {k: i for i, k in enumerate(sim.eop.image)}
    ti = [idx[k] for k in res.eop.image]
    dp = res.eop.xyz - sim.eop.xyz[ti]
    da = (res.eop.opk - sim.eop.opk[ti] + 180) % 360 - 180
    return np.column_stack([dp, da]) / res.eop.sigma


def _run(sim, refine=(), **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(refine=refine, **kw),
                           approx=approx_of(sim), centre_priors=sim.centres)


@pytest.fixture(scope="module")
def rtk():
    """The 48-image RTK block triangulated with 0, 1, 3 and 5 GCPs (seeds 0, 1, 3, 5: independent centre noise):
    {n_gcp: (sim, result)}."""
    out = {}
    for g in (0, 1, 3, 5):
        sim = simulate_rtk_block(g, n_images=48, n_control=g)
        out[g] = (sim, _run(sim))
    return out


@pytest.mark.parametrize("n_gcp", [0, 1, 3, 5])
def test_rtk_centres_are_the_datum_with_any_number_of_gcps(rtk, n_gcp):
    sim, res = rtk[n_gcp]
    s = res.summary
    assert s["trusted"] and s["n_oriented"] == len(sim.images) == 48
    assert 0.9 < s["sigma0"] < 1.1
    d = s["datum"]
    assert d["n_centres"] == 48 and d["n_control"] == n_gcp and d["fixed"] == ["position", "scale", "rotation"]
    assert "48 camera centres (σ 2/2/5 cm)" in d["text"]
    assert ("0 GCPs" in d["text"]) == (n_gcp == 0) and not d["precision"]["weak"]
    c = s["check_rmse_m"]
    assert c["n"] == 10
    # 5 GCPs: issue 29's 3 cm / 5 cm; fewer: the roll about the strips of a 4-strip block rests on the centres'
    # heights (sigma 0.008 deg, 2 cm at the ground), so 3x the centres' accuracy here (1.5x at 300 images: the
    # slow test below)
    h_lim, v_lim = (3 * np.hypot(*RTK[:2]), 1.5 * RTK[2]) if n_gcp < 3 else (0.03, 0.05)
    assert c["horizontal"] < h_lim and c["U"] < v_lim
    # check-point sigmas carry the survey sigma; the errors over them are of the size the sigmas say
    ch = [x for x in res.check if x["evaluated"]]
    assert all(np.allclose(np.hypot(x["sigma_ENU_m"], x["survey_sigma_ENU_m"]), x["sigma_total_ENU_m"]) for x in ch)
    assert all(x["survey_sigma_ENU_m"] == pytest.approx([0.01, 0.01, 0.015]) for x in ch)
    z = np.array([x["normalised"] for x in ch])
    assert np.sqrt(np.mean(z ** 2)) < 2.0 and np.abs(z).max() < 4.5


def test_normalised_eop_errors_over_the_gcp_family_are_honest(rtk):
    # the images of one block share its datum error (the estimate follows the mean of its centres' noise): four
    # blocks are about four samples per component, hence the wide band per component (seed 0's centres tilt the
    # block by 2.9 sigma about the strips) and the narrower one for all of them together
    z = np.vstack([eop_z(sim, res) for sim, res in rtk.values()])
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    assert np.all((rms > 0.4) & (rms < 2.0)), rms
    assert 0.7 < np.sqrt(np.mean(z ** 2)) < 1.4 and np.abs(z).max() < 5


def test_free_focal_length_on_a_nadir_block_warns_of_the_height_correlation(rtk):
    sim, _ = rtk[0]
    res = _run(sim, refine=("f",))
    fh = res.summary["f_height"]
    assert fh["rho"] > 0.95 and fh["sigma_f_px"] > 0.5
    w = [x for x in res.warnings if "focal length and flying height are correlated" in x]
    assert len(w) == 1 and f"ρ = {fh['rho']:.2f}" in w[0] and "oblique images, cross strips" in w[0]
    assert res.camera["f"] == pytest.approx(sim.camera["f"], abs=4 * fh["sigma_f_px"])
    # f fixed: no correlation to report
    assert rtk[0][1].summary["f_height"] is None
    assert not any("flying height" in x for x in rtk[0][1].warnings)


def test_a_second_flying_height_and_cross_strips_separate_f_from_the_height():
    from dgcal.sim.block import p1_35mm_camera
    pat = BlockPattern(heights_m=(150.0, 250.0), n_strips=(3, 2), images_per_strip=(8, 6), cross_strips=2,
                       forward_overlap=0.8, side_overlap=0.7, terrain_amplitude_m=50.0, jitter_deg=(0.5, 0.5, 1.0))
    sim = simulate_block(0, pat, camera=p1_35mm_camera(), n_control=0, n_check=6, n_tie=4000, centre_sigma_m=RTK)
    res = _run(sim, refine=("f",))
    nadir = _run(simulate_rtk_block(0, n_images=48), refine=("f",))
    assert abs(res.summary["f_height"]["rho"]) < abs(nadir.summary["f_height"]["rho"])
    assert res.summary["f_height"]["sigma_f_px"] < nadir.summary["f_height"]["sigma_f_px"]


def test_no_control_and_no_centres_is_refused_with_the_reason():
    sim = simulate_rtk_block(0, n_images=24, n_control=0, centre_sigma_m=None)
    with pytest.raises(InputError, match="no datum"):
        triangulate(sim.camera, sim.points, sim.measurements, sim.crs, approx=approx_of(sim))
    # centres that name no measured image give no datum either
    other = EOP(np.array(["elsewhere.jpg"], dtype=object), sim.eop.xyz[:1], np.full((1, 3), np.nan))
    with pytest.raises(InputError, match="none of the 1 camera centres"):
        triangulate(sim.camera, sim.points, sim.measurements, sim.crs, approx=approx_of(sim), centre_priors=other)


def test_centres_of_other_images_and_images_without_centres_are_named():
    sim = simulate_rtk_block(3, n_images=24, n_control=0)
    keep = np.arange(24) != 7
    c = sim.centres
    centres = EOP(np.r_[c.image[keep], ["IMG_9999.tif"]].astype(object), np.vstack([c.xyz[keep], c.xyz[:1]]),
                  np.vstack([c.opk[keep], c.opk[:1]]), np.vstack([c.sigma[keep], c.sigma[:1]]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, approx=approx_of(sim),
                          centre_priors=centres)
    assert any(w.startswith("1 camera centre(s) name no image of the block (e.g. IMG_9999.tif)") for w in res.warnings)
    assert any(w.startswith(f"1 image(s) have no camera centre (e.g. {sim.images[7]})") for w in res.warnings)
    assert res.summary["datum"]["n_centres"] == 23 and res.summary["n_oriented"] == 24


def test_images_mode_refuses_before_sift(tmp_path, monkeypatch):
    import cv2
    sim = simulate_rtk_block(0, n_images=24, n_control=0, centre_sigma_m=None)
    write_block(sim, tmp_path / "blk")
    img = tmp_path / "img"
    img.mkdir()
    for k in range(2):
        cv2.imwrite(str(img / f"IMG_{k:04d}.tif"), np.zeros((5460, 8192), np.uint8))

    def no_sift(*a, **k):
        raise AssertionError("SIFT ran before the refusal")
    monkeypatch.setattr(inputs_mod, "extract_tie_points", no_sift)
    opts = TriangulateOptions(camera=tmp_path / "blk" / "camera.json", crs=sim.crs, gcp=tmp_path / "blk" / "gcp.csv",
                              images=img)
    with pytest.raises(InputError, match="no datum"):
        gather_inputs(opts)


def test_weak_datum_of_control_along_a_strip_is_warned_and_not_trusted():
    # one strip, its three GCPs within centimetres of the centreline: the roll about the strip is free
    sim = simulate_block(0, BlockPattern(n_strips=(1,), images_per_strip=(12,)), n_control=3, n_check=4, n_tie=3000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(accept_poor=True),
                          approx=approx_of(sim))
    d = res.summary["datum"]
    assert "rotation" not in d["fixed"] and d["line"]["lateral_rms_m"] < 1.0
    assert d["precision"]["weak"] and d["precision"]["rotation_sigma_deg"] > 1.0
    w = [x for x in res.warnings if x.startswith("weak datum")]
    assert len(w) == 1 and f"{d['precision']['rotation_sigma_deg']:.3g} deg" in w[0]
    assert any("datum is not fixed" in p for p in res.problems) and not res.summary["trusted"]


def test_image_with_garbage_measurements_is_named_and_left_out():
    sim = simulate_block(0, BlockPattern(n_strips=(3,), images_per_strip=(10,)), n_control=8, n_tie=6000)
    m = sim.measurements
    bad = "IMG_0012.tif"
    sel = np.flatnonzero(m.image == bad)
    ids = m.id.copy()
    rng = np.random.default_rng(3)
    ids[sel] = np.array([f"T{k:06d}" for k in rng.choice(6000, len(sel), replace=False)], dtype=object)
    ids[sel] = np.where(np.char.startswith(m.id[sel].astype(str), "T"), ids[sel], m.id[sel])  # GCPs kept
    keep = np.ones(len(ids), bool)
    _, first = np.unique(np.c_[m.image.astype(str), ids.astype(str)], axis=0, return_index=True)
    keep[:] = False
    keep[first] = True
    meas = Measurements(m.image[keep], ids[keep], m.xy[keep], m.sigma[keep])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, meas, sim.crs, TriangulationOptions(accept_poor=True),
                          approx=approx_of(sim))
    # its GCP measurements and a stray tie ray survive the outlier cuts: 3 points, not enough to trust
    assert bad not in res.images and len(res.images) == 29
    assert any(w.startswith(f"image {bad} kept 3 of its") and "left out" in w for w in res.warnings)
    assert not res.problems        # one image of 30 left out is within the limit


def test_python_users_see_each_warning_once_and_the_cli_prints_it_once(rtk, tmp_path, capsys):
    sim, _ = rtk[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(refine=("f",)),
                          approx=approx_of(sim), centre_priors=sim.centres)
    texts = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    assert texts and sorted(texts) == sorted(dict.fromkeys(res.warnings))
    # the CLI: a GCP file of check points only, centres with blank angles, f refined
    rc, out = triangulate_block_cli(sim, tmp_path, "f")
    assert rc == 0
    err = capsys.readouterr().err
    assert err.count("focal length and flying height are correlated") == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["datum"]["n_centres"] == 48 and s["datum"]["n_control"] == 0 and s["trusted"]
    assert s["check_rmse_m"]["n"] == 10 and s["f_height"]["rho"] > 0.95


def test_centres_file_with_blank_angles_and_sigmas(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("image,X,Y,Z,omega,phi,kappa,sX,sY,sZ\na.jpg,100,200,300,,,,0.02,0.02,0.05\n"
                 "b.jpg,110,200,300,1,2,3,,,\n")
    c = read_centres(p)
    assert c.xyz.tolist() == [[100, 200, 300], [110, 200, 300]]
    assert np.isnan(c.opk[0]).all() and c.opk[1].tolist() == [1, 2, 3]
    assert c.sigma[0, :3].tolist() == [0.02, 0.02, 0.05] and np.isnan(c.sigma[1]).all()
    q = tmp_path / "d.csv"
    q.write_text("image,X,Y,Z\na.jpg,1,2,3\n")
    assert read_centres(q).sigma.shape == (1, 6)
    for bad, field in (("a.jpg,1,2,x", "z"), ("a.jpg,1,2,3,,,,0.02,-1,0.05", "sy"), ("a.jpg,1,2,3,,abc,,,,", "phi")):
        r = tmp_path / "bad.csv"
        r.write_text("image,X,Y,Z,omega,phi,kappa,sX,sY,sZ\n" + bad + "\n")
        with pytest.raises(InputError) as e:
            read_centres(r)
        assert e.value.line == 2 and e.value.field == field


def test_rtk_block_without_centres_or_control_points_reads_as_all_checks():
    sim = simulate_rtk_block(1, n_images=24, n_control=0)
    assert isinstance(sim.points, Points) and set(sim.points.role) == {"check"}
    e = sim.centres.xyz - sim.eop.xyz
    assert np.all(np.abs(e) < 5 * np.array(RTK)) and sim.centres.sigma[0, :3].tolist() == list(RTK)


@pytest.mark.slow
@pytest.mark.parametrize("n_gcp", [0, 5])
def test_rtk_family_at_300_images_meets_the_issue_29_acceptance(n_gcp):
    # 297 images (11 strips of 27): 0 GCPs within 1.5x the centres' accuracy, 5 GCPs within 3 cm / 5 cm, EOP errors
    # over their sigmas near 1 per component (bench/rtk_block.py 2026-12-07: 1.5 / 1.6 cm and 0.79-1.23 with 0 GCPs,
    # 0.66-1.34 with 5: one block is about one sample of its datum error per component)
    sim = simulate_rtk_block(0, n_images=300, n_control=n_gcp)
    res = _run(sim)
    s = res.summary
    assert s["trusted"] and s["n_oriented"] == len(sim.images)
    c = s["check_rmse_m"]
    h_lim, v_lim = (1.5 * np.hypot(*RTK[:2]), 1.5 * RTK[2]) if n_gcp == 0 else (0.03, 0.05)
    assert c["horizontal"] < h_lim and c["U"] < v_lim
    rms = np.sqrt(np.mean(eop_z(sim, res) ** 2, axis=0))
    assert np.all((rms > 0.5) & (rms < 1.6)), rms
    assert 0.7 < np.sqrt(np.mean(rms ** 2)) < 1.4


def test_centre_prior_block_jacobian_with_antenna_offset_and_flight_shift():
    from dgcal.bundle.solver.blocks import CentrePriors, State
    from dgcal.fields.pose import Poses, so3_exp
    rng = np.random.default_rng(0)
    n = 4
    poses = Poses.from_cam_to_world(so3_exp(rng.normal(0, 0.5, (n, 3))), rng.normal(0, 10, (n, 3)))
    b = CentrePriors.from_arrays(rng.normal(0, 10, (n, 3)), np.full((n, 3), 0.03),
                                 offset_cam=np.array([0.1, -0.2, 0.3]), flight=np.array([0, 0, 1, 1]),
                                 shift_glob=1 + np.arange(6))
    st = State(poses, np.zeros((0, 3)), rng.normal(0, 0.1, 7))
    ev = b.evaluate(st, True)
    eps = 1e-6
    for i in range(n):
        for p in range(6):
            d = np.zeros((n, 6))
            d[i, p] = eps
            moved = st.copy()      # the rule of dgcal.fields.pose: C += dC, R_cam_to_world <- R Exp(dtheta)
            R_c2w = np.swapaxes(st.poses.R_world_to_cam, -1, -2).copy()
            R_c2w[i] = R_c2w[i] @ so3_exp(d[i, 3:][None])[0]
            moved.poses = Poses.from_cam_to_world(R_c2w, st.poses.C_world + d[:, :3])
            num = (b.evaluate(moved, False).r[:, 0] - ev.r[:, 0]) / eps
            ana = np.where(ev.pose == i, ev.J_pose[:, 0, p], 0.0)
            np.testing.assert_allclose(num, ana, atol=1e-4)
    for g in range(1, 7):
        moved = st.copy()
        moved.globals[g] += eps
        num = (b.evaluate(moved, False).r[:, 0] - ev.r[:, 0]) / eps
        np.testing.assert_allclose(num, ev.J_glob[:, 0, list(ev.glob).index(g)], atol=1e-4)


def test_antenna_offset_and_a_shift_per_flight_are_modelled():
    from dgcal.fields.crs import MapGrid
    from dgcal.fields.world import World
    # seeds 5-10 of this case, pooled (2026-12-07): EOP errors over sigmas RMS 0.69-1.16 per component, the flight
    # shifts' 0.67-0.86
    sim = simulate_rtk_block(5, n_images=48, n_control=5)
    offset_cam = np.array([0.05, -0.10, -0.25])        # the antenna above (towards -z) and ahead of the camera
    flights = np.where(np.isin(sim.strip, ["h0s0", "h0s1"]), "A", "B").astype(object)
    shift_map = {"A": np.array([0.12, -0.06, 0.15]), "B": np.array([-0.08, 0.05, -0.10])}
    R_cam_to_world = np.swapaxes(sim.poses.R_world_to_cam, -1, -2)
    antenna_world = sim.poses.C_world + R_cam_to_world @ offset_cam
    w = World(MapGrid(sim.crs), sim.local, crs_text=sim.crs)
    noise = sim.centres.xyz - sim.eop.xyz
    obs = w.to_map(antenna_world) + noise + np.array([shift_map[f] for f in flights])
    centres = EOP(sim.centres.image, obs, sim.centres.opk, sim.centres.sigma)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs,
                          TriangulationOptions(antenna_offset_cam=tuple(offset_cam), flight_shift=True),
                          approx=approx_of(sim), centre_priors=centres, centre_flights=flights)
        naive = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(accept_poor=True),
                            approx=approx_of(sim), centre_priors=centres)
    cm = res.summary["centre_model"]
    assert cm["antenna_offset_cam_m"] == pytest.approx(offset_cam.tolist())
    got = {f["flight"]: f for f in cm["flight_shift"]}
    assert sorted(got) == ["A", "B"] and got["A"]["n_images"] == 24
    R_world_to_grid = res.georef.R_world_to_grid_at(np.zeros((1, 3)))[0]
    for f, truth in shift_map.items():
        est = R_world_to_grid @ np.array(got[f]["shift_ENU_m"])
        sig = np.array(got[f]["sigma_ENU_m"])
        assert np.all(np.abs(est - truth) < 4 * sig + 0.003), (f, est, truth, sig)
    assert "shift of the centres estimated per flight (2)" in res.summary["datum"]["text"]
    z = eop_z(sim, res)
    assert np.sqrt(np.mean(z ** 2)) < 1.5 and res.summary["trusted"]
    # the same centres taken as the projection centres: decimetres off, and the fit says so
    assert res.summary["check_rmse_m"]["U"] < 0.05 < naive.summary["check_rmse_m"]["U"] or \
        naive.summary["sigma0"] > 1.5 * res.summary["sigma0"]


def test_a_flight_shift_without_control_is_refused():
    sim = simulate_rtk_block(0, n_images=24, n_control=0)
    with pytest.raises(InputError, match="needs measured control points"):
        triangulate(sim.camera, sim.points, sim.measurements, sim.crs, TriangulationOptions(flight_shift=True),
                    approx=approx_of(sim), centre_priors=sim.centres)


def test_a_wrong_camera_centre_is_rejected_and_named():
    sim = simulate_rtk_block(1, n_images=24, n_control=0)
    xyz = sim.centres.xyz.copy()
    xyz[5, 2] += 0.6                     # a float fix stated at 5 cm: 12 sigma in height
    xyz[17, 0] -= 0.3                    # 15 sigma in E
    centres = EOP(sim.centres.image, xyz, sim.centres.opk, sim.centres.sigma)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, approx=approx_of(sim),
                          centre_priors=centres)
    rej = {s.image: s for s in res.suspects if s.removed and s.kind == "centre"}
    assert sorted(rej) == sorted([sim.images[5], sim.images[17]])
    assert rej[sim.images[5]].coordinate_error_m[2] == pytest.approx(-0.6, abs=0.12)   # its own 5 cm noise too
    assert rej[sim.images[17]].coordinate_error_m[0] == pytest.approx(0.3, abs=0.06)
    assert sum("camera centre of" in w and "rejected as a blunder" in w for w in res.warnings) == 2
    assert res.summary["trusted"] and res.summary["datum"]["n_centres"] == 22
    assert np.abs(eop_z(sim, res)).max() < 5 and res.summary["n_oriented"] == 24


def test_camera_centres_give_spatial_image_pairs_across_strips():
    from dgcal.bundle.inputs import image_pairs
    sim = simulate_rtk_block(0, n_images=48, n_control=0)
    names = list(sim.images)
    pairs = image_pairs(names, sim.camera, sim.points, sim.centres)
    strip = dict(zip(names, sim.strip))
    gap = {abs(int(strip[a][3:]) - int(strip[b][3:])) for a, b in pairs}
    assert {0, 1} <= gap            # along the strips and to the neighbouring strip (30 % of a footprint away)
    # neighbours only: no pair farther apart than a footprint
    C = dict(zip(names, sim.centres.xyz))
    fp = 150.0 * 8192 / sim.camera["f"]
    assert max(np.linalg.norm(C[a][:2] - C[b][:2]) for a, b in pairs) < fp


def test_zero_gcps_from_measurements_and_centres_alone():
    """No control, no approximate EOPs, no angles: the camera centres start the block (kappa from image motion)
    and fix its datum; every image is oriented and the result equals the one started from approximate EOPs."""
    sim = simulate_rtk_block(2, n_images=48, n_control=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = triangulate(sim.camera, sim.points, sim.measurements, sim.crs, centre_priors=sim.centres)
    s = res.summary
    assert s["trusted"] and s["n_oriented"] == 48
    ref = _run(sim)
    np.testing.assert_allclose(res.eop.xyz, ref.eop.xyz, atol=1e-3)
    c = s["check_rmse_m"]
    assert np.hypot(c["E"], c["N"]) < 3 * np.hypot(*RTK[:2]) and c["U"] < 1.5 * RTK[2]
