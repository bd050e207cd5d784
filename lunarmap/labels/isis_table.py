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
from .pvl import Label, label_int, load_label

__all__ = ["read_isis_table", "isis_table_names"]

_TYPES = {"Double": "f8", "Integer": "i4", "Real": "f4"}


def isis_table_names(label: Label) -> list[str]:
    """Names of the tables described in a cube label."""
    return [str(t.get("Name", "")) for t in label.all("Table") if isinstance(t, Label)]


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
        No such table, a missing or malformed ``StartByte`` / ``Bytes`` / ``Records`` / field, an
        unsupported field type, or a table extending past the file's end.
    """
    label = load_label(path)
    tables = [t for t in label.all("Table") if isinstance(t, Label) and str(t.get("Name", "")) == name]
    if not tables:
        raise LabelError(f"ISIS cube {os.fspath(path)} has no table {name!r} (has: {isis_table_names(label)})")
    t = tables[0]
    where = f"table {name} of {os.fspath(path)}"
    order = "<" if str(t.get("ByteOrder", "Lsb")) == "Lsb" else ">"
    fields: list[tuple[str, str, int]] = []
    for f in t.all("Field"):
        if not isinstance(f, Label) or "Name" not in f:
            raise LabelError(f"{where}: a Field group without a Name")
        ftype = str(f.get("Type", ""))
        if ftype not in _TYPES:
            raise LabelError(f"{where}: unsupported field type {ftype!r}")
        if not str(f["Name"]).strip() or isinstance(f["Name"], (list, Label)):
            raise LabelError(f"{where}: a Field group with an empty or non-text Name {f['Name']!r:.40}")
        fields.append((str(f["Name"]), order + _TYPES[ftype], label_int(f.get("Size", 1), f"{where}: field Size", 1)))
    if not fields:
        raise LabelError(f"{where}: no Field groups")
    names = [n for n, _, _ in fields]
    if len(set(names)) != len(names):
        raise LabelError(f"{where}: repeated field names {sorted(n for n in set(names) if names.count(n) > 1)}")
    try:
        dtype = np.dtype([(n, ty, (s,)) if s > 1 else (n, ty) for n, ty, s in fields])
    except (ValueError, TypeError, OverflowError) as err:
        raise LabelError(f"{where}: fields do not make a record ({err})") from None
    for key in ("StartByte", "Bytes", "Records"):
        if key not in t:
            raise LabelError(f"{where} lacks {key}")
    start = label_int(t["StartByte"], f"{where}: StartByte", 1) - 1
    nbytes = label_int(t["Bytes"], f"{where}: Bytes", 0)
    records = label_int(t["Records"], f"{where}: Records", 0)
    if records * dtype.itemsize != nbytes:
        raise LabelError(f"table {name} of {os.fspath(path)}: {records} records of {dtype.itemsize} bytes "
                         f"do not make the stated {nbytes} bytes")
    if start + nbytes > os.path.getsize(path):
        raise LabelError(f"table {name} of {os.fspath(path)} extends past the end of the file")
    with open(path, "rb") as fh:
        fh.seek(start)
        raw = fh.read(nbytes)
    if len(raw) != nbytes:
        raise LabelError(f"table {name} of {os.fspath(path)} extends past the end of the file")
    rec = np.frombuffer(raw, dtype=dtype)
    columns: dict[str, Any] = {n: rec[n].astype(float if ty.endswith(("f8", "f4")) else int) for n, ty, _ in fields}
    return columns, t
