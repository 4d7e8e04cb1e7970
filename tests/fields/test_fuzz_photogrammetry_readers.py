"""Mutated BINGO, Pix4D GCP and marks, Metashape markers, COLMAP images.txt, DJI JPEG and centres files: a
result with sound numbers or one InputError line naming the file, never a crash or a hang
(tests/fields/fuzz_checks.py)."""
from __future__ import annotations

import numpy as np
import pytest
from fuzz_checks import FuzzStats, check_read, nan_fields
from hypothesis import HealthCheck, given, settings
from test_bingo_metashape import METASHAPE, PIX_MM, H, W, pix4d_bingo_text, truth
from test_colmap_tracks import write_text_model
from test_dji_images import jpeg_with, xmp_payload
from test_fuzz_readers import DEFAULT_CASES, LONG_CASES, OPS, mutate
from test_pix4d_companions import GCPS, MARKS

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


def _fuzz(name, tmp_path_factory, n):
    tmp = tmp_path_factory.mktemp(name)
    sample, fname, reader = READERS[name](tmp)
    p = tmp / fname
    p.write_bytes(sample)
    allowed_nan = nan_fields(reader(p))
    stats = FuzzStats(name)

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(OPS)
    def run(ops):
        check_read(reader, p, mutate(sample, ops), stats, allowed_nan, names=("points3D", "images.txt"))
    try:
        run()
    finally:
        stats.record()


@pytest.mark.parametrize("name", sorted(READERS))
def test_photogrammetry_reader_fuzz(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, DEFAULT_CASES)


@pytest.mark.fuzz
@pytest.mark.parametrize("name", sorted(READERS))
def test_photogrammetry_reader_fuzz_long(name, tmp_path_factory):
    _fuzz(name, tmp_path_factory, LONG_CASES)
