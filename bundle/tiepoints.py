"""Tie points with pycolmap: SIFT features, matching of overlapping pairs, geometric verification, tracks.

Pixels: COLMAP puts the origin at the top-left pixel's corner (its centre is (0.5, 0.5)); dgcal at the
centre of that pixel. Keypoints are shifted by -0.5 px here, at the boundary, and nowhere else.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Measurements

COLMAP_PIXEL_SHIFT = 0.5
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")


def list_images(folder: str | Path) -> list[str]:
    """Image file names (sorted) in a folder; InputError when there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("image folder not found", folder, field="--images")
    names = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
    if not names:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in the folder", folder, field="--images")
    return names


def spatial_pairs(names: list[str], centres: np.ndarray, footprint_m: float | np.ndarray,
                  max_neighbours: int = 20) -> list[tuple[str, str]]:
    """Image pairs whose approximate centres (m) lie closer than their footprint size: the overlapping ones."""
    c = np.asarray(centres, float)
    fp = np.broadcast_to(np.asarray(footprint_m, float), (len(c),))
    d = np.linalg.norm(c[:, None, :2] - c[None, :, :2], axis=2)
    pairs = set()
    for i in range(len(c)):
        order = np.argsort(d[i])
        for j in order[1:max_neighbours + 1]:
            if d[i, j] < 0.5 * (fp[i] + fp[j]):
                pairs.add((min(i, j), max(i, j)))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def sequential_pairs(names: list[str], overlap: int = 8) -> list[tuple[str, str]]:
    """Pairs of each image with its `overlap` successors (exhaustive when there are few images)."""
    n = len(names)
    if n <= overlap + 1:
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    return [(names[i], names[j]) for i in range(n) for j in range(i + 1, min(n, i + 1 + overlap))]


def extract_tie_points(image_dir: str | Path, names: list[str] | None = None,
                       pairs: list[tuple[str, str]] | None = None, max_features: int = 4000,
                       min_track: int = 2, camera_K: np.ndarray | None = None, prefix: str = "tie_",
                       workdir: str | Path | None = None, num_threads: int = 2) -> Measurements:
    """Tie-point measurements (px, OpenCV convention) from SIFT tracks across `pairs` (default sequential).

    Each verified track (no two features in one image) of length >= `min_track` becomes a point id
    `prefix + n`; every observation's sigma is left NaN (the caller's default applies).
    """
    import pycolmap   # deferred: a module-level pycolmap import gave an import-order heap corruption
    pycolmap.logging.minloglevel = 1   # COLMAP's per-image INFO lines would drown the command's output
    image_dir = Path(image_dir)
    names = list(names) if names is not None else list_images(image_dir)
    missing = [n for n in names if not (image_dir / n).is_file()]
    if missing:
        raise InputError(f"image {missing[0]} not found" + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
                         image_dir, field="--images")
    pairs = pairs if pairs is not None else sequential_pairs(names)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        db_path = Path(tmp) / "db.sqlite"
        ext = pycolmap.FeatureExtractionOptions()
        ext.sift.max_num_features = int(max_features)
        ext.sift.first_octave = 0          # no 2x upsampling: 4x faster, and aerial images have texture to spare
        ext.num_threads = num_threads
        ext.use_gpu = False
        reader = pycolmap.ImageReaderOptions()
        if camera_K is not None:
            K = np.asarray(camera_K, float)
            reader.camera_model = "PINHOLE"
            reader.camera_params = ",".join(str(v) for v in (K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_SHIFT,
                                                            K[1, 2] + COLMAP_PIXEL_SHIFT))
        pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
        pairs_path = Path(tmp) / "pairs.txt"
        pairs_path.write_text("".join(f"{a} {b}\n" for a, b in pairs))
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = num_threads
        mopt.use_gpu = False
        popt = pycolmap.ImportedPairingOptions()
        popt.match_list_path = str(pairs_path)
        pycolmap.match_image_pairs(db_path, matching_options=mopt, pairing_options=popt, device=pycolmap.Device.cpu)
        with pycolmap.Database.open(db_path) as db:
            id_to_name = {im.image_id: im.name for im in db.read_all_images()}
            kps = {iid: np.asarray(db.read_keypoints(iid))[:, :2] - COLMAP_PIXEL_SHIFT for iid in id_to_name}
            pair_ids, tvgs = db.read_two_view_geometries()
            matches = []
            for pid, tvg in zip(pair_ids, tvgs):
                inl = np.asarray(tvg.inlier_matches)
                if len(inl) == 0:
                    continue
                i1, i2 = pycolmap.pair_id_to_image_pair(pid)
                matches.append((i1, i2, inl))
    return _tracks(id_to_name, kps, matches, min_track, prefix)


def _tracks(id_to_name: dict, kps: dict, matches: list, min_track: int, prefix: str) -> Measurements:
    """Union-find of verified matches into tracks; tracks seeing one image twice are dropped."""
    ids = sorted(kps)
    offset, total = {}, 0
    for iid in ids:
        offset[iid] = total
        total += len(kps[iid])
    parent = np.arange(total)

    def find(a):
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    for i1, i2, inl in matches:
        for a, b in zip(inl[:, 0] + offset[i1], inl[:, 1] + offset[i2]):
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    node_image = np.concatenate([np.full(len(kps[i]), i) for i in ids]) if ids else np.zeros(0, int)
    node_xy = np.concatenate([kps[i] for i in ids]) if ids else np.zeros((0, 2))
    matched = np.zeros(total, bool)
    for i1, i2, inl in matches:
        matched[inl[:, 0] + offset[i1]] = True
        matched[inl[:, 1] + offset[i2]] = True
    nodes = np.nonzero(matched)[0]
    roots = np.array([find(a) for a in nodes], int)
    order = np.argsort(roots, kind="stable")
    nodes, roots = nodes[order], roots[order]
    uniq, start, count = np.unique(roots, return_index=True, return_counts=True)
    img, pid, xy = [], [], []
    n = 0
    for s, c in zip(start, count):
        if c < min_track:
            continue
        nn = nodes[s:s + c]
        ims = node_image[nn]
        if len(np.unique(ims)) != len(ims):
            continue   # inconsistent track: one image twice
        name = f"{prefix}{n}"
        n += 1
        for a in nn:
            img.append(id_to_name[node_image[a]]); pid.append(name); xy.append(node_xy[a])
    return Measurements(np.array(img, dtype=object), np.array(pid, dtype=object), np.array(xy).reshape(-1, 2),
                        np.full((len(img), 2), np.nan))
