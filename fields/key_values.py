"""KEY=VALUE items (command-line settings, description overrides, column roles): the one parser of dgcal.

`split_key_value` splits an item; `typed_value` turns its text into the type a dataclass field declares (bool,
int, float (finite), str, an optional number that `none`/`off` leaves unset); an item that does not parse is an
`InputError` naming the setting it was given for (`what`: the option or description it belongs to).
"""
from __future__ import annotations

import math
import types
import typing

from dgcal.fields.errors import InputError

TRUE_WORDS = ("1", "true", "yes", "on")
FALSE_WORDS = ("0", "false", "no", "off")
NONE_WORDS = ("none", "off", "null")


def split_key_value(item: object, what: str) -> tuple[str, str]:
    """(KEY, VALUE) of a `KEY=VALUE` item, both stripped; InputError naming `what` when there is no `=` or key."""
    key, sep, val = str(item).partition("=")
    if not sep or not key.strip():
        raise InputError(f"expected KEY=VALUE, got {str(item)!r}", field=what)
    return key.strip(), val.strip()


def _optional(typ) -> tuple[object, bool]:
    """The type inside `X | None` (or `Optional[X]`) and whether None is allowed."""
    if isinstance(typ, types.UnionType) or typing.get_origin(typ) is typing.Union:
        args = [a for a in typing.get_args(typ) if a is not type(None)]
        if len(args) == 1:
            return args[0], len(args) < len(typing.get_args(typ))
    return typ, False


def settable(typ) -> bool:
    """Whether a field of type `typ` can be given as one KEY=VALUE text (a scalar: bool, int, float, str)."""
    return _optional(typ)[0] in (bool, int, float, str)


def typed_value(text: str, typ, key: str, what: str):
    """`text` as a value of type `typ` (bool words, a whole number, a finite float, a string, or None for `none`/
    `off` where the type allows None); InputError naming `key` and `what` otherwise."""
    inner, nullable = _optional(typ)
    v = str(text).strip()
    low = v.lower()
    if nullable and inner is not bool and low in NONE_WORDS:
        return None
    try:
        if inner is bool:
            if low not in TRUE_WORDS + FALSE_WORDS:
                raise ValueError
            return low in TRUE_WORDS
        if inner is int:
            return int(v)
        if inner is float:
            x = float(v)
            if not math.isfinite(x):
                raise ValueError
            return x
        if inner is str:
            return v
    except ValueError:
        kind = {bool: "true or false", int: "a whole number", float: "a finite number"}[inner]
        raise InputError(f"bad value for {key}: {text!r} ({kind}" + (" or none" if nullable else "") + ")",
                         field=what) from None
    raise InputError(f"{key} cannot be given as KEY=VALUE", field=what)
