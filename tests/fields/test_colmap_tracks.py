"""A COLMAP model as tie points: text files written as COLMAP documents them, binary ones written by pycolmap."""
import numpy as np
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.colmap_tracks import colmap_model_files, read_colmap_tracks


def write_text_model(folder, rng, n_img=4, n_pts=30, w=640, h=480):
    """cameras/images/points3D.txt; returns {(image, point id): COLMAP xy}."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(f"# Camera list\n1 SIMPLE_PINHOLE {w} {h} 500 {w / 2} {h / 2}\n")
    obs = {}
    tracks = {k: [] for k in range(1, n_pts + 1)}
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i in range(1, n_img + 1):
        name = f"DJI_{i:04d}.JPG"
        lines.append(f"{i} 1 0 0 0 {i * 0.5} 0 0 1 {name}")
        feats = []
        for k in range(1, n_pts + 1):
            if rng.random() < 0.7 or k <= 2:
                x, y = rng.uniform(0, w), rng.uniform(0, h)
                tracks[k].append((i, len(feats)))
                feats.append(f"{x:.6f} {y:.6f} {k}")
                obs[(name, k)] = (float(f"{x:.6f}"), float(f"{y:.6f}"))
        feats.append(f"{rng.uniform(0, w):.3f} {rng.uniform(0, h):.3f} -1")     # a feature without a 3-D point
        lines.append(" ".join(feats))
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    pts = ["# 3D point list"]
    for k, tr in tracks.items():
        if tr:
            pts.append(f"{k} {rng.normal():.3f} {rng.normal():.3f} {5 + rng.normal():.3f} 128 128 128 0.5 "
                       + " ".join(f"{a} {b}" for a, b in tr))
    (folder / "points3D.txt").write_text("\n".join(pts) + "\n")
    return obs


def test_text_and_binary_models_give_the_same_tracks_shifted_half_a_pixel(tmp_path):
    obs = write_text_model(tmp_path / "txt", np.random.default_rng(5))
    m = read_colmap_tracks(tmp_path / "txt")
    counts = {}
    for (_name, k) in obs:
        counts[k] = counts.get(k, 0) + 1
    want = {(n, f"colmap_{k}"): xy for (n, k), xy in obs.items() if counts[k] >= 2}
    got = {(a, b): tuple(xy) for a, b, xy in zip(m.image, m.id, m.xy)}
    assert set(got) == set(want)
    assert max(abs(got[key][j] - (want[key][j] - 0.5)) for key in want for j in (0, 1)) < 1e-9
    assert m.lines.min() >= 5 and m.lines.max() % 2 == 1          # the POINTS2D lines of images.txt
    pycolmap = pytest.importorskip("pycolmap")
    rec = pycolmap.Reconstruction(str(tmp_path / "txt"))
    (tmp_path / "bin").mkdir()
    rec.write_binary(str(tmp_path / "bin"))
    assert colmap_model_files(tmp_path / "bin") == (tmp_path / "bin", "bin")
    mb = read_colmap_tracks(tmp_path / "bin")
    gotb = {(a, b): tuple(xy) for a, b, xy in zip(mb.image, mb.id, mb.xy)}
    assert set(gotb) == set(want) and max(abs(gotb[k][j] - got[k][j]) for k in got for j in (0, 1)) < 1e-6
    assert len(read_colmap_tracks(tmp_path / "txt", min_track_length=4)) < len(m)


def test_colmap_principal_point_default_is_the_image_centre_in_corner_origin():
    """COLMAP's default principal point is (w/2, h/2): its pixel origin is the image's corner (dgcal: -0.5)."""
    pycolmap = pytest.importorskip("pycolmap")
    cam = pycolmap.Camera.create_from_model_name(1, "SIMPLE_PINHOLE", 100.0, 100, 80)
    assert np.allclose(cam.img_from_cam(np.array([[0.0, 0.0, 1.0]])), [[50.0, 40.0]])


@pytest.mark.parametrize("old, new, field", [
    ("1 1 0 0 0 0.5 0 0 1 DJI_0001.JPG", "1 1 0 0 0 0.5 0 0 1", "NAME"),
    (" 1 ", " 1 7 ", "POINTS2D"),
    (" 2 ", " x ", "POINTS2D"),
])
def test_errors_name_the_line(tmp_path, old, new, field):
    write_text_model(tmp_path, np.random.default_rng(1))
    p = tmp_path / "images.txt"
    lines = p.read_text().splitlines()
    target = 3 if field == "NAME" else 4
    lines[target] = lines[target].replace(old, new, 1)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as exc:
        read_colmap_tracks(tmp_path)
    assert f"images.txt:{target + 1}:" in str(exc.value) and f"field '{field}'" in str(exc.value)


def test_not_a_model(tmp_path):
    with pytest.raises(InputError, match="not a COLMAP model"):
        read_colmap_tracks(tmp_path)
