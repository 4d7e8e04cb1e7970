"""Target detection on rendered photos with known truth: recovery, corner accuracy, honest sigmas, bad input."""
import shutil

import numpy as np
import pytest

from dgcal.calib.selfcal.detection import CharucoFieldDetector, detect_folder, detect_image, read_gray
from dgcal.fields.io.csv_tables import read_table
from dgcal.fields.errors import InputError
from dgcal.fields.targets.printing import print_raster
from dgcal.fields.io.formats import read_measurements, write_measurements
from dgcal.fields.targets.plate import TargetField
from dgcal.sim.camera_field import simulate_camera_field

# small images need coarser squares than the default 0.08 m plate to keep > 30 px per square
FIELD = TargetField(square_m=0.12, marker_m=0.09)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("camfield")
    truth = simulate_camera_field(out, seed=3, n_images=4, image_size=(1200, 800), field=FIELD, progress=False)
    return out, truth


@pytest.fixture(scope="module")
def detected(sim):
    out, _ = sim
    return detect_folder(out / "images", out / "field.csv", workers=2, progress=False)


def _pairs(sim, meas):
    out, _ = sim
    tr = read_table(out / "truth_measurements.csv", ["image", "id", "x", "y", "complete"])
    truth = {(a, b): (np.array([x, y]), c) for a, b, x, y, c in zip(tr["image"], tr["id"], tr["x"], tr["y"],
                                                                      tr["complete"])}
    det = {(a, b): (xy, s) for a, b, xy, s in zip(meas.image, meas.id, meas.xy, meas.sigma)}
    return truth, det


def test_detection_recovers_visible_targets_with_subpixel_accuracy(sim, detected):
    meas, report = detected
    truth, det = _pairs(sim, meas)
    visible = [k for k, (_, c) in truth.items() if c == 1]
    assert len(visible) > 600
    recovered = np.mean([k in det for k in visible])
    assert recovered > 0.95, recovered
    assert all(k in truth for k in det)  # nothing detected that is not there
    err = np.array([det[k][0] - truth[k][0] for k in det])
    rms = np.sqrt(np.mean(err ** 2))
    print(f"recovered {recovered:.3f} of {len(visible)} visible targets; corner RMS {rms:.4f} px per axis, "
          f"max {np.abs(err).max():.3f} px")
    assert rms < 0.08 and np.abs(err).max() < 0.5
    assert abs(err.mean()) < 0.01  # no bias
    assert report["image_size"] == [1200, 800] and report["n_images"] == 4
    assert sum(r["corners"] for r in report["images"].values()) == len(meas)


def test_detection_sigmas_are_honest(sim, detected):
    meas, _ = detected
    truth, det = _pairs(sim, meas)
    z = np.concatenate([(det[k][0] - truth[k][0]) / det[k][1] for k in det])
    ratio = np.sqrt(np.mean(z ** 2))
    print(f"RMS of error/sigma: {ratio:.2f}")
    assert 0.6 < ratio < 1.6


def test_measurements_csv_round_trip(detected, tmp_path):
    meas, _ = detected
    write_measurements(tmp_path / "m.csv", meas)
    back = read_measurements(tmp_path / "m.csv")
    assert list(back.id) == list(meas.id) and np.allclose(back.xy, meas.xy, atol=1e-4)


def test_bad_inputs_name_the_file(sim, tmp_path):
    out, _ = sim
    with pytest.raises(InputError, match="no images"):
        detect_folder(tmp_path, out / "field.csv", progress=False)
    with pytest.raises(InputError, match="does not exist"):
        detect_folder(tmp_path / "nope", out / "field.csv", progress=False)
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    shutil.copy(out / "images" / "IMG_0001.jpg", imgs / "a.jpg")
    (imgs / "b.jpg").write_bytes(b"\xff\xd8 this is not a jpeg")
    with pytest.raises(InputError, match=r"b\.jpg"):
        detect_folder(imgs, out / "field.csv", workers=1, progress=False)
    with pytest.raises(InputError, match=r"b\.jpg"):
        detect_folder(imgs, out / "field.csv", workers=2, progress=False)
    with pytest.raises(InputError, match="missing.jpg"):
        read_gray(tmp_path / "missing.jpg")


def test_ids_missing_from_the_field_csv_are_dropped(sim, tmp_path):
    out, _ = sim
    lines = (out / "field.csv").read_text().splitlines()
    kept = [lines[0]] + lines[1::2]
    (tmp_path / "field.csv").write_text("\n".join(kept) + "\n")
    shutil.copy(out / "field.json", tmp_path / "field.json")
    img = read_gray(out / "images" / "IMG_0001.jpg")
    det = detect_image(img, tmp_path / "field.csv")
    allowed = {ln.split(",")[0] for ln in kept[1:]}
    assert len(det.ids) > 50 and set(det.ids) <= allowed and det.stats["not_in_field"] > 0


def _printed(tf, pad=60):
    img = print_raster(tf, 25.4)
    return np.pad(img, pad, constant_values=255), pad


def test_duplicated_markers_are_rejected():
    tf = TargetField(diameter_m=0.9, square_m=0.08, marker_m=0.06)
    img, pad = _printed(tf, pad=100)
    base = CharucoFieldDetector(tf).detect(img)
    ids, corners, printed = tf.markers()
    m = int(ids[printed][len(ids[printed]) // 2])
    x0, y0 = (corners[list(ids).index(m)].min(axis=0) * 1000).astype(int) + pad
    patch = img[y0 - 10:y0 + 70, x0 - 10:x0 + 70].copy()
    img[5:85, 5:85] = patch  # a second copy of marker m in the white margin
    det = CharucoFieldDetector(tf).detect(img)
    assert det.stats["rejected_duplicate_marker"] == 2
    lost = set(base.ids) - set(det.ids)
    assert lost and set(det.ids) < set(base.ids)
    # only corners next to the duplicated marker are lost
    mx, my = corners[list(ids).index(m)].mean(axis=0)
    for i in lost:
        r, c = int(i[1:3]), int(i[3:5])
        assert abs((c + 1) * tf.square_m - mx) < tf.square_m and abs((r + 1) * tf.square_m - my) < tf.square_m


def test_border_and_homography_rejections():
    tf = TargetField(diameter_m=0.9, square_m=0.08, marker_m=0.06)
    img, pad = _printed(tf)
    full = CharucoFieldDetector(tf).detect(img)
    cut = img[:, : img.shape[1] // 2 + 20]  # cuts through a column of squares
    det = CharucoFieldDetector(tf).detect(cut)
    assert 0 < len(det.ids) < len(full.ids)
    assert det.xy[:, 0].max() < cut.shape[1] - 4
    ref = dict(zip(full.ids, full.xy))
    assert max(np.abs(ref[i] - p).max() for i, p in zip(det.ids, det.xy)) < 0.05
    # a corner moved by 5 px (tolerance 0.04 square = 3.2 px) is caught by its neighbours' homography, the others
    # are not
    d = CharucoFieldDetector(tf)
    cids = np.array(sorted(d.target_of_corner))
    k2 = {v: k for k, v in d.target_of_corner.items()}
    xy = np.array([ref[d.target_of_corner[k]] for k in cids])
    j = int(np.nonzero(cids == k2["C0405"])[0][0])
    xy[j] += [5.0, -2.0]
    from dgcal.calib.selfcal.detection import fit_homography
    H = [fit_homography(np.array([d.corner_board_xy[k] for k in cids]), xy)] * len(cids)
    bad = d._homography_outliers(cids, xy, np.full(len(cids), 80.0), H)
    assert bad[j] and bad.sum() == 1


@pytest.mark.parametrize("sigma", [1.0, 3.0, 6.0])
def test_noise_estimate_on_a_textured_image(sigma):
    from dgcal.calib.selfcal.detection import estimate_noise
    tf = TargetField(diameter_m=0.9, square_m=0.08, marker_m=0.06)
    clean = print_raster(tf, 25.4).astype(float) * 0.7 + 40  # strong edges over much of the image
    rng = np.random.default_rng(1)
    img = np.clip(np.rint(clean + rng.normal(0, sigma, clean.shape)), 0, 255).astype(np.uint8)
    assert abs(estimate_noise(img) / sigma - 1) < 0.15
