"""Self-calibrating bundle adjustment against simulated truth: projection accuracy over the frame, OpenCV
comparison, parameter errors within 3 sigma, honest sigmas over seeds, outliers, fixed parameters."""
import numpy as np
import pytest

from dgcal.calib.selfcal.diagnostics import diagnose, projection_difference
from dgcal.calib.selfcal.adjustment import adjust
from dgcal.calib.selfcal.opencv_baseline import calibrate_with_opencv
from dgcal.fields.targets.plate import TargetField
from dgcal.sim.camera_field import calibration_field_camera, plan_shots

SIZE = (6000, 4000)


def simulate_measurements(camera, xyz, shots, noise_px, rng, margin_px=2.0):
    """Noisy projections (px) of field points (m) seen in each shot: (image, index, xy)."""
    w, h = camera.image_size
    img, idx, xy = [], [], []
    for s in shots:
        Xc = xyz @ s.R_field_to_cam.T + s.t_field_to_cam
        uv = camera.project(Xc)
        ok = (Xc[:, 2] > 0) & (uv[:, 0] >= margin_px) & (uv[:, 0] <= w - 1 - margin_px) \
            & (uv[:, 1] >= margin_px) & (uv[:, 1] <= h - 1 - margin_px)
        img += [s.image] * int(ok.sum())
        idx.append(np.flatnonzero(ok))
        xy.append(uv[ok] + rng.normal(0.0, noise_px, (int(ok.sum()), 2)))
    return np.array(img), np.concatenate(idx), np.vstack(xy)


def scene(seed, n_images=48, square_m=0.08, truth=None, field=None):
    rng = np.random.default_rng(seed)
    tf = field or TargetField(square_m=square_m, marker_m=0.75 * square_m)
    pts = tf.points()
    truth = truth or calibration_field_camera(SIZE)
    shots = plan_shots(n_images, truth, tf, rng)
    img, idx, xy = simulate_measurements(truth, pts.xyz, shots, 0.1, rng)
    return truth, pts, img, pts.ids[idx], xy


def test_projection_accuracy_and_opencv_comparison():
    # the simulator's lens has a small skew B2, which OpenCV's model cannot represent
    truth, pts, img, ids, xy = scene(1)
    assert len(set(img.tolist())) >= 40
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
    rms, mx, _ = projection_difference(truth, res.camera)
    assert rms < 0.03 and mx < 0.08, (rms, mx)
    cv_rms, cv_cam = calibrate_with_opencv(pts, img, ids, xy, SIZE)
    cv_diff, cv_max, _ = projection_difference(truth, cv_cam)
    assert rms < cv_diff and mx < cv_max, (rms, cv_diff, mx, cv_max)
    assert res.rms_px <= cv_rms  # same definition: sqrt(mean |v|^2) per point
    assert abs(res.sigma0 - 0.1) < 0.01
    err = (res.camera.params - truth.params)[res.free] / res.camera.sigmas[res.free]
    assert np.all(np.abs(err) < 3.0), dict(zip(np.array(truth.PARAMS)[res.free], err))
    dg = diagnose(res)
    assert not dg.pattern.lens_misfit and not dg.pattern.systematic


def test_same_model_as_opencv_gives_the_same_accuracy():
    # without skew OpenCV's 5-coefficient model is fraser7 with B2 = 0: hold B2 and compare like with like
    truth = calibration_field_camera(SIZE)
    truth.params[9] = 0.0
    truth, pts, img, ids, xy = scene(2, truth=truth)
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7", fixed=("B2",))
    rms, mx, _ = projection_difference(truth, res.camera)
    cv_rms, cv_cam = calibrate_with_opencv(pts, img, ids, xy, SIZE)
    cv_diff, cv_max, _ = projection_difference(truth, cv_cam)
    assert rms < 0.03 and mx < 0.08, (rms, mx)
    # equal up to the few 4-sigma tail points the robust rejection removes from Gaussian noise
    assert rms <= 1.1 * cv_diff + 0.001, (rms, cv_diff)
    assert res.n_rejected < 5e-4 * len(xy) + 3


def test_sigmas_are_honest_over_seeds():
    normalised = []
    for seed in range(5):
        truth, pts, img, ids, xy = scene(100 + seed, n_images=30, square_m=0.16)
        res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
        e = (res.camera.params - truth.params) / res.camera.sigmas
        assert np.all(np.abs(e) < 3.5), e  # 3 sigma for each, a little slack over 50 draws
        normalised.append(e)
    r = float(np.sqrt(np.mean(np.square(normalised))))
    assert 0.6 < r < 1.5, r


def test_outliers_are_rejected_and_listed():
    truth, pts, img, ids, xy = scene(7, n_images=30, square_m=0.16)
    rng = np.random.default_rng(3)
    bad = rng.choice(len(xy), 25, replace=False)
    xy = xy.copy()
    xy[bad] += rng.choice([-1, 1], (25, 2)) * rng.uniform(3, 30, (25, 2))
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
    listed = {(r.image, r.id) for r in res.rejected}
    assert {(img[k], ids[k]) for k in bad} <= listed
    assert len(listed) < 25 + 0.005 * len(xy)
    assert all(r.residual_px > 0.35 for r in res.rejected)  # 4 robust sigmas of 0.1 px noise
    rms, mx, _ = projection_difference(truth, res.camera)
    assert rms < 0.05, rms


def test_start_poses_by_plain_pnp_and_ransac_only_where_gross_errors_call_for_it(monkeypatch):
    from dgcal.calib.selfcal import adjustment
    truth, pts, img, ids, xy = scene(7, n_images=30, square_m=0.16)
    ransac_images = []          # the image of every RANSAC call, found by its first pixel
    ransac = adjustment._pnp_ransac

    def counted(obj, uv, *a):
        ransac_images.append(img[np.flatnonzero(np.all(xy_now == uv[0], axis=1))[0]])
        return ransac(obj, uv, *a)
    monkeypatch.setattr(adjustment, "_pnp_ransac", counted)
    xy_now = xy
    clean = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
    first = set(ransac_images)
    n_images = len(set(img.tolist()))
    assert len(first) <= 0.2 * n_images          # plain IPPE for most (RANSAC where the lens bends corners past 2 %)
    # gross errors (far beyond PnP's 2 % of the frame) in three more images: RANSAC there too, and they are rejected
    names = [n for n in dict.fromkeys(img.tolist()) if n not in first][:3]
    bad = np.concatenate([np.flatnonzero(img == n)[:4] for n in names])
    xy_now = xy.copy()
    xy_now[bad] += 1500.0
    ransac_images.clear()
    res = adjust(pts.ids, pts.xyz, img, ids, xy_now, SIZE, "fraser7")
    assert set(names) <= set(ransac_images) and len(set(ransac_images) - set(names)) <= 0.2 * n_images
    assert {(img[k], ids[k]) for k in bad} <= {(r.image, r.id) for r in res.rejected}
    d = np.abs(res.camera.params - clean.camera.params)
    assert np.all(d <= 3 * clean.camera.sigmas), d / clean.camera.sigmas


def test_fixed_parameters_stay_and_have_zero_sigma():
    truth, pts, img, ids, xy = scene(8, n_images=30, square_m=0.16)
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7", fixed=("K3", "B2"))
    assert res.camera["K3"] == 0.0 and res.camera["B2"] == 0.0
    s = res.camera_sigmas()
    assert s["K3"] == 0.0 and s["B2"] == 0.0 and s["K1"] > 0
    assert np.all(np.isnan(res.correlation[res.camera.PARAMS.index("K3")]))
    # a real misfit (B2, K3 of the truth are not modelled) shows up as a larger sigma0
    assert res.sigma0 > 0.1


def test_opencv8_model_on_simulated_fraser_truth():
    truth, pts, img, ids, xy = scene(9, n_images=30, square_m=0.16)
    truth.params[9] = 0.0  # opencv8 has no skew
    truth, pts, img, ids, xy = scene(9, n_images=30, square_m=0.16, truth=truth)
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "opencv8")
    rms, mx, _ = projection_difference(truth, res.camera)
    # the over-parametrised rational model extrapolates loosely into the sparsely covered corners
    assert rms < 0.05 and mx < 0.6, (rms, mx)
    assert abs(res.sigma0 - 0.1) < 0.015


def test_too_few_images_is_an_input_error():
    from dgcal.fields.errors import InputError
    truth, pts, img, ids, xy = scene(10, n_images=6, square_m=0.16)
    keep = np.isin(img, sorted(set(img.tolist()))[:2])
    with pytest.raises(InputError, match="need 3 or more"):
        adjust(pts.ids, pts.xyz, img[keep], ids[keep], xy[keep], SIZE, "fraser7")


def test_camera_centres_and_their_sigmas_are_honest():
    from scipy.spatial.transform import Rotation
    truth, pts, img, ids, xy = scene(11, n_images=30, square_m=0.16)
    res = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
    rng = np.random.default_rng(11)
    shots = {s.image: s for s in plan_shots(30, truth, TargetField(square_m=0.16, marker_m=0.12), rng)}
    C, sC = res.camera_centres()
    z = []
    for i, name in enumerate(res.image_names):
        s = shots[name]
        C_true = -s.R_field_to_cam.T @ s.t_field_to_cam
        z.append((C[i] - C_true) / sC[i])
        dR = Rotation.from_matrix(res.R_field_to_cam[i] @ s.R_field_to_cam.T).as_rotvec()
        assert np.all(np.abs(np.degrees(dR)) < 4 * res.pose_sigma[i, 3:] + 1e-9)
    z = np.array(z)
    assert np.all(np.abs(z) < 4.5) and 0.5 < np.sqrt(np.mean(z**2)) < 1.6, np.sqrt(np.mean(z**2))


def test_initial_camera_gives_the_same_solution():
    truth, pts, img, ids, xy = scene(12, n_images=20, square_m=0.16)
    a = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7")
    b = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7", initial=truth)
    assert np.all(np.abs(a.camera.params - b.camera.params) < 0.01 * a.camera.sigmas)
    # another model as the start: converted, then adjusted
    c = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "opencv8", initial=truth)
    assert abs(c.rms_px - a.rms_px) < 0.01


def test_thinned_start_keeps_every_kth_row_of_each_image():
    from dgcal.calib.selfcal.adjustment import _thinned
    img = np.array([0, 1, 0, 1, 0, 1, 0, 1, 0, 2, 2, 0, 0, 0, 0])  # interleaved rows; image 0: 9, 1: 4, 2: 2
    active = np.ones(len(img), bool)
    active[4] = False                                                # image 0: 8 active rows
    keep = _thinned(img, active, 3, 2)
    assert np.array_equal(np.flatnonzero(keep), [0, 1, 5, 9, 10, 11])  # 0: every 4th active, 1: every 2nd, 2: all
    assert _thinned(img, active, 3, 5) is None                       # no image has 2 x 5: nothing to thin


def test_thinned_start_reaches_the_minimum_of_all_observations(monkeypatch):
    # without rejection the observations are the same: the thinned first solve only changes the path there
    from dgcal.calib.selfcal import adjustment
    truth, pts, img, ids, xy = scene(3, n_images=18)
    thinned = []
    spy = adjustment._thinned
    monkeypatch.setattr(adjustment, "_thinned", lambda *a: thinned.append(spy(*a)) or thinned[-1])
    a = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7", reject_k=0)
    assert thinned[-1] is not None and thinned[-1].sum() < 0.6 * len(xy)
    monkeypatch.setattr(adjustment, "COARSE_POINTS", 10 ** 9)
    b = adjust(pts.ids, pts.xyz, img, ids, xy, SIZE, "fraser7", reject_k=0)
    assert thinned[-1] is None
    assert np.all(np.abs(a.camera.params - b.camera.params) < 0.01 * b.camera.sigmas)
    np.testing.assert_allclose(a.camera.sigmas, b.camera.sigmas, rtol=1e-4)
    np.testing.assert_allclose(a.poses.cov, b.poses.cov, rtol=1e-3, atol=1e-20)
    assert a.sigma0 == pytest.approx(b.sigma0, rel=1e-6)
