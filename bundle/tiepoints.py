"""Tie points with pycolmap: SIFT features, matching of overlapping pairs, geometric verification, tracks.

Pixels: COLMAP puts the origin at the top-left pixel's corner (its centre is (0.5, 0.5)); dgcal at the
centre of that pixel. Keypoints are shifted by -0.5 px here, at the boundary, and nowhere else.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import Measurements
from dgcal.fields.io.image_folders import list_image_names

COLMAP_PIXEL_SHIFT = 0.5
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
                       workdir: str | Path | None = None, num_threads: int = 2,
                       stats: dict | None = None) -> Measurements:
    """Tie-point measurements (px, OpenCV convention) from SIFT tracks across `pairs` (default sequential).

    Each verified track (no two features in one image) of length >= `min_track` becomes a point id
    `prefix + n`; every observation's sigma is left NaN (the caller's default applies). `stats`, when given,
    receives the counts (features, pairs, verified pairs, matches, tracks) and stage times (s).
    """
    import pycolmap   # deferred: a module-level pycolmap import gave an import-order heap corruption
    pycolmap.logging.minloglevel = 1   # COLMAP's per-image INFO lines would drown the command's output
    image_dir = Path(image_dir)
    names = list(names) if names is not None else list_image_names(image_dir)
    missing = [n for n in names if not (image_dir / n).is_file()]
    if missing:
        raise InputError(f"image {missing[0]} not found"
                         + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
                         image_dir, field="images")
    pairs = pairs if pairs is not None else sequential_pairs(names)
    t_start = time.perf_counter()
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
        t_matched = time.perf_counter()
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
    tracks = _tracks(id_to_name, kps, matches, min_track, prefix)
    if stats is not None:
        stats.update({"n_images": len(names), "n_features": int(sum(len(k) for k in kps.values())),
                      "n_pairs": len(pairs), "n_verified_pairs": len(matches),
                      "n_matches": int(sum(len(m[2]) for m in matches)), "n_tracks": len(set(tracks.id)),
                      "n_observations": len(tracks), "seconds_extract_match": round(t_matched - t_start, 3),
                      "seconds_tracks": round(time.perf_counter() - t_matched, 3)})
    return tracks


def _tracks(id_to_name: dict, kps: dict, matches: list, min_track: int, prefix: str) -> Measurements:
    """Tracks: connected components of the verified matches (keypoints as nodes); tracks that see one image
    twice are dropped. Vectorised (scipy's connected components), no loop over matches."""
    ids = sorted(kps)
    sizes = np.array([len(kps[i]) for i in ids], int)
    offset = dict(zip(ids, np.concatenate([[0], np.cumsum(sizes)[:-1]]) if ids else []))
    total = int(sizes.sum())
    if not matches or total == 0:
        return Measurements(np.array([], dtype=object), np.array([], dtype=object), np.zeros((0, 2)),
                            np.zeros((0, 2)))
    a = np.concatenate([inl[:, 0] + offset[i1] for i1, i2, inl in matches])
    b = np.concatenate([inl[:, 1] + offset[i2] for i1, i2, inl in matches])
    graph = sp.coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(total, total))
    _, label = connected_components(graph, directed=False)
    node_image = np.repeat(np.arange(len(ids)), sizes)
    node_xy = np.concatenate([kps[i] for i in ids])
    matched = np.zeros(total, bool)
    matched[a] = matched[b] = True
    nodes = np.flatnonzero(matched)
    lab = label[nodes]
    order = np.lexsort((node_image[nodes], lab))
    nodes, lab = nodes[order], lab[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    counts = np.diff(np.r_[starts, len(lab)])
    im_sorted = node_image[nodes]
    # one image twice in a track: its sorted images repeat
    dup = np.r_[False, (lab[1:] == lab[:-1]) & (im_sorted[1:] == im_sorted[:-1])]
    bad_track = np.zeros(len(starts), bool)
    np.logical_or.at(bad_track, np.searchsorted(starts, np.flatnonzero(dup), side="right") - 1, True)
    good = (counts >= min_track) & ~bad_track
    keep = np.repeat(good, counts)
    track_no = np.repeat(np.cumsum(good) - 1, counts)[keep]
    names = np.array([id_to_name[i] for i in ids], dtype=object)
    sel = nodes[keep]
    pid = np.array([f"{prefix}{k}" for k in range(int(good.sum()))], dtype=object)[track_no]
    return Measurements(names[node_image[sel]], pid, node_xy[sel].reshape(-1, 2), np.full((len(sel), 2), np.nan))
