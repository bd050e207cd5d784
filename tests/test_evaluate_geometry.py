"""Viewing/illumination geometry of images and pairs against independent computations.

* SPICE (``illumf``, ``spkpos``, ``vsep``, ``pxform``) on the synthetic mission's kernels for the
  angles: emission from ``illumf`` with no aberration correction (the cameras' positions are
  geometric: the IK says ``LIGHTTIME_CORRECTION = NONE``), incidence from ``illumf`` with ``LT+S``
  (the ISD's Sun is the LT+S Sun seen from the Moon's centre), phase as ``vsep`` of the SPICE
  observer and Sun vectors, the sub-solar ground azimuth by spherical trigonometry from the
  sub-solar point, off-nadir / slew / convergence from SPICE states, the in-image sub-solar azimuth
  of a pinhole frame image from the IK and ``pxform`` alone;
* closed forms on the simulated symmetric pairs (sphere, analytic circular orbits): convergence,
  emission, slew, B/H, scaled pixel width and height;
* the footprint and overlap areas against an independent integral / a grid count.
"""

from __future__ import annotations

import numpy as np
import pytest
import spiceypy

from lunarmap.camera.factory import camera_from_isd
from lunarmap.camera.geodesy import xyz_to_lonlat_height
from lunarmap.errors import EvaluationInputError, GeometryError, NoOverlapError
from lunarmap.evaluate import candidate_pairs, footprint, image_geometry, overlap, pair_geometry, shadow_tip_distance, view_geometry
from lunarmap.orientation.drivers import image_support
from lunarmap.simulate import look_angle_for_emission, pointed_camera, stereo_pair
from lunarmap.simulate.orbits import GM_MOON, NAC_LINE_TIME
from lunarmap.spice import KernelSet, kernels
from lunarmap.synthetic import FRAME_CAMERA_FRAME, FRAME_CAMERA_ID

RAD_TOL = 1e-6
IMAGES = ["sim_nac_equator", "sim_nac_85n", "sim_frame_a", "sim_frame_b"]
R_MOON = 1737.4e3


@pytest.fixture(scope="module")
def mission(sim_mission):
    out = {}
    for name in IMAGES:
        isd = image_support(sim_mission.parent / f"{name}.lbl", sim_mission)
        out[name] = (isd, camera_from_isd(isd), camera_from_isd(isd, distortion=False))
    return sim_mission, out


def _points(cam, n=12, seed=3):
    rng = np.random.default_rng(seed)
    return cam.image_to_ground(rng.uniform(0, cam.n_lines, n), rng.uniform(0, cam.n_samples, n), height=0.0)


@pytest.mark.parametrize("name", IMAGES)
def test_angles_equal_spice(name, mission):
    mk, cams = mission
    isd, cam, _ = cams[name]
    P = _points(cam)
    g = view_geometry(cam, P, name=name)
    frame = cam.eo.body_frame
    errs = {k: [] for k in ("emission", "incidence", "phase", "subsolar_ground_azimuth", "off_nadir", "slew")}
    with kernels(KernelSet.from_metakernel(mk)):
        for i, p in enumerate(P):
            et, pk = float(g.et[i]), p / 1e3
            e_none = spiceypy.illumf("ELLIPSOID", "MOON", "SUN", et, frame, "NONE", "-990", pk)
            e_lts = spiceypy.illumf("ELLIPSOID", "MOON", "SUN", et, frame, "LT+S", "-990", pk)
            errs["emission"].append(g.emission[i] - e_none[4])
            errs["incidence"].append(g.incidence[i] - e_lts[3])
            sc = spiceypy.spkezr("-990", et, frame, "NONE", "MOON")[0]
            sun = np.asarray(spiceypy.spkpos("SUN", et, frame, "LT+S", "MOON")[0])
            errs["phase"].append(g.phase[i] - spiceypy.vsep(np.asarray(sc[:3]) - pk, sun - pk))
            # sub-solar ground azimuth: initial bearing of the great circle towards the sub-solar point
            lon1, lat1 = spiceypy.reclat(pk)[1:]
            lon2, lat2 = spiceypy.reclat(sun)[1:]
            dl = lon2 - lon1
            az = np.arctan2(np.sin(dl) * np.cos(lat2), np.cos(lat1) * np.sin(lat2) - np.sin(lat1) * np.cos(lat2) * np.cos(dl))
            errs["subsolar_ground_azimuth"].append(np.angle(np.exp(1j * (g.subsolar_ground_azimuth[i] - az))))
            # off-nadir and slew from the SPICE state: nadir is -C, "right" is v x C
            c, v = np.asarray(sc[:3]), np.asarray(sc[3:])
            los, nadir = pk - c, -c
            errs["off_nadir"].append(g.off_nadir[i] - spiceypy.vsep(los, nadir))
            right = np.cross(v, c)
            right /= np.linalg.norm(right)
            errs["slew"].append(g.slew[i] - np.arctan2(los @ right, los @ nadir / np.linalg.norm(nadir)))
    worst = {k: float(np.max(np.abs(v))) for k, v in errs.items()}
    print(name, {k: f"{v:.1e}" for k, v in worst.items()})
    for k, v in worst.items():
        assert v <= RAD_TOL, (k, v)


def test_frame_subsolar_and_north_azimuth_in_the_image_equal_pinhole_projection(mission):
    """In-image azimuths of a distortion-free frame image against a projection built from the IK and pxform."""
    mk, cams = mission
    isd, _, cam = cams["sim_frame_a"]
    P = _points(cam, n=6)
    g = view_geometry(cam, P)
    with kernels(KernelSet.from_metakernel(mk)):
        fname, fid = FRAME_CAMERA_FRAME, FRAME_CAMERA_ID
        f = spiceypy.gdpool(f"INS{fid}_FOCAL_LENGTH", 0, 1)[0]
        its = np.asarray(spiceypy.gdpool(f"INS{fid}_ITRANSS", 0, 3))
        itl = np.asarray(spiceypy.gdpool(f"INS{fid}_ITRANSL", 0, 3))
        et = float(g.et[0])
        M = np.asarray(spiceypy.pxform(cam.eo.body_frame, fname, et))
        C = np.asarray(spiceypy.spkpos("-990", et, cam.eo.body_frame, "NONE", "MOON")[0]) * 1e3
        sun = np.asarray(spiceypy.spkpos("SUN", et, cam.eo.body_frame, "LT+S", "MOON")[0]) * 1e3

    def pix(X):
        v = M @ (X - C)
        x, y = f * v[0] / v[2], f * v[1] / v[2]
        return np.array([itl[1] * x + itl[2] * y, its[1] * x + its[2] * y])   # (line, sample) up to offsets

    worst = 0.0
    for i, p in enumerate(P):
        up = p / np.linalg.norm(p)
        s = sun - p
        s_h = s - (s @ up) * up
        north = np.array([0.0, 0.0, 1.0]) - up[2] * up
        for d, got in ((s_h, g.subsolar_azimuth[i]), (north, g.north_azimuth[i])):
            d = d / np.linalg.norm(d)
            dl, ds = (pix(p + 0.5 * d) - pix(p - 0.5 * d))
            worst = max(worst, abs(np.angle(np.exp(1j * (got - np.arctan2(dl, ds))))))
    print(f"in-image azimuths vs pinhole projection: {worst:.1e} rad")
    assert worst <= RAD_TOL


def _one(da) -> float:
    return float(np.asarray(da).reshape(-1)[0])


def test_convergence_of_the_frame_pair_equals_spice(mission):
    mk, cams = mission
    a, b = cams["sim_frame_a"][1], cams["sim_frame_b"][1]
    ds = pair_geometry({"a": a, "b": b})
    assert ds.sizes["pair"] == 1 and 0.5 < _one(ds.overlap_fraction) < 0.7     # the mission plans 60 % overlap
    P = np.array([_points(a, 30)[k] for k in range(30)])
    P = P[np.isfinite(b.ground_to_image(P)[0])][:8]
    ga, gb = view_geometry(a, P), view_geometry(b, P)
    worst = 0.0
    with kernels(KernelSet.from_metakernel(mk)):
        for i, p in enumerate(P / 1e3):
            ca = np.asarray(spiceypy.spkpos("-990", float(ga.et[i]), a.eo.body_frame, "NONE", "MOON")[0])
            cb = np.asarray(spiceypy.spkpos("-990", float(gb.et[i]), a.eo.body_frame, "NONE", "MOON")[0])
            conv = np.arctan2(np.linalg.norm(np.cross(ga.to_sensor[i], gb.to_sensor[i])),
                              ga.to_sensor[i] @ gb.to_sensor[i])
            worst = max(worst, abs(conv - spiceypy.vsep(ca - p, cb - p)))
    print(f"convergence vs SPICE: {worst:.1e} rad")
    assert worst <= RAD_TOL


# -- closed forms on the simulated symmetric pairs ----------------------------------------------------

@pytest.mark.parametrize("conv", [5.0, 20.0, 45.0, 60.0])
def test_symmetric_pair_closed_forms(conv):
    H = 50e3
    c1, c2 = stereo_pair("linescan", conv, n_lines=512, n_samples=512)
    ds = pair_geometry({"a": c1, "b": c2})
    P = c1.image_to_ground(256.0, 256.0, 0.0)
    ga = view_geometry(c1, P)
    e = np.radians(conv / 2)
    r = R_MOON + H
    theta = np.arcsin(R_MOON / r * np.sin(e))                  # look angle at the sensor
    beta = e - theta                                          # central angle sensor / point
    bh = 2 * r * np.sin(beta) / (r * np.cos(beta) - R_MOON)
    gp = pair_geometry({"a": c1, "b": c2}, point=P)
    errs = {
        "convergence": np.radians(_one(gp.convergence)) - np.radians(conv),
        "emission": _one(ga.emission) - e,
        "slew": _one(ga.slew) + np.radians(look_angle_for_emission(conv / 2, H)),   # rolled left = negative
        "off_nadir": _one(ga.off_nadir) - theta,
    }
    for k, v in errs.items():
        assert abs(v) <= RAD_TOL, (k, v)
    assert _one(gp.base_height) == pytest.approx(bh, rel=1e-9)
    # Becker's parallax/height ratio: the sensors lie on opposite sides, so |tan(e) a1 - tan(e) a2| = 2 tan(e)
    assert _one(gp.parallax_height_ratio) == pytest.approx(2 * np.tan(e), rel=1e-6)
    assert np.radians(90.0 - _one(gp.bisector_elevation)) <= 1e-5     # the bisector is (nearly) vertical
    assert _one(gp.aspect_ratio_ratio) == pytest.approx(1.0, abs=1e-9)   # mirror images: same pixels
    assert _one(ds.convergence) == pytest.approx(conv, abs=0.05)        # at the overlap centroid
    # scaled pixel height: the scene turns rigidly about the orbit normal at the orbit's angular rate
    w = np.sqrt(GM_MOON / r ** 3)
    normal = np.cross(c1.eo.positions[0], c1.eo.velocities[0])
    normal /= np.linalg.norm(normal)
    dist_axis = np.linalg.norm(P - (P @ normal) * normal)
    h_px = 2 * dist_axis * np.sin(0.5 * w * NAC_LINE_TIME)
    # scaled pixel width: samples sweep a great circle across track; look angle atan(y / f) - roll
    f, pitch = 699.62, 0.007
    roll = np.radians(look_angle_for_emission(conv / 2, H))
    b = [np.arcsin(r / R_MOON * np.sin(t)) - t for t in (np.arctan(-0.5 * pitch / f) - roll,
                                                         np.arctan(0.5 * pitch / f) - roll)]
    w_px = 2 * R_MOON * np.sin(0.5 * abs(b[1] - b[0]))
    assert _one(ga.pixel_height) == pytest.approx(h_px, rel=1e-6)
    assert _one(ga.pixel_width) == pytest.approx(w_px, rel=1e-6)


def test_image_geometry_table_and_shadow_tip_distance():
    c = pointed_camera("linescan", 30.0, 0.0, 10.0, n_lines=256, n_samples=256)
    ds = image_geometry({"x": c})
    assert list(ds.image.values) == ["x"]
    assert _one(ds.emission) == pytest.approx(10.0, abs=1e-7)
    assert bool(ds.inside[0])
    # shadow tips: same light -> 0; Sun at 45 deg from opposite azimuths -> 2 tan(45) = 2
    assert shadow_tip_distance(0.5, 1.0, 0.5, 1.0) == 0.0
    assert shadow_tip_distance(np.pi / 4, 0.0, np.pi / 4, np.pi) == pytest.approx(2.0)
    assert shadow_tip_distance(np.pi / 3, 0.3, 0.0, 2.0) == pytest.approx(np.tan(np.pi / 3))


# -- footprints and overlaps ---------------------------------------------------------------------------

def _footprint_integral(cam, n=64):
    """Area of the image on the sphere as the integral of |dG/dl x dG/ds| (midpoint rule, central differences)."""
    nl, ns = cam.n_lines, cam.n_samples
    l = (np.arange(n) + 0.5) * nl / n
    s = (np.arange(n) + 0.5) * ns / n
    L, S = np.meshgrid(l, s, indexing="ij")
    h = 1e-3
    dGl = (cam.image_to_ground(L + h, S) - cam.image_to_ground(L - h, S)) / (2 * h)
    dGs = (cam.image_to_ground(L, S + h) - cam.image_to_ground(L, S - h)) / (2 * h)
    return float(np.sum(np.linalg.norm(np.cross(dGl, dGs), axis=-1)) * (nl / n) * (ns / n))


def test_footprint_area_equals_integral_and_self_overlap():
    cam = pointed_camera("frame", 30.0, 10.0, 0.0)
    fp = footprint(cam)
    ref = _footprint_integral(cam)
    print(f"footprint {fp.area():.1f} m2 vs integral {ref:.1f} m2")
    assert fp.area() == pytest.approx(ref, rel=1e-6)
    ov = overlap(fp, fp)      # convex hulls: the pinhole footprint's edges bow inwards by centimetres
    assert ov.area == pytest.approx(fp.area(), rel=1e-4) and ov.fraction == pytest.approx(1.0)


def test_overlap_of_shifted_frames_equals_grid_count():
    a = pointed_camera("frame", 30.0, 10.0, 0.0)
    b = pointed_camera("frame", 30.04, 10.02, 0.0)
    ov = overlap(footprint(a), footprint(b))
    # count a fine lon/lat grid of points seen inside both images; each cell's area on the sphere
    lon = np.linspace(29.85, 30.2, 500)
    lat = np.linspace(9.9, 10.12, 500)
    LON, LAT = np.meshgrid(lon, lat)
    X = np.stack([np.cos(np.radians(LAT)) * np.cos(np.radians(LON)), np.cos(np.radians(LAT)) * np.sin(np.radians(LON)),
                  np.sin(np.radians(LAT))], -1) * R_MOON
    both = np.isfinite(a.ground_to_image(X)[0]) & np.isfinite(b.ground_to_image(X)[0])
    cell = R_MOON ** 2 * np.radians(lon[1] - lon[0]) * np.radians(lat[1] - lat[0]) * np.cos(np.radians(LAT))
    ref = float(np.sum(cell[both]))
    print(f"overlap {ov.area:.0f} m2 vs grid {ref:.0f} m2")
    assert 0.2 < ov.fraction < 0.9
    assert ov.area == pytest.approx(ref, rel=5e-3)
    lon_c, lat_c, _ = xyz_to_lonlat_height(ov.centroid)
    assert 30.0 < lon_c < 30.04 and 10.0 < lat_c < 10.02


def test_candidate_pairs_keep_every_overlapping_pair_and_drop_most_others():
    """Oracle: a pair overlaps when a 24 x 24 grid of image a, at height 0, lands inside image b."""
    rng = np.random.default_rng(5)
    cams = {}
    for k in range(40):
        kind = "frame" if k % 2 else "linescan"
        cams[f"im{k}"] = pointed_camera(kind, 30.0 + rng.uniform(-0.6, 0.6), 10.0 + rng.uniform(-0.6, 0.6),
                                        rng.uniform(-30.0, 30.0))
    fps = {n: [footprint(c)] for n, c in cams.items()}
    got = set(candidate_pairs(fps))
    names = list(cams)
    g = (np.arange(24) + 0.5) / 24
    overlapping = set()
    for i, a in enumerate(names):
        L, S = np.meshgrid(g * cams[a].n_lines, g * cams[a].n_samples, indexing="ij")
        X = cams[a].image_to_ground(L.ravel(), S.ravel(), height=0.0)
        for b in names[i + 1:]:
            li, sa = cams[b].ground_to_image(X, on_miss="nan")
            inside = np.isfinite(li) & (li >= 0) & (li <= cams[b].n_lines) & (sa >= 0) & (sa <= cams[b].n_samples)
            if inside.any():
                overlapping.add((a, b))
    n_all = len(names) * (len(names) - 1) // 2
    print(f"{len(overlapping)} overlapping pairs, {len(got)} candidates, {n_all} pairs")
    assert overlapping and overlapping <= got
    assert len(got) < 0.5 * n_all
    assert all(names.index(a) < names.index(b) for a, b in got)
    # an image of unknown footprint pairs with every other
    fps["im3"] = None
    got = set(candidate_pairs(fps))
    assert {p for p in got if "im3" in p} == {tuple(sorted(("im3", n), key=names.index)) for n in names if n != "im3"}


def test_bad_input_no_overlap_single_image_unknown_names():
    a = pointed_camera("frame", 30.0, 10.0, 0.0)
    far = pointed_camera("frame", 31.0, 10.0, 0.0)
    with pytest.raises(EvaluationInputError, match="two images"):
        pair_geometry({"a": a})
    ds = pair_geometry({"a": a, "far": far})
    assert ds.sizes["pair"] == 0 and ds.attrs["skipped"] == ["a/far: no overlap"]
    with pytest.raises(NoOverlapError, match="a and far"):
        pair_geometry({"a": a, "far": far}, on_no_overlap="raise")
    with pytest.raises(EvaluationInputError, match="unknown image"):
        pair_geometry({"a": a, "far": far}, pairs=[("a", "b")])
    with pytest.raises(EvaluationInputError, match="not a SensorModel"):
        image_geometry({"a": object()})
    # a point on the far side of the Moon is not seen
    with pytest.raises(GeometryError, match="not seen"):
        view_geometry(a, -a.image_to_ground(144.0, 192.0), name="a")
