"""Sphinx configuration of lunarmap's documentation site (``make docs``).

The build is strict: ``sphinx-build -W --keep-going -n`` turns every warning (a broken
cross-reference, a docstring Sphinx cannot parse, a notebook cell that raises) into a failure.
The tutorials in ``tutorials/`` are Markdown notebooks (jupytext/MyST) that myst-nb executes at
every build; they need the shared kernel sets (``$LUNARMAP_SHARED_KERNELS``, default
``../shared/data/kernels`` beside the checkout) and say so in their first cell when these are absent.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).parent / "_ext"))

import lunarmap  # noqa: E402

project = "lunarmap"
author = "the lunarmap developers"
copyright = "2026, the lunarmap developers"
version = release = lunarmap.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_nb",
    "sphinx_copybutton",
    "lunarmap_refs",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
exclude_patterns = ["_build", "**.ipynb_checkpoints", "api/_generate.py", "_ext"]
root_doc = "index"

# -- autodoc / numpydoc ------------------------------------------------------------------------
autodoc_typehints = "none"              # types are in the numpydoc text; signatures stay readable
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "undoc-members": False}
autosummary_generate = False
numpydoc_show_class_members = False     # members are documented by autodoc below each class
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()

# The library's docstrings name numpy, xarray, dask and standard-library types that no inventory
# here resolves (the build has no network for intersphinx): these targets are not lunarmap's.
nitpick_ignore_regex = [
    (r"py:.*", r"(numpy|np|xarray|xr|dask|distributed|pandas|pd|scipy|pyproj|matplotlib|spiceypy|"
               r"pathlib|os|typing|collections|concurrent|logging|json|io)(\..*)?"),
    (r"py:.*", r"(Path|Any|Callable|Sequence|Mapping|Iterable|Iterator|ArrayLike|NDArray|Array|"
               r"Dataset|DataArray|ndarray|Client|Future|Delayed|Figure|Axes|Protocol|Enum)"),
    (r"py:.*", r"(int|float|str|bool|bytes|dict|list|tuple|set|object|None|Exception|ValueError|"
               r"RuntimeError|OSError|KeyError|TypeError|Warning|UserWarning)"),
]

# -- MyST / notebooks --------------------------------------------------------------------------
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
# every build from a clean tree (make docs removes docs/_build) executes every tutorial; a rebuild
# re-executes only the tutorials whose code changed (jupyter-cache in docs/_build/.jupyter_cache)
nb_execution_mode = "cache"
nb_execution_cache_path = str(Path(__file__).parent / "_build" / ".jupyter_cache")
nb_execution_timeout = 1800     # per cell; the shared 2-core machine runs several jobs at once
nb_execution_raise_on_error = True      # a cell that raises fails the build
nb_execution_show_tb = True
nb_merge_streams = True
os.environ.setdefault("LUNARMAP_SHARED_KERNELS", str(ROOT.parent / "shared" / "data" / "kernels"))
#: tutorials that read the shared kernel sets: shown unexecuted (not failed) where those are absent
SHARED_TUTORIALS = ["tutorials/label_to_rpc.md", "tutorials/isis_network.md"]
nb_execution_excludepatterns: list[str] = [p for p in os.environ.get("LUNARMAP_DOCS_NO_EXECUTE", "").split(",") if p]
if not (Path(os.environ["LUNARMAP_SHARED_KERNELS"]) / "lro_nac_M103595705LE").is_dir():
    nb_execution_excludepatterns += SHARED_TUTORIALS
    print(f"lunarmap docs: shared kernels absent ({os.environ['LUNARMAP_SHARED_KERNELS']}): "
          f"not executing {', '.join(SHARED_TUTORIALS)}")
# (no MPLBACKEND here: the notebook kernels draw with matplotlib's inline backend)

# -- HTML --------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"lunarmap {release}"
html_static_path = ["_static"]
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_sidebars = {"**": ["sidebar-nav-bs"]}
