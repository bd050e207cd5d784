"""Resolve cross-references of lunarmap's docstrings to the names the API reference documents.

The docstrings name objects where they are defined (``lunarmap.rpc.fit.fit_rpc``, ``ImageSupport``,
``offsets.offset_drift_step`` inside :mod:`lunarmap.adjust.qc`); the reference documents them under
their public names (``lunarmap.rpc.fit_rpc``). A reference Sphinx cannot find is resolved here by
importing its target and finding the documented name of the same object. A target that imports but
is not public (a module inside a package, a private helper) links to the page of the nearest
documented package. A target that does not import at all is left alone, so Sphinx still warns about
it: a broken reference fails the build.
"""

from __future__ import annotations

import importlib
from typing import Any

from sphinx.util.nodes import make_refnode

_CACHE: dict[str, Any] = {}


def _import(path: str) -> Any:
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:  # noqa: BLE001 (any import failure: not this prefix)
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


def _index(env: Any) -> dict[str, Any]:
    if _CACHE.get("n") == len(env.get_domain("py").objects):
        return _CACHE
    by_id: dict[int, str] = {}
    by_last: dict[str, list[str]] = {}
    for name, entry in env.get_domain("py").objects.items():
        if entry.aliased or not name.startswith("lunarmap"):
            continue
        by_last.setdefault(name.rsplit(".", 1)[-1], []).append(name)
        obj = _import(name)
        if obj is not None and not isinstance(obj, (str, int, float, tuple, dict, list)):
            # the deepest (most specific) documented name wins over a top-level re-export
            prev = by_id.get(id(obj))
            if prev is None or prev.count(".") < name.count("."):
                by_id[id(obj)] = name
    _CACHE.update(n=len(env.get_domain("py").objects), by_id=by_id, by_last=by_last)
    return _CACHE


def _missing_reference(app: Any, env: Any, node: Any, contnode: Any) -> Any:
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    context = node.get("py:module") or ""
    index = _index(env)
    domain = env.get_domain("py")
    candidates = [target]
    # the module that defines the docstring's object (autodoc names it in the node's source:
    # "docstring of lunarmap.camera.factory.camera_from_isd"), then the page's module
    source = str(node.source or "")
    defining = source.rpartition("docstring of ")[2] if "docstring of " in source else ""
    for prefix in (defining, context):
        while prefix:
            candidates.append(f"{prefix}.{target}")
            prefix = prefix.rpartition(".")[0]
    if node.get("reftype") in ("attr", "meth") and "." in target:
        # an attribute autodoc does not document separately (a dataclass field): its class
        owner = target.rpartition(".")[0]
        candidates += [c.rpartition(".")[0] for c in candidates if c.endswith("." + target) or c == target]
        candidates.append(owner)
    for cand in candidates:
        obj = _import(cand) if cand.startswith("lunarmap") else None
        if obj is None:
            continue
        name = index["by_id"].get(id(obj))
        if name is None and hasattr(obj, "__name__"):
            # a public object whose documented name has another path
            hits = [n for n in index["by_last"].get(getattr(obj, "__name__", ""), []) if _import(n) is obj]
            name = hits[0] if hits else None
        if name is not None and name in domain.objects:
            entry = domain.objects[name]
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, name)
        # importable but not public: the nearest documented package's page
        pkg = cand
        while pkg and pkg not in domain.modules:
            pkg = pkg.rpartition(".")[0]
        if pkg:
            entry = domain.modules[pkg]
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, pkg)
    # a bare name (``ImageSupport``): the documented lunarmap object of that name, when there is one
    hits = index["by_last"].get(target, [])
    if len(hits) >= 1 and "." not in target:
        objs = {id(_import(h)) for h in hits}
        if len(objs) == 1:
            name = max(hits, key=lambda n: n.count("."))
            entry = domain.objects[name]
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, name)
    return None


def setup(app: Any) -> dict[str, Any]:
    app.connect("missing-reference", _missing_reference)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
