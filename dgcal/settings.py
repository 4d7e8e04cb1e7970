"""`--set KEY=VALUE` of a verb: parsed generically from the fields of the options object the verb built.

An options object lists the estimator options `--set` reaches (`settings_groups()`: name -> dataclass instance);
a key is `group.field` or a bare field name (the first group that has it), or an old name of its
`SETTING_ALIASES`. A key of another mode (`others`: options objects of the other modes) is an error naming the
mode it belongs to; an unknown key lists the keys there are.
"""
from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable

from dgcal.fields.errors import InputError
from dgcal.fields.key_values import settable, split_key_value, typed_value


def setting_fields(groups: dict) -> dict[str, tuple[str, str, object]]:
    """Every settable key of `groups` -> (group, field, type): `group.field` always, the bare field for the first
    group that has it."""
    out: dict = {}
    for g, obj in groups.items():
        hints = typing.get_type_hints(type(obj))
        for f in dataclasses.fields(obj):
            typ = hints.get(f.name, f.type)
            if f.name.startswith("_") or not settable(typ):
                continue
            out[f"{g}.{f.name}"] = (g, f.name, typ)
            out.setdefault(f.name, (g, f.name, typ))
    return out


def _resolve(key: str, aliases: dict) -> str:
    k = key.replace("-", "_")
    return aliases.get(k, k)


def apply_settings(opts, items, others: Callable[[], dict] | dict | None = None, flag: str = "--set"):
    """Set the `KEY=VALUE` items on the options object `opts` (in place; returned); InputError naming `flag` for a
    malformed item, a bad value, a key of another mode (`others`: mode name -> options object, or a function
    giving them, called only for a key `opts` lacks) or an unknown key."""
    groups = opts.settings_groups()
    known = setting_fields(groups)
    aliases = getattr(opts, "SETTING_ALIASES", {})
    for item in items:
        key, text = split_key_value(item, flag)
        k = _resolve(key, aliases)
        if k not in known:
            mode = getattr(opts, "mode", "this mode")
            later = k in setting_fields(opts.settings_groups(every=True))   # the mode's, with more inputs
            other_modes = others() if callable(others) else (others or {})
            owners = [m for m, other in other_modes.items() if m != mode and _resolve(
                key, getattr(other, "SETTING_ALIASES", {})) in setting_fields(other.settings_groups(every=True))]
            more = f"--mode {mode} uses it only with another input (a base station)"
            if owners:
                raise InputError(f"{key} is a setting of --mode {'/'.join(owners)}: " +
                                 (more if later else f"--mode {mode} does not use it"), field=flag)
            if later:
                raise InputError(f"{key}: {more}", field=flag)
            bare = sorted(n for n in known if "." not in n)
            raise InputError(f"unknown setting {key!r} (KEY=VALUE with KEY one of {', '.join(bare)}, or GROUP.KEY with "
                             f"GROUP one of {', '.join(groups)})", field=flag)
        g, name, typ = known[k]
        setattr(groups[g], name, typed_value(text, typ, key, flag))
    return opts
