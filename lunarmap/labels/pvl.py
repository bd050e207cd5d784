"""A small reader for PVL labels (ISIS cube labels and PDS3 labels).

Handles what planetary image labels use: ``Object``/``Group`` nesting (and the
PDS3 ``OBJECT = X ... END_OBJECT = X`` spelling), quoted strings spanning lines,
``(...)`` sequences and ``{...}`` sets spanning lines, units in angle brackets,
``/* */`` comments, ISIS's hyphenated line continuation of long words, and the
binary payload after ``End`` (ignored). Numbers with units come back as
:class:`Quantity` (a ``float`` that remembers its unit).

Written here rather than depending on the ``pvl`` package: the subset needed is
small and a dependency would bring its own value types into lunarmap's API.
"""

from __future__ import annotations

import os
import re
from typing import Any, Iterator

from ..errors import LabelError, LabelKeywordError

__all__ = ["Label", "Quantity", "load_label", "parse_label", "label_int"]


class Quantity(float):
    """A number with a unit, e.g. ``1.0288 <ms>``; behaves as a ``float``."""

    unit: str

    def __new__(cls, value: float, unit: str) -> "Quantity":
        obj = super().__new__(cls, value)
        obj.unit = unit
        return obj

    def __repr__(self) -> str:
        return f"Quantity({float(self)!r}, {self.unit!r})"

    def __reduce__(self) -> tuple[type, tuple[float, str]]:
        # float's own reduction calls Quantity(value) without the unit: labels would not unpickle
        return Quantity, (float(self), self.unit)


class Label(dict):
    """An ordered, case-insensitive mapping of a PVL block.

    Repeated keywords or blocks (several ``Object = Table``) are kept: ``label[k]``
    returns the first and :meth:`all` every occurrence. A missing key raises
    :class:`~lunarmap.errors.LabelKeywordError` (a ``KeyError``) naming the label file and the
    keyword's path in it (``IsisCube/Core/Dimensions/Lines``).

    Parameters
    ----------
    source : str
        The label file, for messages.
    path : str
        Where this block sits in the label (``"IsisCube/Core"``; ``""`` for the top level).
    """

    def __init__(self, source: str = "", path: str = "") -> None:
        super().__init__()
        self._lower: dict[str, str] = {}
        self._repeats: dict[str, list[Any]] = {}
        self.source = source
        self.path = path

    def add(self, key: str, value: Any) -> None:
        low = key.lower()
        if low in self._lower:
            self._repeats.setdefault(low, []).append(value)
            return
        self._lower[low] = key
        super().__setitem__(key, value)

    def __getitem__(self, key: str) -> Any:
        try:
            return super().__getitem__(self._lower.get(key.lower(), key))
        except KeyError:
            where = f"{self.path}/{key}" if self.path else str(key)
            raise LabelKeywordError(f"label {self.source or '(in memory)'} lacks {where}") from None

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key.lower() in self._lower

    def get(self, key: str, default: Any = None) -> Any:
        return self[key] if key in self else default

    def all(self, key: str) -> list[Any]:
        """Every value given for ``key``, in order."""
        if key not in self:
            return []
        return [self[key], *self._repeats.get(key.lower(), [])]

    def find(self, key: str) -> Any:
        """The first value of ``key`` anywhere in the tree (depth first), or ``None``."""
        if key in self:
            return self[key]
        for value in self.values():
            if isinstance(value, Label):
                found = value.find(key)
                if found is not None:
                    return found
        return None


_TOKEN = re.compile(
    r"""\s*(?:
        (?P<comment>/\*.*?\*/)
      | (?P<dq>"(?:[^"])*")
      | (?P<sq>'(?:[^'])*')
      | (?P<unit><[^>]*>)
      | (?P<punct>[=(){},])
      | (?P<word>[^\s=(){},<>"']+)
    )""",
    re.VERBOSE | re.DOTALL,
)


def _tokenize(text: str) -> Iterator[tuple[str, str, int]]:
    pos, n = 0, len(text)
    line, counted = 1, 0  # line numbers counted incrementally: linear in the text (PVL networks are MBs)
    while pos < n:
        m = _TOKEN.match(text, pos)
        if not m:
            if text[pos:].strip() == "":
                return
            line = text.count("\n", 0, pos) + 1
            raise LabelError(f"unexpected character {text[pos]!r} at line {line}")
        pos = m.end()
        kind = m.lastgroup
        if kind == "comment" or kind is None:
            continue
        start = m.start(kind)
        line += text.count("\n", counted, start)
        counted = start
        yield kind, m.group(kind), line


def _scalar(kind: str, tok: str) -> Any:
    if kind == "dq" or kind == "sq":
        # PVL folds line breaks in quoted text; ISIS hyphenates long words with '-\n'
        inner = tok[1:-1]
        inner = re.sub(r"-\s*\n\s*", "", inner) if "-\n" in inner else inner
        return re.sub(r"\s*\n\s*", " ", inner)
    try:
        if re.fullmatch(r"[+-]?\d+", tok):
            return int(tok)
        return float(tok)
    except ValueError:
        return tok


class _Parser:
    def __init__(self, text: str, source: str) -> None:
        self.source = source
        self.toks = list(_tokenize(text))
        self.i = 0

    def error(self, msg: str, line: int | None = None) -> LabelError:
        where = f" (line {line})" if line else ""
        return LabelError(f"malformed label {self.source}{where}: {msg}")

    def peek(self) -> tuple[str, str, int] | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self) -> tuple[str, str, int]:
        tok = self.peek()
        if tok is None:
            raise self.error("unexpected end of label")
        self.i += 1
        return tok

    def value(self) -> Any:
        kind, tok, line = self.take()
        if kind == "punct" and tok in "({":
            close = ")" if tok == "(" else "}"
            items: list[Any] = []
            while True:
                nk = self.peek()
                if nk is None:
                    raise self.error(f"unterminated sequence opened with {tok!r}", line)
                if nk[0] == "punct" and nk[1] == close:
                    self.take()
                    after = self.peek()
                    if after is not None and after[0] == "unit":  # a unit for the whole sequence
                        self.take()
                        unit = after[1][1:-1].strip()
                        items = [Quantity(float(v), unit) if isinstance(v, (int, float)) else v for v in items]
                    return items
                if nk[0] == "punct" and nk[1] == ",":
                    self.take()
                    continue
                items.append(self.value())
        if kind == "punct":
            raise self.error(f"unexpected {tok!r}", line)
        val = _scalar(kind, tok)
        # ISIS continues long unquoted words with a trailing '-' on the line
        while kind == "word" and isinstance(val, str) and val.endswith("-"):
            nk = self.peek()
            if nk is None or nk[0] != "word" or nk[2] == line:
                break
            self.take()
            val = val[:-1] + nk[1]
            line = nk[2]
        nk = self.peek()
        if nk is not None and nk[0] == "unit":
            self.take()
            unit = nk[1][1:-1].strip()
            if isinstance(val, (int, float)):
                return Quantity(float(val), unit)
        return val

    def block(self, end_words: tuple[str, ...], name: str | None, path: str = "") -> Label:
        lab = Label(self.source, path)
        while True:
            tok = self.peek()
            if tok is None:
                if name is None:
                    return lab
                raise self.error(f"block {name!r} is never closed")
            kind, word, line = tok
            low = word.lower()
            if kind != "word":
                raise self.error(f"expected a keyword, found {word!r}", line)
            if low == "end" and name is None:
                return lab  # anything after End (binary data) is not label
            if low in end_words:
                self.take()
                nxt = self.peek()
                if nxt is not None and nxt[0] == "punct" and nxt[1] == "=":
                    self.take()
                    self.take()
                return lab
            if low in ("end_object", "end_group", "end"):
                raise self.error(f"{word} does not close the open block {name!r}", line)
            self.take()
            eq = self.take()
            if eq[0] != "punct" or eq[1] != "=":
                raise self.error(f"expected '=' after {word!r}", line)
            if low in ("object", "group", "begin_object", "begin_group"):
                kind2, bname, _ = self.take()
                bname = str(_scalar(kind2, bname))
                ends = ("end_object",) if "object" in low else ("end_group",)
                lab.add(bname, self.block(ends, bname, f"{path}/{bname}" if path else bname))
            else:
                lab.add(word, self.value())


def parse_label(text: str, source: str = "<string>") -> Label:
    """Parse PVL text into a :class:`Label` tree."""
    if "\x00" in text:
        text = text.split("\x00", 1)[0]
    parser = _Parser(text, source)
    if not parser.toks:
        raise LabelError(f"empty label {source}")
    lab = parser.block(("end",), None)
    if not lab:
        raise LabelError(f"label {source} holds no keywords")
    return lab


def load_label(path: str | os.PathLike[str]) -> Label:
    """Read the PVL label of a file (an ISIS cube's attached label, a PDS3 .lbl).

    Raises
    ------
    LabelError
        The file is missing, unreadable or not valid PVL.
    """
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise LabelError(f"label file not found: {p}")
    with open(p, "rb") as fh:
        raw = fh.read(2_000_000)
    # an ISIS cube's label is ASCII text followed by binary data: stop at "End" line
    text = raw.decode("latin-1")
    m = re.search(r"^\s*End\s*$", text, re.MULTILINE)
    if m:
        text = text[: m.end()]
    return parse_label(text, p)


def label_int(value: Any, what: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """A label value as an integer in ``[minimum, maximum]``; ``what`` names it (and its file) in the message.

    Raises
    ------
    LabelError
        Not an integer (``1D5``, ``End``, ``2.5``, a boolean) or out of range.
    """
    try:
        number = float(value)
        if isinstance(value, bool) or not number.is_integer():
            raise ValueError
        out = int(number)
    except (TypeError, ValueError, OverflowError):
        raise LabelError(f"{what} {value!r:.60} is not an integer") from None
    if minimum is not None and out < minimum:
        raise LabelError(f"{what} {out} is less than {minimum}")
    if maximum is not None and out > maximum:
        raise LabelError(f"{what} {out} is more than {maximum}")
    return out
