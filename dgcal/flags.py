"""Library errors in the words of the command line: an `InputError` naming an options field (`rinex_obs`,
`base.position_ecef`) is raised again naming the verb's flag (`--rinex-obs`, `--base-position`)."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from dgcal.fields.errors import InputError


def flag_of(field: str, flags: dict[str, str]) -> str | None:
    """The flag of an options field from the verb's table (its flags by destination, `rinex_obs` -> `--rinex-obs`,
    and its `OPTION_FLAGS` where the names differ); None for anything else (a field of a file)."""
    return flags.get(field)


@contextmanager
def flags_in_errors(flags: dict[str, str]) -> Iterator[None]:
    """Within the block, an InputError (or ResultError) without a file whose field is an options field of `flags`
    (field -> flag) comes out naming the flag."""
    try:
        yield
    except InputError as exc:
        flag = flag_of(exc.field, flags) if exc.path is None and exc.field and not exc.field.startswith("-") \
            else None
        if flag is None:
            raise
        raise type(exc)(exc.reason, None, exc.line, flag) from exc
