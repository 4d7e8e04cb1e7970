"""GNSS files as archives serve them (`pos/gnss/gnss_files.py`): Hatanaka-compressed observations (CRINEX) inside
gzip, Unix compress (.Z), bzip2 or zip read to the same epochs as the plain RINEX; containers told by their bytes,
not their names; broken archives refused naming the file; RTKLIB's peer gets plain copies."""
from __future__ import annotations

import bz2
import gzip
import zipfile
from pathlib import Path

import hatanaka
import ncompress
import numpy as np
import pytest

from dgcal.cli import main
from dgcal.fields.errors import InputError
from dgcal.pos.gnss.gnss_files import container_of, first_gnss_line, read_gnss_lines
from dgcal.pos.gnss.precise import product_kind
from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs

DATA = Path(__file__).parent / "data"
OBS = "rinex-sept/SEPT078M1.21O"
NAV = "rinex-sept/SEPT078M.21P"


def _pack(data: bytes, kind: str, path):
    if kind == "gz":
        path.write_bytes(gzip.compress(data))
    elif kind == "Z":
        path.write_bytes(ncompress.compress(data))
    elif kind == "bz2":
        path.write_bytes(bz2.compress(data))
    elif kind == "zip":
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr(path.stem, data)
    else:
        path.write_bytes(data)
    return path


@pytest.fixture(scope="module")
def plain(shared_data):
    return (shared_data / OBS).read_bytes()


@pytest.mark.parametrize("kind", ["plain", "gz", "Z", "bz2", "zip"])
def test_hatanaka_observations_in_every_container_read_as_the_plain_file(shared_data, plain, tmp_path, kind):
    crx = hatanaka.rnx2crx(plain)
    assert crx[:80].decode().find("CRINEX VERS") >= 0
    path = _pack(crx, kind, tmp_path / f"SEPT078M1.21d{'' if kind == 'plain' else '.' + kind}")
    ref = read_rinex_obs(shared_data / OBS)
    got = read_rinex_obs(path)
    assert len(got.epochs) == len(ref.epochs) == 60
    for a, b in zip(ref.epochs, got.epochs):
        assert a.t_gps == b.t_gps and a.sat == b.sat
        np.testing.assert_array_equal(a.pr_m, b.pr_m)


@pytest.mark.parametrize("kind", ["gz", "Z", "bz2", "zip"])
def test_containers_by_content_not_name(shared_data, plain, tmp_path, kind):
    """A `.Z` name on a gzip file and a `.gz` name on an LZW one: the bytes decide."""
    wrong = {"gz": "Z", "Z": "gz", "bz2": "gz", "zip": "Z"}[kind]
    path = _pack(plain, kind, tmp_path / f"SEPT078M1.21o.{wrong}")
    assert read_gnss_lines(path) == plain.decode("ascii").splitlines()
    assert first_gnss_line(path).startswith("     3.04") and container_of(path.read_bytes()[:4]) == \
        {"gz": "gzip", "Z": "lzw", "bz2": "bzip2", "zip": "zip"}[kind]


def test_compressed_navigation_and_products_are_recognised(shared_data, tmp_path):
    """A `.Z` navigation file and a `.Z` SP3 (as CDDIS served them) are told apart by content and read."""
    nav = _pack((shared_data / NAV).read_bytes(), "Z", tmp_path / "SEPT078M.21P.Z")
    assert product_kind(nav) == "nav"
    assert len(read_rinex_nav(nav).eph) == len(read_rinex_nav(shared_data / NAV).eph) > 0
    sp3 = _pack(gzip.decompress((DATA / "COD0MGXFIN_20210781100_02H_05M_ORB.SP3.gz").read_bytes()), "Z",
                tmp_path / "COD0MGXFIN_20210781100_02H_05M_ORB.SP3.Z")
    assert product_kind(sp3) == "sp3"


def test_broken_archives_and_crinex_are_refused_naming_the_file(plain, tmp_path):
    trunc = tmp_path / "cut.21o.gz"
    trunc.write_bytes(gzip.compress(plain)[:200])
    with pytest.raises(InputError, match="cannot decompress the gzip file") as e:
        read_gnss_lines(trunc)
    assert str(trunc) in str(e.value)
    two = tmp_path / "two.zip"
    with zipfile.ZipFile(two, "w") as zf:
        zf.writestr("a.21o", plain)
        zf.writestr("b.21o", plain)
    with pytest.raises(InputError, match="exactly one file"):
        read_gnss_lines(two)
    bad = tmp_path / "bad.21d"
    crx = hatanaka.rnx2crx(plain).splitlines(keepends=True)
    bad.write_bytes(b"".join(crx[:40] + [b"&garbage that is not a compact epoch line\n"] + crx[60:]))
    with pytest.raises(InputError) as e:
        read_rinex_obs(bad)
    assert str(bad) in str(e.value)
    assert first_gnss_line(tmp_path / "missing.21o") == ""


def test_spp_from_a_hatanaka_gzip_observation_file(shared_data, plain, tmp_path):
    """What a CORS archive serves (`.crx.gz`) goes straight into `dgcal pos`."""
    obs = _pack(hatanaka.rnx2crx(plain), "gz", tmp_path / "SEPT00XXX_R_20210781200_01M_01S_MO.crx.gz")
    nav = _pack((shared_data / NAV).read_bytes(), "Z", tmp_path / "SEPT078M.21P.Z")
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(obs), "--rinex-nav", str(nav), "--no-progress",
                 "--no-report", "--out", str(tmp_path / "o")]) == 0
    assert main(["pos", "--mode", "spp", "--rinex-obs", str(shared_data / OBS), "--rinex-nav",
                 str(shared_data / NAV), "--no-progress", "--no-report", "--out", str(tmp_path / "p")]) == 0
    assert (tmp_path / "o" / "gnss.csv").read_text() == (tmp_path / "p" / "gnss.csv").read_text()
