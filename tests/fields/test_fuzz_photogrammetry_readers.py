"""Mutated BINGO, Pix4D GCP and marks, Metashape markers, COLMAP images.txt, DJI JPEG and centres files: a
result with sound numbers (finite where the valid file has them, |x| < 1e12) or one InputError line naming the
file, never a crash or a hang (10 s)."""
from __future__ import annotations

import signal

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from test_bingo_metashape import METASHAPE, PIX_MM, H, W, pix4d_bingo_text, truth
from test_colmap_tracks import write_text_model
from test_dji_images import jpeg_with, xmp_payload
from test_fuzz_readers import DEFAULT_CASES, LONG_CASES, OPS, mutate
from test_pix4d_companions import GCPS, MARKS

from dgcal.fields.errors import InputError
from dgcal.fields.io.bingo import read_bingo
from dgcal.fields.io.centres import read_centres
from dgcal.fields.io.colmap_tracks import read_colmap_tracks
from dgcal.fields.io.dji_images import read_dji_photo
from dgcal.fields.io.metashape_markers import read_metashape_markers
from dgcal.fields.io.pix4d_marks import read_pix4d_gcps, read_pix4d_marks


def _colmap(tmp):
    write_text_model(tmp, np.random.default_rng(0), n_img=3, n_pts=8)
    return (tmp / "images.txt").read_bytes(), "images.txt", read_colmap_tracks


READERS = {
    "bingo": lambda tmp: (pix4d_bingo_text(truth(n_img=2, n_pts=3)).encode(), "b.txt",
                          lambda p: read_bingo(p, (W, H), PIX_MM)),
    "metashape-markers": lambda tmp: (METASHAPE.encode(), "markers.xml", read_metashape_markers),
    "colmap-images-txt": _colmap,
    "pix4d-gcps": lambda tmp: (GCPS.encode(), "gcps.txt", read_pix4d_gcps),
    "pix4d-marks": lambda tmp: (MARKS.encode(), "marks.csv", read_pix4d_marks),
    "dji-jpeg": lambda tmp: (jpeg_with([xmp_payload()]), "DJI_0001.JPG", read_dji_photo),
    "centres-csv": lambda tmp: (b"image,X,Y,Z,omega,phi,kappa,sX,sY,sZ\nDJI_0001.JPG,500100.1,2519800.2,140.1,,,,"
                                b"0.02,0.02,0.05\nDJI_0002.JPG,500110.1,2519800.2,140.3,1,2,3,0.02,0.02,0.05\n",
                                "centres.csv", read_centres),
}


HANG_S = 10.0
MAX_ABS = 1e12
# result fields that may hold NaN (not given) in a valid file, and those that never may
OPTIONAL = ("sigma", "opk", "_sigma")
REQUIRED = ("xy", "xyz", "lat", "lon", "h")


def _alarm(signum, frame):
    raise TimeoutError(f"no result after {HANG_S:g} s")


def _check(reader, p, data: bytes) -> None:
    """Write `data` to `p` and read it: within HANG_S, one InputError line naming the file, or sound numbers."""
    p.write_bytes(data)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    try:
        result = reader(p)
    except InputError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.strip(), repr(msg)
        assert str(p) in msg or p.name in msg or str(p.parent) in msg, msg
        return
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    for name in REQUIRED + OPTIONAL:
        v = getattr(result, name, None)
        if v is None:
            continue
        a = np.asarray(v, float)
        finite = a[np.isfinite(a)]
        assert name in OPTIONAL or np.isfinite(a).all(), f"{name}: non-finite value accepted"
        assert not finite.size or np.abs(finite).max() < MAX_ABS, f"{name}: absurd value accepted"


def _fuzz(name, tmp_path_factory, n):
    tmp = tmp_path_factory.mktemp(name)
    sample, fname, reader = READERS[name](tmp)
    p = tmp / fname
    p.write_bytes(sample)
    reader(p)                          # the valid sample reads

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(OPS)
    def run(ops):
        _check(reader, p, mutate(sample, ops))
    run()


@pytest.mark.parametrize("name", sorted(READERS))
def test_photogrammetry_reader_fuzz(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, DEFAULT_CASES)


@pytest.mark.fuzz
@pytest.mark.parametrize("name", sorted(READERS))
def test_photogrammetry_reader_fuzz_long(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, LONG_CASES)
