"""Photos and video frames to detect targets in, and the choice of frames from videos.

Sources (`--images`): folders of photos (JPEG, PNG, TIFF, BMP, ...), single photo files and video files (read
with cv2.VideoCapture, every frame or, for long videos, every k-th so that at most `max_candidates` are looked at).
A frame's label (the `image` of the measurements) is its file name, or `<video file name>#<frame number>` (frame
numbers from 0) for video frames.

Frame choice for videos (photos are all kept): among the frames where the target was detected with enough
corners,

1. sharpness: the standard deviation of the Laplacian over the detected corners' bounding box, divided by the
   standard deviation of the grey values there (so lighting does not matter); frames below `blur_fraction` of the
   median sharpness are left out as blurred (motion blur);
2. no repeats: a frame whose corners lie within `duplicate_px` (default 0.5 px: the board did not move; median over
   the corners both share, sharing
   at least 80 % of them) of an already chosen frame's adds no geometry, only noise correlated with that frame's
   (a board held still), and is left out;
3. coverage diversity: frames are chosen greedily, each time the one that adds most new coverage (cells of a
   12 x 8 grid over the frame reached by its corners, counted once per board orientation class: the tilt
   direction of the board's plane, 9 classes) with sharpness as tie break, up to `max_frames`.

Every candidate is listed with its sharpness, corner count and the reason it was chosen or not
(`FrameChoice.rows`).
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np
from tqdm import tqdm

from dgcal.calib.selfcal.detection import Detection, read_gray
from dgcal.fields.io.image_folders import RASTER_SUFFIXES
from dgcal.fields.errors import InputError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv", ".mts", ".m2ts")


@dataclass
class Source:
    """One input: a photo file or a video file (kind 'image' or 'video')."""

    path: Path
    kind: str


def expand_sources(paths) -> list[Source]:
    """The photos and videos named by `paths` (folders are expanded to their photos and videos, sorted);
    InputError naming a path that is missing, unsupported or holds nothing to read."""
    out: list[Source] = []
    for p in ([paths] if isinstance(paths, (str, Path)) else list(paths)):
        p = Path(p)
        if p.is_dir():
            known = RASTER_SUFFIXES + VIDEO_SUFFIXES
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in known)
            if not found:
                raise InputError(f"no images ({', '.join(RASTER_SUFFIXES)}) or videos in the folder", p)
            out += [Source(q, "video" if q.suffix.lower() in VIDEO_SUFFIXES else "image") for q in found]
        elif p.is_file():
            suf = p.suffix.lower()
            if suf in VIDEO_SUFFIXES:
                out.append(Source(p, "video"))
            elif suf in RASTER_SUFFIXES:
                out.append(Source(p, "image"))
            else:
                raise InputError(f"not an image or video file (suffixes {', '.join(RASTER_SUFFIXES + VIDEO_SUFFIXES)})",
                                 p)
        else:
            raise InputError("image folder, image or video file not found", p)
    return out


def open_video(path: Path) -> tuple[cv2.VideoCapture, int, float]:
    """An opened cv2.VideoCapture, its frame count (-1 when unknown) and frame rate (0 when unknown); InputError
    naming the file when it cannot be opened or holds no readable frame."""
    # FFmpeg's own messages would add lines to dgcal's one-line errors: quiet unless the user asks for them
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise InputError("cannot open the video (missing, corrupt or a codec OpenCV's video backend lacks)", path)
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or -1)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    return cap, n, fps


def video_frames(path: Path, max_candidates: int = 400) -> Iterator[tuple[int, float, np.ndarray]]:
    """(frame number, time s, grey uint8 image) of a video's frames, every k-th so at most ~max_candidates."""
    cap, n, fps = open_video(path)
    step = max(1, math.ceil(n / max_candidates)) if n > 0 else 1
    got = 0
    k = 0
    try:
        while True:
            if k % step:
                if not cap.grab():
                    break
                k += 1
                continue
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            got += 1
            gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            yield k, (k / fps if fps > 0 else float("nan")), gray
            k += 1
    finally:
        cap.release()
    if got == 0:
        raise InputError("the video opened but no frame could be decoded", path)


def sharpness(gray: np.ndarray, xy: np.ndarray) -> float:
    """Std of the Laplacian over the corners' bounding box (10 % margin) / std of the grey values there."""
    if len(xy) == 0:
        return 0.0
    h, w = gray.shape[:2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    m = 0.1 * (hi - lo) + 4
    x0, y0 = int(max(0, lo[0] - m[0])), int(max(0, lo[1] - m[1]))
    x1, y1 = int(min(w, hi[0] + m[0] + 1)), int(min(h, hi[1] + m[1] + 1))
    patch = gray[y0:y1, x0:x1].astype(np.float32)
    if patch.size < 16:
        return 0.0
    lap = cv2.Laplacian(patch, cv2.CV_32F, ksize=3)
    return float(lap.std() / max(float(patch.std()), 1.0))


@dataclass
class Candidate:
    """A frame the target was looked for in: label, source, frame number and time, detection, sharpness."""

    label: str
    source: Path
    frame: int | None
    time_s: float
    detection: Detection
    sharpness: float
    status: str = ""


@dataclass
class FrameChoice:
    """The candidates (all frames looked at) and which were chosen."""

    candidates: list[Candidate] = field(default_factory=list)

    @property
    def chosen(self) -> list[Candidate]:
        return [c for c in self.candidates if c.status == "chosen"]

    def rows(self) -> list[list]:
        """Table rows: label, source, frame, time_s, corners, sharpness, status."""
        return [[c.label, c.source.name, "" if c.frame is None else c.frame,
                 "" if not math.isfinite(c.time_s) else round(c.time_s, 4), int(len(c.detection.ids)),
                 round(c.sharpness, 4), c.status] for c in self.candidates]

    def summary(self) -> dict:
        """Counts by status."""
        out: dict[str, int] = {}
        for c in self.candidates:
            key = c.status.split(" (")[0].split(":")[0]
            out[key] = out.get(key, 0) + 1
        return out


def _board_normal_class(det_xy: np.ndarray, board_xy: np.ndarray) -> int:
    """A coarse class (0-8) of the board's tilt seen in a frame: the direction in which the local scale of the
    board-to-image homography changes (foreshortening), or 0 for a fronto-parallel view."""
    if len(det_xy) < 4:
        return 0
    H, _ = cv2.findHomography(board_xy.astype(np.float64), det_xy.astype(np.float64), 0)
    if H is None:
        return 0
    g = H[2, :2] / H[2, 2]                       # perspective row: the scale gradient direction on the board
    ext = np.ptp(board_xy, axis=0).max()
    tilt = np.linalg.norm(g) * ext                # relative scale change across the board
    if tilt < 0.08:
        return 0
    ang = math.atan2(g[1], g[0])
    return 1 + int(((ang + math.pi) / (2 * math.pi) * 8) % 8)


def choose_frames(cands: list[Candidate], image_size: tuple[int, int], board_xy_of: Callable[[np.ndarray], np.ndarray],
                  min_corners: int = 6, max_frames: int = 100, blur_fraction: float = 0.5,
                  duplicate_px: float | None = None, cells: tuple[int, int] = (12, 8)) -> None:
    """Set every video candidate's `status`: chosen, or why not (see the module doc). `board_xy_of(ids)` gives the
    board-plane coordinates (m) of corner ids (for the tilt class)."""
    w, h = image_size
    dup = duplicate_px if duplicate_px is not None else 0.5
    usable = []
    for c in cands:
        if len(c.detection.ids) < min_corners:
            c.status = f"too few corners ({len(c.detection.ids)} < {min_corners})"
        else:
            usable.append(c)
    if not usable:
        return
    med = float(np.median([c.sharpness for c in usable]))
    sharp = []
    for c in usable:
        if c.sharpness < blur_fraction * med:
            c.status = f"blurred (sharpness {c.sharpness:.3g} < {blur_fraction:g} x median {med:.3g})"
        else:
            sharp.append(c)
    # coverage keys of every frame: (cell, tilt class)
    keys = {}
    for c in sharp:
        xy = c.detection.xy
        ix = np.clip((xy[:, 0] / w * cells[0]).astype(int), 0, cells[0] - 1)
        iy = np.clip((xy[:, 1] / h * cells[1]).astype(int), 0, cells[1] - 1)
        cls = _board_normal_class(xy, board_xy_of(c.detection.ids))
        keys[id(c)] = set((iy * cells[0] + ix + cls * cells[0] * cells[1]).tolist())
    chosen: list[Candidate] = []
    covered: set = set()
    left = sorted(sharp, key=lambda c: -c.sharpness)
    while left:
        # repeats of chosen frames first
        rest = []
        for c in left:
            twin = _duplicate_of(c, chosen, dup)
            if twin is not None:
                c.status = f"repeat of {twin.label} (corners within {dup:.1f} px)"
            else:
                rest.append(c)
        left = rest
        if not left:
            break
        if len(chosen) >= max_frames:
            for c in left:
                c.status = f"not needed (max {max_frames} frames)"
            break
        gains = [len(keys[id(c)] - covered) for c in left]
        k = int(np.argmax(gains))  # ties: the sharpest (the list is sorted by sharpness)
        c = left.pop(k)
        c.status = "chosen"
        chosen.append(c)
        covered |= keys[id(c)]


def _duplicate_of(c: Candidate, chosen: list[Candidate], tol_px: float) -> Candidate | None:
    """The chosen frame that `c` repeats (same corners within tol_px, median), if any."""
    ids = c.detection.ids
    pos = {k: i for i, k in enumerate(ids)}
    for o in chosen:
        common = [(pos[k], j) for j, k in enumerate(o.detection.ids) if k in pos]
        if len(common) < 0.8 * max(len(ids), len(o.detection.ids)):
            continue
        a, b = np.array(common).T
        if np.median(np.linalg.norm(c.detection.xy[a] - o.detection.xy[b], axis=1)) < tol_px:
            return o
    return None


def detect_sources(sources: list[Source], detect: Callable[[np.ndarray], Detection], max_candidates: int = 400,
                   progress: bool = False) -> tuple[list[Candidate], tuple[int, int] | None]:
    """Run `detect` on every photo and on the candidate frames of every video; returns the candidates and the
    common image size (None when sizes differ). InputError naming an unreadable photo or video."""
    cands: list[Candidate] = []
    sizes = set()
    bar = tqdm(desc="detect", unit="frame", disable=not progress, file=sys.stderr)
    try:
        for src in sources:
            if src.kind == "image":
                if src.path.stat().st_size == 0:
                    raise InputError("cannot read the image (empty file)", src.path)
                g = read_gray(src.path)
                det = detect(g)
                sizes.add((g.shape[1], g.shape[0]))
                cands.append(Candidate(src.path.name, src.path, None, float("nan"), det, sharpness(g, det.xy)))
                bar.update()
                continue
            for k, t, g in video_frames(src.path, max_candidates):
                det = detect(g)
                sizes.add((g.shape[1], g.shape[0]))
                cands.append(Candidate(f"{src.path.name}#{k:06d}", src.path, k, t, det, sharpness(g, det.xy)))
                bar.update()
    finally:
        bar.close()
    return cands, (sizes.pop() if len(sizes) == 1 else None)
