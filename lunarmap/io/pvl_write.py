"""Writing PVL text (ISIS labels): the inverse of :func:`lunarmap.labels.parse_label` for what lunarmap writes.

A label is a list of items: ``(key, value)`` keywords, ``("Object", name, items)`` and
``("Group", name, items)`` blocks. Values are numbers, strings (quoted when needed),
sequences (written ``(a, b, c)``) or ``(value, unit)`` via :class:`Unit`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Iterable

from ..errors import InvalidInputError

__all__ = ["Unit", "format_pvl", "pvl_value"]

_BARE = re.compile(r"^[A-Za-z0-9_.+\-:/$]+$")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


@dataclass(frozen=True)
class Unit:
    """A value with a unit, written ``value <unit>``."""

    value: Any
    unit: str


def pvl_value(v: Any) -> str:
    """PVL text of one value."""
    if isinstance(v, Unit):
        return f"{pvl_value(v.value)} <{v.unit}>"
    if isinstance(v, bool):
        return "True" if v else "False"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InvalidInputError(f"PVL cannot hold the non-finite number {v!r}")
        return repr(v)  # shortest text that reads back to the same double
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(pvl_value(x) for x in v) + ")"
    if hasattr(v, "item") and not isinstance(v, str):  # numpy scalar
        return pvl_value(v.item())
    s = str(v)
    if s and _BARE.match(s) and s.lower() not in ("end", "end_object", "end_group", "object", "group") \
            and not _NUMBER.match(s):  # "007" unquoted would read back as the number 7
        return s
    if '"' in s:
        raise InvalidInputError(f"PVL string {s!r} holds a double quote")
    return f'"{s}"'


def _lines(items: Iterable[Any], indent: int) -> list[str]:
    pad = "  " * indent
    out: list[str] = []
    items = list(items)
    width = max([len(str(it[0])) for it in items if len(it) == 2] or [0])
    for it in items:
        if len(it) == 3:
            kind, name, sub = it
            out.append(f"{pad}{kind} = {name}")
            out.extend(_lines(sub, indent + 1))
            out.append(f"{pad}End_{kind}")
            if indent == 0:
                out.append("")
        else:
            key, value = it
            out.append(f"{pad}{str(key).ljust(width)} = {pvl_value(value)}")
    return out


def format_pvl(items: Iterable[Any], end: bool = True) -> str:
    """PVL text of ``items`` (see the module docstring), closed by ``End`` unless ``end=False``."""
    text = "\n".join(_lines(items, 0))
    return text + ("\nEnd\n" if end else "\n")
