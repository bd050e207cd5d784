"""``[adjust.jitter]`` of the run configuration (issue 30, items 3 and 5): read, validated with named errors, and
handed to the adjustment step as a JitterSpec (the step's cache key changes with it)."""

from __future__ import annotations

import pytest

from lunarmap.errors import ConfigError
from lunarmap.workflows import config_from_dict


def _dict(tmp_path, jitter=None) -> dict:
    for f in ("nav.tm", "a.lbl", "a.nc", "b.lbl", "b.nc"):
        (tmp_path / f).write_text("")
    d = {"run": {"output": "out"}, "kernels": {"metakernel": "nav.tm"},
         "images": [{"name": "a", "label": "a.lbl", "pixels": "a.nc"}, {"name": "b", "label": "b.lbl", "pixels": "b.nc"}],
         "adjust": {}}
    if jitter is not None:
        d["adjust"]["jitter"] = jitter
    return d


def test_jitter_table_is_read(tmp_path):
    assert config_from_dict(_dict(tmp_path), base=tmp_path).jitter is None
    cfg = config_from_dict(_dict(tmp_path, {"knot_lines": 100, "sigma": 2e-6, "zero_sigma": 1e-5, "images": ["b"]}),
                           base=tmp_path)
    assert cfg.jitter is not None
    assert (cfg.jitter.knot_lines, cfg.jitter.sigma, cfg.jitter.zero_sigma, cfg.jitter.images) == (100.0, 2e-6, 1e-5,
                                                                                                    ("b",))
    plain = config_from_dict(_dict(tmp_path, {"knot_lines": 50.0, "sigma": 1e-6}), base=tmp_path)
    assert plain.jitter is not None and plain.jitter.images is None and plain.jitter.zero_sigma is None
    assert plain.digest() != cfg.digest()


@pytest.mark.parametrize("jitter, msg", [
    ({"knot_lines": 0.5, "sigma": 2e-6}, "knot_lines must be >= 1 line"),
    ({"knot_lines": 100, "sigma": 0.0}, "sigma must be > 0"),
    ({"knot_lines": 100, "sigma": 2e-6, "zero_sigma": -1.0}, "zero_sigma must be > 0"),
    ({"knot_lines": 100, "sigma": 2e-6, "images": ["c"]}, "unknown c"),
    ({"knot_lines": 100, "sigma": 2e-6, "images": []}, "got none"),
    ({"knot_lines": 100, "sigma": 2e-6, "rate": 3}, "unknown key"),
    ({"sigma": 2e-6}, "knot_lines"),
])
def test_bad_jitter_tables_are_config_errors(tmp_path, jitter, msg):
    with pytest.raises(ConfigError, match=msg):
        config_from_dict(_dict(tmp_path, jitter), base=tmp_path)
