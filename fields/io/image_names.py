"""Image labels of other programs' files -> the image file names dgcal uses (a map, or the file stem)."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Mapping, Sequence

from dgcal.fields.errors import InputError


def image_namer(image_names: Mapping[str, str] | Sequence[str] | None, path: Path | None,
                field: str = "image") -> Callable[[str, int | None], str]:
    """A function (label, file line) -> image name: through a map (`{label: name}`), by exact name or file
    stem among `image_names` (Pix4D and Metashape label `DJI_0001.JPG` as `DJI_0001`), or the label itself
    (`image_names` None). An unknown label is an InputError naming the file line."""
    if image_names is None:
        return lambda label, line: label
    if isinstance(image_names, Mapping):
        table = {str(k): str(v) for k, v in image_names.items()}

        def by_map(label: str, line: int | None) -> str:
            if label not in table:
                raise InputError(f"image {label!r} is not in the image map", path, line, field)
            return table[label]
        return by_map
    names = [str(n) for n in image_names]
    exact = set(names)
    stems: dict[str, str] = {}
    for n in names:
        stems.setdefault(Path(n).stem, n)

    def by_stem(label: str, line: int | None) -> str:
        if label in exact:
            return label
        if label in stems:
            return stems[label]
        if Path(label).stem in stems:
            return stems[Path(label).stem]
        raise InputError(f"image {label!r} matches none of the {len(names)} image names", path, line, field)
    return by_stem
