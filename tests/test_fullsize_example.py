"""The full-size block layout (NAC-L / NAC-R, two strips, two orbits) and the example written once."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np
import pytest

import lunarmap
from lunarmap.cli import build_parser
from lunarmap.errors import InvalidInputError
from lunarmap.io import IsisCube, open_image
from lunarmap.synthetic import build_block_model, open_block_mission, write_block_mission
from lunarmap.synthetic import block as block_module
from lunarmap.synthetic.block import image_footprint
from lunarmap.workflows import write_example
from lunarmap.workflows.example import EXAMPLE_STATE


def _en(model, xyz):
    s = model.site(1)
    lon, lat = np.radians(s.longitude_deg), np.radians(s.latitude_deg)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    d = xyz - model.site_xyz()
    return np.stack([d @ east, d @ north], axis=-1)


def _inside(quad, pts):
    """Points inside a convex quadrilateral (corners in order), 2-D."""
    sign = []
    for a, b in zip(quad, np.roll(quad, -1, axis=0)):
        sign.append(np.sign((b[0] - a[0]) * (pts[:, 1] - a[1]) - (b[1] - a[1]) * (pts[:, 0] - a[0])))
    sign = np.array(sign)
    return np.all(sign >= 0, axis=0) | np.all(sign <= 0, axis=0)


def test_full_size_layout_geometry():
    m = build_block_model(0, orbits=2, layout="full_size")
    assert [im.name for im in m.images] == [f"orbit{o}_{c}_{s}" for o in (1, 2) for s in "ab" for c in ("nacl", "nacr")]
    assert all(im.lines == 52224 and im.samples == 5064 for im in m.images)
    quads = {im.name: _en(m, image_footprint(m, im)) for im in m.images}
    ext_e, ext_n = m.site(1).extents
    for q in quads.values():   # the site's rectangle holds every footprint with a border
        assert np.all(np.abs(q[:, 0]) < ext_e / 2 - 250) and np.all(np.abs(q[:, 1]) < ext_n / 2 - 250)
    rng = np.random.default_rng(0)
    for im in m.images:
        # sample the footprint (bilinear in its corners) and find the images of the other orbit that see it
        q = quads[im.name]
        u, v = rng.uniform(0, 1, (2, 4000))
        pts = ((1 - v)[:, None] * ((1 - u)[:, None] * q[0] + u[:, None] * q[1])
               + v[:, None] * ((1 - u)[:, None] * q[3] + u[:, None] * q[2]))
        other = [o for o in m.images if o.orbit != im.orbit]
        seen = np.zeros(len(pts), bool)
        for o in other:
            seen |= _inside(quads[o.name], pts)
        assert seen.mean() > 0.6, (im.name, seen.mean())      # most of it (70-100 %) is seen from the other orbit
        # the orbits' strips are staggered: orbit 1's strip b and orbit 2's strip a straddle the other's seam,
        # so the four strips of a camera form one chain of cross-orbit overlaps
        if im.kind.endswith("_b" if im.orbit == 1 else "_a"):
            for strip in "ab":
                twin = f"orbit{3 - im.orbit}_{im.kind[:4]}_{strip}"
                assert _inside(quads[twin], pts).mean() > 0.05, (im.name, twin)
    # NAC-L (east) and NAC-R (west) of one strip overlap by ~70 m (140 px) at both ends
    for o in (1, 2):
        for s in "ab":
            left, right = quads[f"orbit{o}_nacl_{s}"], quads[f"orbit{o}_nacr_{s}"]
            for lc, rc in ((0, 1), (3, 2)):      # inner corners: south, north
                assert 40.0 < right[rc, 0] - left[lc, 0] < 120.0, (o, s, right[rc, 0] - left[lc, 0])
    # no two images of one camera on one orbit share an exposure time (they would see the same ground from
    # the same place: no parallax); strip b starts a line after strip a ends
    for a in m.images:
        for b in m.images:
            if a.name < b.name and a.camera == b.camera and a.orbit == b.orbit:
                first, second = sorted((a, b), key=lambda im: im.planned_start_et)
                gap = second.planned_start_et - (first.planned_start_et + first.duration)
                assert 0.5 * first.line_time < gap < 2.0 * first.line_time
    # 0.5 m pixels, ~20 degrees of cross-orbit convergence at the site
    geo = block_module.block_geometry(m)
    assert all(0.48 < g["gsd_m"] < 0.52 for g in geo["images"].values())
    site = m.site_xyz()
    views = [m.position_body_fixed(p.epoch) - site for p in m.passes]
    conv = np.degrees(np.arccos(views[0] @ views[1] / np.linalg.norm(views[0]) / np.linalg.norm(views[1])))
    assert 18.0 < conv < 22.0
    with pytest.raises(InvalidInputError, match="layout"):
        build_block_model(0, layout="huge")
    with pytest.raises(InvalidInputError, match="one site"):
        build_block_model(0, layout="full_size", sites=2)


def test_full_size_mission_cameras(tmp_path):
    """Through the written kernels and the generic driver: LRO NAC-like cameras of ~0.5 m pixels whose samples
    run the same way (NAC-R's frame is turned 180 degrees and its TRANSX/TRANSY negated, as LRO's)."""
    from lunarmap.simulate import block_cameras

    bm = write_block_mission(tmp_path / "m", seed=1, layout="full_size")
    assert bm.model.orbits == 2 and open_block_mission(tmp_path / "m").model.layout == "full_size"
    names = ["orbit1_nacl_a", "orbit1_nacr_a"]
    cams = block_cameras(bm, "truth", names)
    nav = block_cameras(bm, "navigation", names)
    east = {}
    for n in names:
        c = cams[n]
        assert c.distortion.k1 == pytest.approx(1.81e-5 if "nacl" in n else 1.83e-5)
        g = c.image_to_ground([26112.5, 26112.5, 26113.5], [2532.5, 2533.5, 2532.5], height=0.0)
        assert 0.47 < np.linalg.norm(g[1] - g[0]) < 0.53 and 0.47 < np.linalg.norm(g[2] - g[0]) < 0.53
        east[n] = _en(bm.model, g)[1, 0] - _en(bm.model, g)[0, 0]
        off = np.linalg.norm(nav[n].image_to_ground(26112.5, 2532.5) - c.image_to_ground(26112.5, 2532.5))
        assert 15.0 < off < 80.0                      # the example's per-orbit navigation errors
    assert np.sign(east["orbit1_nacl_a"]) == np.sign(east["orbit1_nacr_a"])


@pytest.fixture
def small_full_size(monkeypatch):
    """The full-size layout with 256-line images and 64 m albedo tiles (every other dimension as it is), so that it
    renders in seconds."""
    from functools import partial

    from lunarmap.simulate import mission
    from lunarmap.simulate.albedo import tiled_albedo

    monkeypatch.setattr(block_module, "FULL_NAC_LINES", 256)
    monkeypatch.setattr(mission, "tiled_albedo", partial(tiled_albedo, tile_nodes=(256, 240)))


def _files(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_mtime_ns, p.stat().st_ino) for p in root.rglob("*") if p.is_file()}


def _written(caplog) -> str:
    msgs = [r.getMessage() for r in caplog.records if "part(s) written" in r.getMessage()]
    assert msgs
    return msgs[-1]


FOUR = ["orbit1_nacl_a", "orbit1_nacr_a", "orbit2_nacl_a", "orbit2_nacr_a"]   # strip a of both orbits


def test_full_size_example_writes_cubes_once(tmp_path, small_full_size, caplog):
    caplog.set_level(logging.INFO, logger="lunarmap")
    kw = dict(full_size=True, n_control=4, n_check=4, names=FOUR)
    cfg = write_example(tmp_path, **kw)
    text = cfg.read_text()
    assert 'pixels = "mission/orbit2_nacr_a.cub"' in text and 'group = "2-nacr"' in text
    bm = open_block_mission(tmp_path / "mission")
    cube = IsisCube(tmp_path / "mission" / "orbit1_nacl_a.cub")
    assert cube.layout.fmt == "Tile" and cube.layout.dtype == np.uint8 and cube.shape == (1, 256, 5064)
    dn = open_image(cube.path).values[0]
    assert np.all(np.isfinite(dn)) and 40 < np.median(dn) < 120 and dn.min() >= 1 and dn.max() <= 254
    # the cube is a self-contained ISIS cube: its label's Instrument and Kernels groups load the camera
    again = lunarmap.load_camera(cube.path, bm.truth_metakernel)
    from lunarmap.simulate import block_cameras

    truth = block_cameras(bm, "truth", ["orbit1_nacl_a"])["orbit1_nacl_a"]
    g = truth.image_to_ground([10.5, 200.5], [100.5, 4000.5], height=0.0)
    np.testing.assert_allclose(np.column_stack(again.ground_to_image(g)), [[10.5, 100.5], [200.5, 4000.5]], atol=1e-6)
    # the cubes agree at true conjugates across the orbits (20 degrees): 15 x 15 windows, resampled through the
    # local affine map of the truth cameras through the DTM, correlate; 3 px off they do not
    from scipy.ndimage import map_coordinates

    from lunarmap.simulate import block_check_points
    from lunarmap.simulate.truth import true_conjugates
    import xarray as xr

    a, b = "orbit1_nacl_a", "orbit2_nacl_a"
    cams = block_cameras(bm, "truth", [a, b])
    with xr.open_dataarray(tmp_path / "mission" / "dtm.nc") as d:
        dtm = d.load()
    pts = block_check_points(bm, 12, sigma_px=0.0, seed=3, cameras=cams, names=[a, b], dtm=dtm, margin_px=30.0)
    first = pts["image_id"].values == 0
    l1, s1 = np.floor(pts["line_true"].values[first]) + 0.5, np.floor(pts["sample_true"].values[first]) + 0.5
    l2, s2 = true_conjugates(cams[a], cams[b], l1, s1, dtm)
    dl, ds = true_conjugates(cams[a], cams[b], l1 + 1, s1, dtm), true_conjugates(cams[a], cams[b], l1, s1 + 1, dtm)
    ia, ib = dn, open_image(tmp_path / "mission" / f"{b}.cub").values[0]
    uu = np.arange(-7, 8)
    ul, us = np.meshgrid(uu, uu, indexing="ij")

    def ncc(p, q):
        p, q = p - p.mean(), q - q.mean()
        return float((p * q).sum() / np.sqrt((p * p).sum() * (q * q).sum()))

    good, off = [], []
    for k in range(l1.size):
        w1 = ia[int(l1[k]) - 7:int(l1[k]) + 8, int(s1[k]) - 7:int(s1[k]) + 8]
        lw = l2[k] + (dl[0][k] - l2[k]) * ul + (ds[0][k] - l2[k]) * us
        sw = s2[k] + (dl[1][k] - s2[k]) * ul + (ds[1][k] - s2[k]) * us
        good.append(ncc(w1, map_coordinates(ib, [lw - 0.5, sw - 0.5], order=1)))
        off.append(ncc(w1, map_coordinates(ib, [lw + 2.5, sw + 2.5], order=1)))
    assert np.median(good) > 0.9 and np.median(good) - np.median(off) > 0.6, (good, off)
    from lunarmap.adjust import read_network

    net = read_network(tmp_path / "points.nc")
    kinds = list(np.asarray(net.point_type))
    assert kinds.count("control") == 4 and kinds.count("check") == 4
    # a second call rewrites nothing, quickly
    before = _files(tmp_path)
    t = time.perf_counter()
    write_example(tmp_path, **kw)
    assert time.perf_counter() - t < 5.0
    assert _files(tmp_path) == before
    assert "0 part(s) written" in _written(caplog)
    # a touched cube (and only it) is rendered again; a killed render's temporary file is cleaned up
    os.utime(cube.path, ns=(1, 1))
    (tmp_path / "mission" / ".orbit1_nacl_a.cub.x.tmp").write_bytes(b"partial")
    write_example(tmp_path, **kw)
    assert "1 part(s) written (image:orbit1_nacl_a)" in _written(caplog)
    assert not (tmp_path / "mission" / ".orbit1_nacl_a.cub.x.tmp").exists()
    np.testing.assert_array_equal(open_image(cube.path).values[0], dn)    # the same pixels: seeded noise


def test_example_written_once_and_parts_rewritten_by_their_parameters(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="lunarmap")
    kw = dict(quick=True, names=["orbit1_nac"], n_control=2, n_check=2)
    write_example(tmp_path, **kw)
    assert "mission" in _written(caplog) and (tmp_path / EXAMPLE_STATE).is_file()
    before = _files(tmp_path)
    t = time.perf_counter()
    write_example(tmp_path, **kw)
    assert time.perf_counter() - t < 3.0
    assert _files(tmp_path) == before and "0 part(s) written" in _written(caplog)
    # a deleted image: that image (with its site's DTM), nothing else
    (tmp_path / "mission" / "orbit1_nac.nc").unlink()
    write_example(tmp_path, **kw)
    assert "2 part(s) written (image:orbit1_nac, dtm)" in _written(caplog)
    after = _files(tmp_path)
    assert {k for k in after if after[k] != before.get(k)} == {"mission/orbit1_nac.nc", "mission/dtm.nc",
                                                              EXAMPLE_STATE}


def test_example_parts_record(tmp_path):
    """The record of parts: a digest or a file stamp that differs, a missing file or a broken record is not fresh."""
    from lunarmap.workflows.example import _Parts

    (tmp_path / "a.txt").write_text("a")
    parts = _Parts(tmp_path)
    d = parts.digest({"x": 1})
    assert d == parts.digest({"x": 1}) != parts.digest({"x": 2})
    parts.done("a", d, [tmp_path / "a.txt"])
    again = _Parts(tmp_path)
    assert again.fresh("a", d) and not again.fresh("a", parts.digest({"x": 2})) and not again.fresh("b", d)
    (tmp_path / "a.txt").write_text("b")          # same size, new modification time
    assert not _Parts(tmp_path).fresh("a", d)
    (tmp_path / "a.txt").unlink()
    assert not _Parts(tmp_path).fresh("a", d)
    (tmp_path / EXAMPLE_STATE).write_text("{not json")
    assert _Parts(tmp_path).parts == {}


def test_cli_full_size_flag():
    args = build_parser().parse_args(["run", "--example", "--full-size", "--output", "x"])
    assert args.full_size and args.example
    assert not build_parser().parse_args(["demo"]).full_size
