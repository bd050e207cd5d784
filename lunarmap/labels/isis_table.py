"""Binary tables attached to ISIS cubes (``Object = Table`` in the cube label).

ISIS ``spiceinit`` stores the orientation it computed in tables named
``InstrumentPointing``, ``InstrumentPosition``, ``BodyRotation`` and
``SunPosition``: records of fixed-size fields (here ``Double``, ``Integer``,
``Real``), little- or big-endian as the table's ``ByteOrder`` says, starting at
the 1-based byte ``StartByte`` of the cube file.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..errors import LabelError
from .pvl import Label, load_label

__all__ = ["read_isis_table", "isis_table_names"]

_TYPES = {"Double": "f8", "Integer": "i4", "Real": "f4"}


def isis_table_names(label: Label) -> list[str]:
    """Names of the tables described in a cube label."""
    return [str(t.get("Name", "")) for t in label.all("Table")]


def read_isis_table(path: str | os.PathLike[str], name: str) -> tuple[dict[str, np.ndarray], Label]:
    """Read one table of an ISIS cube.

    Parameters
    ----------
    path : path-like
        The ISIS cube (label attached).
    name : str
        Table name, e.g. ``"InstrumentPointing"``.

    Returns
    -------
    columns : dict of str to ndarray
        One array per field, ``(records,)`` or ``(records, size)`` for fields of size > 1.
    table_label : Label
        The table's label block (frames, cache type, kernels...).

    Raises
    ------
    LabelError
        No such table, an unsupported field type, or a table extending past the file's end.
    """
    label = load_label(path)
    tables = [t for t in label.all("Table") if str(t.get("Name", "")) == name]
    if not tables:
        raise LabelError(f"ISIS cube {os.fspath(path)} has no table {name!r} (has: {isis_table_names(label)})")
    t = tables[0]
    order = "<" if str(t.get("ByteOrder", "Lsb")) == "Lsb" else ">"
    fields: list[tuple[str, str, int]] = []
    for f in t.all("Field"):
        ftype = str(f.get("Type", ""))
        if ftype not in _TYPES:
            raise LabelError(f"table {name} of {os.fspath(path)}: unsupported field type {ftype!r}")
        fields.append((str(f["Name"]), order + _TYPES[ftype], int(f.get("Size", 1))))
    dtype = np.dtype([(n, ty, (s,)) if s > 1 else (n, ty) for n, ty, s in fields])
    start, nbytes, records = int(t["StartByte"]) - 1, int(t["Bytes"]), int(t["Records"])
    if records * dtype.itemsize != nbytes:
        raise LabelError(f"table {name} of {os.fspath(path)}: {records} records of {dtype.itemsize} bytes "
                         f"do not make the stated {nbytes} bytes")
    with open(path, "rb") as fh:
        fh.seek(start)
        raw = fh.read(nbytes)
    if len(raw) != nbytes:
        raise LabelError(f"table {name} of {os.fspath(path)} extends past the end of the file")
    rec = np.frombuffer(raw, dtype=dtype)
    columns: dict[str, Any] = {n: rec[n].astype(float if ty.endswith(("f8", "f4")) else int) for n, ty, _ in fields}
    return columns, t
