"""A PX4 ULog's message stream checked before pyulog reads it, so that a damaged log costs one pass, not minutes.

pyulog recovers from a corrupt message by stepping one byte and reading up to 64 KiB again (a damaged 1 MB log
took over 100 s of CPU), and flattens nested formats without bound (a format of 65535 elements of a format of
65535 elements). `scan_ulog` walks the messages once (3-byte headers: uint16 size, uint8 type) and refuses:
- a message pyulog would take as corrupt (a type it does not parse in that section of the log, of size 0 or
  larger than 10 000 bytes): the error names the byte offset and how many bytes before it are readable;
- a format that flattens to more fields than a message can hold (65535 bytes), or that contains itself.
A last message cut short by the end of the file (a log whose writer lost power) ends the stream, as in pyulog.
"""
from __future__ import annotations

import struct
from pathlib import Path

from dgcal.fields.errors import InputError

MAGIC = b"ULog\x01\x12\x35"
HEADER_BYTES = 16
# the message types pyulog parses in its definitions and in its data section; any other type of size 0 or above
# 10 000 bytes it takes as a corrupt header (and steps one byte)
DEFINITION_TYPES = frozenset(b"BFIMPQALC")
DATA_TYPES = frozenset(b"IMPQALCDOS")
MAX_UNKNOWN_SIZE = 10_000       # pyulog's bound: an unknown type above it is a corrupt header
MAX_FIELDS = 65_535             # a data message holds at most 65535 bytes, each field at least one
BASIC_TYPES = frozenset(("int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t",
                         "uint64_t", "float", "double", "bool", "char"))


def _format_fields(payload: bytes) -> tuple[str, list[tuple[str, int]]] | None:
    """(name, [(type, array size)]) of a format message, None when it does not parse (pyulog skips those)."""
    try:
        text = payload.decode("utf-8", "ignore")
        name, _, body = text.partition(":")
        fields = []
        for f in body.split(";"):
            if not f:
                continue
            typ, _, field_name = f.partition(" ")
            size = 0
            if "[" in typ:
                size = int(typ[typ.index("[") + 1:typ.index("]")])
                typ = typ[:typ.index("[")]
            if not field_name or not 0 <= size <= 0xFFFF:
                return None       # pyulog refuses such a format (and keeps no definition of it)
            fields.append((typ, size))
        return name, fields
    except ValueError:
        return None


def _flat_count(name: str, formats: dict, path: Path, memo: dict, stack: tuple = ()) -> int:
    """Fields of format `name` once nested formats and arrays are flattened (as pyulog does); InputError beyond
    MAX_FIELDS or for a format that contains itself (a missing one counts 0)."""
    if name in memo:
        return memo[name]
    if name in stack:
        raise InputError(f"format {name!r} contains itself: a corrupt format definition", path, field="format")
    if name not in formats:
        return 0      # pyulog skips a topic whose format is missing
    n = 0
    for typ, size in formats[name]:
        one = 1 if typ in BASIC_TYPES else _flat_count(typ, formats, path, memo, (*stack, name))
        n += one * max(size, 1)
        if n > MAX_FIELDS:
            raise InputError(f"format {name!r} flattens to more than {MAX_FIELDS} fields: a corrupt format "
                             "definition", path, field="format")
    memo[name] = n
    return n


def _corrupt(path: Path, offset: int, size: int, kind: int, total: int) -> InputError:
    what = f"type 0x{kind:02x}" + (f" {chr(kind)!r}" if 32 < kind < 127 else "")
    return InputError(f"the log is damaged at byte {offset} of {total} (a message of {what}, {size} bytes): the "
                      f"first {offset} bytes are readable (cut the file there, e.g. `head -c {offset}`)", path,
                      field="ulog stream")


def scan_ulog(path: str | Path, data: bytes | None = None) -> int:
    """Bytes of the ULog at `path` (or its `data`) that pyulog may read: the whole file, or up to a last message cut
    short; InputError naming the byte offset for a corrupt message or format (see the module doc)."""
    path = Path(path)
    if data is None:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    total = len(data)
    if total < HEADER_BYTES or data[:7] != MAGIC:
        raise InputError(f"not a PX4 ULog file (starts {data[:7]!r})", path, field="header")
    formats: dict[str, list[tuple[str, int]]] = {}
    logged: list[str] = []
    unpack = struct.Struct("<HB").unpack_from
    offset, ends = HEADER_BYTES, [total]      # segments: the main stream, then each block of appended data
    definitions = True                        # before the first subscription or log line (pyulog's first section)
    while True:
        size, kind = unpack(data, offset) if offset + 3 <= ends[0] else (0, -1)
        cut = kind < 0 or offset + 3 + size > ends[0]
        handled = DEFINITION_TYPES if definitions else DATA_TYPES
        corrupt = kind >= 0 and kind not in handled and (kind == 0 or size == 0 or size > MAX_UNKNOWN_SIZE)
        # a corrupt header cut short by the end of the file among the definitions sends pyulog back and forth for
        # ever (it steps back over more than it read); in the data section it ends the log
        if corrupt and (definitions or not cut):
            raise _corrupt(path, offset, size, kind, total)
        if cut:
            if len(ends) == 1:
                break                         # a last message cut short (or none): the file ends
            offset = ends.pop(0)              # the main stream stops short of the appended data (as pyulog)
            continue
        if kind in (0x41, 0x4C, 0x43):        # 'A', 'L', 'C' end pyulog's definitions section
            definitions = False
        payload = data[offset + 3:offset + 3 + size]
        if kind == 0x42 and offset == HEADER_BYTES and size >= 40:   # 'B' flag bits: appended data's offsets
            starts = sorted({o for o in struct.unpack_from("<3Q", payload, 16) if offset < o < total})
            ends = [*starts, total]
        elif kind == 0x46:                    # 'F' format
            parsed = _format_fields(payload)
            if parsed is not None:
                formats[parsed[0]] = parsed[1]
        elif kind == 0x41 and size > 3:       # 'A' add logged message: its topic's format
            logged.append(payload[3:].decode("utf-8", "ignore"))
        offset += 3 + size
    memo: dict[str, int] = {}
    for name in dict.fromkeys(logged):
        _flat_count(name, formats, path, memo)
    return min(offset, total)
