"""Write the API reference's sources (``docs/api/*.rst``) from ``__all__`` of lunarmap and its subpackages.

Run after adding or removing a public name: ``python docs/api/_generate.py``. The pages are
committed, and ``tests/test_docs_api.py`` fails when a public name is missing from them (or a page
documents a name that is no longer public), so the reference cannot fall behind silently.
Each page holds the package's docstring, a summary table, then every name in full (autodoc from the
numpydoc docstrings).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import sys
import types
from functools import lru_cache
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

import lunarmap  # noqa: E402

#: subpackages in the order of the data flow (ARCHITECTURE.md), then anything else found
ORDER = ["spice", "labels", "io", "orientation", "orientation.drivers", "camera", "rpc", "simulate",
         "synthetic", "matching", "adjust", "adjust.qc", "evaluate", "missions", "workflows", "parallel"]


@lru_cache(maxsize=1)
def packages() -> list[str]:
    found = [m.name for m in pkgutil.walk_packages(lunarmap.__path__, "lunarmap.") if m.ispkg]
    ordered = [f"lunarmap.{n}" for n in ORDER if f"lunarmap.{n}" in found]
    return ["lunarmap", *ordered, *sorted(set(found) - set(ordered))]


def kind(obj: object) -> str:
    if isinstance(obj, types.ModuleType):
        return "module"
    if inspect.isclass(obj):
        return "class"
    if callable(obj):
        return "function"
    return "data"


def home_of(obj: object) -> str | None:
    """The subpackage that documents ``obj`` in full: the one its defining module is in, else the first exporting it."""
    exporting = [p for p in packages()[1:] if any(getattr(importlib.import_module(p), n, None) is obj
                                                  for n in importlib.import_module(p).__all__)]
    where = getattr(obj, "__module__", "") or ""
    inside = [p for p in exporting if where == p or where.startswith(p + ".")]
    if inside:
        return max(inside, key=len)
    return exporting[0] if exporting else None


def page(pkg: str) -> str:
    mod = importlib.import_module(pkg)
    names = list(mod.__all__)
    title = f"``{pkg}``"
    lines = [title, "=" * len(title), "", f".. automodule:: {pkg}", "   :no-members:", "",
             f".. currentmodule:: {pkg}", ""]
    groups: dict[str, list[str]] = {"class": [], "function": [], "data": [], "module": []}
    for name in names:
        groups[kind(getattr(mod, name))].append(name)
    heads = {"class": "Classes", "function": "Functions", "data": "Constants", "module": "Modules"}
    for name in groups["module"]:
        lines += [f"``{name}``: the module :mod:`{pkg}.{name}`, documented on its own page.", ""]
    for k in ("function", "class", "data"):
        if not groups[k]:
            continue
        lines += [heads[k], "-" * len(heads[k]), ""]
        for name in groups[k]:
            obj = getattr(mod, name)
            if k == "function":
                lines += [f".. autofunction:: {name}", ""]
            elif k == "class":
                home = home_of(obj)
                if home and home != pkg:
                    # documented in full once, where it lives; here a target that points there
                    # (two full descriptions of one class would share its canonical name)
                    lines += [f".. py:class:: {name}", "", f"   Re-exported from :class:`{home}.{name}`, documented there.", ""]
                else:
                    lines += [f".. autoclass:: {name}", ""]
            else:
                value = repr(obj)
                lines += [f".. autodata:: {name}"]
                if len(value) > 70:
                    lines += ["   :no-value:"]
                lines += [""]
    return "\n".join(lines).rstrip() + "\n"


def main() -> None:
    pkgs = list(packages())
    for pkg in pkgs:
        (HERE / f"{pkg}.rst").write_text(page(pkg))
    index = ["API reference", "=============", "",
             "Generated from the numpydoc docstrings of every name in ``lunarmap.__all__`` and in each",
             "subpackage's ``__all__`` (``docs/api/_generate.py``; ``tests/test_docs_api.py`` checks that none",
             "is missing). The packages are listed in the order of the data flow: a package imports only",
             "packages above it.", "", ".. toctree::", "   :maxdepth: 1", ""]
    index += [f"   {pkg}" for pkg in pkgs] + ["   lunarmap.errors", "   lunarmap.cli", ""]
    (HERE / "index.rst").write_text("\n".join(index))
    errors = ["``lunarmap.errors``", "===================", "", ".. automodule:: lunarmap.errors",
              "   :members:", "   :member-order: bysource", ""]
    (HERE / "lunarmap.errors.rst").write_text("\n".join(errors))
    cli = ["``lunarmap.cli``", "================", "", ".. automodule:: lunarmap.cli", "   :members:", ""]
    (HERE / "lunarmap.cli.rst").write_text("\n".join(cli))
    print(f"wrote {len(pkgs) + 3} pages")


if __name__ == "__main__":
    main()
