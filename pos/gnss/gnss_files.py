"""GNSS data files as they come from archives: plain, gzip, Unix compress (.Z), bzip2, zip, and Hatanaka-compressed
RINEX observations (CRINEX, `.crx`/`.YYd`), all read as text.

Why: CORS and IGS archives serve observations as `.crx.gz` / `.YYd.Z` and products as `.Z` or `.gz`; a user should
not have to unpack them by hand. Containers are recognised by their first bytes, not their names (a `.Z` file is LZW,
not gzip); the decompression is the `hatanaka` package's (RNXCMP's crx2rnx, Geospatial Information Authority of
Japan, with Python's and ncompress's decoders). A u-blox UBX log (raw receiver output) is turned into RINEX 3.04 text
by `dgcal.pos.gnss.ubx` when the caller says whether observations or navigation are wanted.
"""
from __future__ import annotations

import bz2
import gzip
import io
import zipfile
import zlib
from pathlib import Path

import hatanaka
import ncompress
import numpy as np

from dgcal.fields.errors import InputError

_GZIP, _LZW, _BZIP2, _ZIP = b"\x1f\x8b", b"\x1f\x9d", b"BZh", b"PK\x03\x04"
UBX_SYNC = b"\xb5\x62"          # a u-blox UBX frame's first two bytes
UBX_SEARCH_BYTES = 65536        # a logger may write NMEA or a partial frame before the first whole UBX frame
CRINEX_MARK = "CRINEX VERS"


def ubx_checksum(frame: np.ndarray) -> tuple[int, int]:
    """UBX 8-bit Fletcher checksum (CK_A, CK_B) of a frame's class, id, length and payload bytes (uint8 array)."""
    b = frame.astype(np.int64)
    ck_b = int(np.dot(np.arange(len(b), 0, -1, dtype=np.int64), b) & 0xFF)
    return int(b.sum() & 0xFF), ck_b


def _valid_frame_at(data: bytes, k: int) -> bool:
    """Whether a whole UBX frame with a correct checksum starts at byte k."""
    if k + 8 > len(data):
        return False
    end = k + 6 + int.from_bytes(data[k + 4:k + 6], "little")
    if end + 2 > len(data):
        return False
    return ubx_checksum(np.frombuffer(data[k + 2:end], dtype=np.uint8)) == (data[end], data[end + 1])


def looks_like_ubx(data: bytes) -> bool:
    """Whether `data` (a file's plain content) is a u-blox UBX log: it starts with a UBX frame, or a whole frame with a
    correct checksum follows within its first `UBX_SEARCH_BYTES` (NMEA sentences or a cut frame before it, as loggers
    write them) and it does not begin as a RINEX file."""
    if data[:2] == UBX_SYNC:
        return True
    if b"RINEX VERSION" in data[:200] or CRINEX_MARK.encode() in data[:200]:
        return False
    k = data.find(UBX_SYNC, 0, UBX_SEARCH_BYTES)
    while 0 <= k < UBX_SEARCH_BYTES:
        if _valid_frame_at(data, k):
            return True
        k = data.find(UBX_SYNC, k + 1, UBX_SEARCH_BYTES)
    return False


def is_ubx_file(path: str | Path) -> bool:
    """Whether the file at `path` (plain or in an archive) is a u-blox UBX log; False when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(UBX_SEARCH_BYTES + 8)
        if container_of(head[:4]) != "plain":
            head = _unpack(Path(path).read_bytes(), container_of(head[:4]), Path(path))[:UBX_SEARCH_BYTES + 8]
    except (OSError, InputError):
        return False
    return looks_like_ubx(head)


def container_of(head: bytes) -> str:
    """The compression of a file from its first bytes: "gzip", "lzw" (Unix compress .Z), "bzip2", "zip" or "plain"."""
    for magic, name in ((_GZIP, "gzip"), (_LZW, "lzw"), (_BZIP2, "bzip2"), (_ZIP, "zip")):
        if head.startswith(magic):
            return name
    return "plain"


def _unpack(data: bytes, kind: str, path: Path) -> bytes:
    try:
        if kind == "gzip":
            return gzip.decompress(data)
        if kind == "lzw":
            return ncompress.decompress(data)
        if kind == "bzip2":
            return bz2.decompress(data)
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            names = [n for n in zf.namelist() if not n.endswith("/")]
            if len(names) != 1:
                raise InputError(f"a zip archive must hold exactly one file, this one holds {len(names)}", path)
            return zf.read(names[0])
    except InputError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, RuntimeError, zlib.error) as exc:
        raise InputError(f"cannot decompress the {kind} file: {exc}", path) from None


def read_gnss_bytes(path: str | Path, kind: str | None = None) -> bytes:
    """The plain content of a GNSS file (RINEX, SP3, clock, ANTEX) whatever its container; a Hatanaka-compressed
    observation file comes back as RINEX, a u-blox UBX log (`looks_like_ubx`) as the RINEX 3.04 observation
    (`kind` "obs") or navigation ("nav") file of its RAWX / SFRBX messages (`dgcal.pos.gnss.ubx`). InputError naming
    the file when it is missing or cannot be decoded."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    data = path.read_bytes()
    container = container_of(data[:4])
    if container != "plain":
        data = _unpack(data, container, path)
    if looks_like_ubx(data[:UBX_SEARCH_BYTES + 8]):
        # why here: ubx writes through pos/gnss/carrier.py, which imports the RINEX readers that call this
        from dgcal.pos.gnss.ubx import ubx_rinex_lines
        return ("\n".join(ubx_rinex_lines(data, path, kind or "")) + "\n").encode("ascii")
    if data[:80].decode("ascii", "replace").find(CRINEX_MARK) >= 0:
        try:
            data = hatanaka.crx2rnx(data)
        except (ValueError, RuntimeError, OSError) as exc:
            raise InputError(f"cannot expand the Hatanaka-compressed RINEX (crx2rnx): {str(exc).strip()}", path) \
                from None
    return data


def read_gnss_lines(path: str | Path, kind: str | None = None) -> list[str]:
    """All lines of a GNSS file (see `read_gnss_bytes`; `kind` "obs"/"nav" says what a UBX log is read for) as ASCII
    text without line ends (bytes that are not ASCII become U+FFFD, for the readers to name)."""
    return read_gnss_bytes(path, kind).decode("ascii", errors="replace").splitlines()


def first_gnss_line(path: str | Path) -> str:
    """The first line of a GNSS file's plain content; '' when it cannot be read (the reader then says why)."""
    try:
        with open(path, "rb") as fh:
            head = fh.readline(4096)
        if container_of(head[:4]) == "plain":     # the common case: no need to read the whole file
            return head.decode("ascii", errors="replace").rstrip("\r\n")
        lines = read_gnss_lines(path)
    except (InputError, OSError):
        return ""
    return lines[0] if lines else ""
