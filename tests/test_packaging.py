"""The package's metadata: one version, shown by ``lunarmap --version`` (issue 31)."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

import lunarmap
from lunarmap.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_version_command_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"lunarmap {lunarmap.__version__}"


def test_version_from_the_console_entry_point():
    out = subprocess.run([sys.executable, "-m", "lunarmap", "--version"], capture_output=True, text=True,
                         check=True, timeout=120).stdout
    assert out.strip() == f"lunarmap {lunarmap.__version__}"


def test_version_has_one_source():
    assert re.fullmatch(r"\d+\.\d+\.\d+([ab]|rc)?\d*(\.dev\d+)?", lunarmap.__version__)
    text = (ROOT / "pyproject.toml").read_text()
    # pyproject.toml reads the version from lunarmap/__init__.py instead of stating its own
    assert 'dynamic = ["version"]' in text and 'attr = "lunarmap.__version__"' in text
    assert not re.search(r'(?m)^version\s*=', text.split("[project.optional-dependencies]")[0])
    # the installed distribution's metadata (editable or wheel) carries the same version
    assert metadata.version("lunarmap") == lunarmap.__version__


def test_changelog_names_the_version():
    assert f"## {lunarmap.__version__}" in (ROOT / "CHANGELOG.md").read_text()
