"""Every public name is in the API reference's sources (issue 31); no Sphinx build needed.

The public names are ``lunarmap.__all__`` and the ``__all__`` of every subpackage. The reference
(``docs/api/<package>.rst``, written by ``docs/api/_generate.py``) documents each under its
package's ``.. currentmodule::`` with an ``auto*`` or ``py:class`` directive; a name missing there,
or a name documented that is no longer public, fails here.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import lunarmap

API = Path(__file__).resolve().parents[1] / "docs" / "api"
DIRECTIVE = re.compile(r"^\.\. (?:autofunction|autoclass|autodata|py:class|py:function|py:data):: (\S+)", re.M)


def _packages() -> list[str]:
    return ["lunarmap", *sorted(m.name for m in pkgutil.walk_packages(lunarmap.__path__, "lunarmap.") if m.ispkg)]


def _documented(pkg: str) -> set[str]:
    page = API / f"{pkg}.rst"
    assert page.is_file(), f"no API page {page.name} for {pkg} (run python docs/api/_generate.py)"
    text = page.read_text()
    assert f".. currentmodule:: {pkg}\n" in text and f".. automodule:: {pkg}\n" in text
    return set(DIRECTIVE.findall(text))


@pytest.mark.parametrize("pkg", _packages())
def test_every_public_name_is_in_the_api_reference(pkg):
    mod = importlib.import_module(pkg)
    public = set(mod.__all__)
    documented = _documented(pkg)
    modules = {n for n in public if type(getattr(mod, n)).__name__ == "module"}
    text = (API / f"{pkg}.rst").read_text()
    for name in modules:   # a module in __all__ (lunarmap.errors) has a page of its own
        assert f":mod:`{pkg}.{name}`" in text and (API / f"{pkg}.{name}.rst").is_file()
    assert sorted(public - modules - documented) == [], f"public names of {pkg} missing from docs/api/{pkg}.rst"
    assert sorted(documented - public) == [], f"docs/api/{pkg}.rst documents names {pkg} no longer exports"


def test_every_api_page_is_in_the_toctree():
    index = (API / "index.rst").read_text()
    pages = sorted(p.stem for p in API.glob("*.rst") if p.stem != "index")
    assert [p for p in pages if f"   {p}\n" not in index] == []
    assert set(_packages()) <= set(pages)


def test_names_counted():
    total = sum(len(importlib.import_module(p).__all__) for p in _packages())
    assert total >= 400    # 443 when this test was written: a collapse of __all__ shows here
