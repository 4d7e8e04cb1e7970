"""One image-folder lister for every verb (`fields/io/image_folders.py`): suffixes, order, raw files and the error
that names the folder and the option's field (the CLI
shows its flag: `tests/pos/ins/test_mrk_pairing.py`)."""
from __future__ import annotations

import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.image_folders import list_image_files, list_image_names


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "imgs"
    d.mkdir()
    for n in ("b.JPG", "a.png", "c.tif", "d.DNG", "notes.txt", "e.pgm"):
        (d / n).write_bytes(b"x")
    (d / "sub.jpg").mkdir()            # a folder named like an image is not an image
    return d


def test_sorted_by_name_suffix_case_insensitive_raw_on_request(folder):
    assert list_image_names(folder) == ["a.png", "b.JPG", "c.tif", "e.pgm"]
    assert list_image_names(folder, raw=True) == ["a.png", "b.JPG", "c.tif", "d.DNG", "e.pgm"]
    assert [p.parent for p in list_image_files(folder)] == [folder] * 4


@pytest.mark.parametrize("kind", ["missing", "file", "empty"])
def test_error_names_the_folder_and_the_field(tmp_path, kind):
    target = tmp_path / "x"
    if kind == "file":
        target.write_text("a")
    elif kind == "empty":
        target.mkdir()
        (target / "readme.txt").write_text("a")
    with pytest.raises(InputError) as e:
        list_image_names(target, "event_images")
    assert str(target) in str(e.value) and "event_images" in str(e.value)
    assert {"missing": "does not exist", "file": "not a folder", "empty": "no images"}[kind] in str(e.value)
