"""Ranger flight parameters -> orientation by the paper's five rotations, and the paper's tables.

Oracles: known orientations (random ones, the synthetic mission's frame images through SPICE, a
Ranger-like simulation) turned into flight parameters and back; closed forms of the geometry
(law of cosines, the nadir's image); the coordinates printed in the paper's Tables II and III.
"""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.errors import FlightParameterError, GeometryError, InvalidInputError
from lunarmap.missions import (FlightParameters, five_rotations, flight_parameters_from_orientation,
                               read_flight_parameters, sensor_to_body, table_coordinates, tilt_from_ranges)
from lunarmap.missions.five_rotations import PHOTO_TO_SENSOR, omega_angle, orientation_angles, paper_step3
from lunarmap.missions.flight_parameters import COLUMNS
from lunarmap.orientation.rotation import rotvec_to_matrix

R_MOON = 1736600.0


def rotation_angle(a, b) -> np.ndarray:
    """Angle (rad) between rotation matrices, accurate for tiny angles (from the skew part)."""
    d = np.asarray(a) @ np.swapaxes(np.asarray(b), -1, -2)
    s = (d - np.swapaxes(d, -1, -2)) / 2
    return np.arcsin(np.clip(np.linalg.norm(np.stack([s[..., 2, 1], s[..., 0, 2], s[..., 1, 0]], -1), axis=-1), 0, 1))


def random_orientations(n, rng, max_tilt_deg=20.0):
    lat, lon = rng.uniform(-89, 89, n), rng.uniform(-180, 180, n)
    alt = rng.uniform(3e3, 400e3, n)
    up = np.column_stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                          np.cos(np.radians(lat)) * np.sin(np.radians(lon)), np.sin(np.radians(lat))])
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east, axis=1)[:, None]
    north = np.cross(up, east)
    nadir = np.stack([east, -north, -up], axis=-1)
    return (R_MOON + alt)[:, None] * up, nadir @ rotvec_to_matrix(rng.normal(0, np.radians(max_tilt_deg) / 2, (n, 3)))


def test_random_orientations_survive_flight_parameters_to_1e_9_rad():
    pos, rot = random_orientations(3000, np.random.default_rng(0))
    table = flight_parameters_from_orientation([f"p{i}" for i in range(3000)], pos, rot, radius=R_MOON)
    back = table.sensor_rotations()
    err = rotation_angle(back, rot)
    print(f"five rotations vs truth: max {err.max():.2e} rad over 3000 orientations, tilts "
          f"{table.tilt.min():.2f}-{table.tilt.max():.2f} deg")
    assert err.max() <= 1e-9
    assert np.abs(table.positions - pos).max() <= 1e-6


def test_synthetic_mission_frames_survive_flight_parameters(sim_mission):
    """The synthetic mission's frame images (orientation from its SPICE kernels): EO -> parameters -> EO."""
    from lunarmap.orientation.drivers import image_support
    from lunarmap.orientation.rotation import quat_to_matrix

    pos, rot = [], []
    for name in ("sim_frame_a", "sim_frame_b"):
        eo = image_support(sim_mission.parent / f"{name}.lbl", sim_mission).exterior_orientation()
        pos.append(eo.positions[0])
        rot.append(quat_to_matrix(eo.quaternions[0]))
    table = flight_parameters_from_orientation(["a", "b"], np.array(pos), np.array(rot), radius=1737400.0)
    err = rotation_angle(table.sensor_rotations(), np.array(rot))
    print(f"synthetic mission frames: {err.max():.2e} rad; tilts {table.tilt}")
    assert err.max() <= 1e-9
    assert np.abs(table.positions - np.array(pos)).max() <= 1e-6
    table.check_consistency(tolerance_deg=1e-9, altitude_tolerance=1e-6)


def test_each_rotation_does_what_the_paper_says():
    rng = np.random.default_rng(3)
    pos, rot = random_orientations(200, rng)
    a = orientation_angles(pos, rot, R_MOON)
    r1, r2, r3, r4, r5 = five_rotations(a["AZN"], a["AZSC"], a["tilt"], a["LATs"], a["LONs"])
    m = r5 @ r4 @ r3 @ r2 @ r1
    assert np.allclose(m, rot @ PHOTO_TO_SENSOR, atol=1e-12)
    # R1: lunar north (after rabatment) is +y'; R2: the nadir point f tan t (cos w, -sin w) goes to the origin
    f = 100.0
    w, t = np.radians(omega_angle(a["AZN"], a["AZSC"])), np.radians(a["tilt"])
    nadir = np.column_stack([f * np.tan(t) * np.cos(w), -f * np.tan(t) * np.sin(w), np.full(w.size, -f)])
    moved = np.einsum("nij,nj->ni", r2, nadir)
    assert np.abs(moved[:, :2]).max() < 1e-9
    # R3 R2 is a rotation; R4 R5 are the local east/north/up at the sub-spacecraft point
    g = r3 @ r2
    assert np.abs(g @ np.swapaxes(g, 1, 2) - np.eye(3)).max() < 1e-12
    up = pos / np.linalg.norm(pos, axis=1)[:, None]
    assert np.allclose((r5 @ r4)[:, :, 2], up, atol=1e-12)
    # the nadir's image lies f tan t from the principal point, along AZS/C (counterclockwise from +y)
    p = np.einsum("nji,nj->ni", m, -up)                      # nadir look in photo coordinates
    xy = -f * p[:, :2] / p[:, 2:]
    assert np.allclose(np.hypot(xy[:, 0], xy[:, 1]), f * np.tan(t), rtol=1e-9)
    az = np.radians(a["AZSC"])
    assert np.allclose(xy / np.hypot(xy[:, 0], xy[:, 1])[:, None], np.column_stack([-np.sin(az), np.cos(az)]),
                       atol=1e-9)


def test_tilt_is_the_law_of_cosines_and_is_stable():
    r, rg = 1760e3, 30e3
    t = tilt_from_ranges(r, rg, R_MOON)
    assert np.cos(np.radians(t)) == pytest.approx((r * r + rg * rg - R_MOON ** 2) / (2 * r * rg), abs=1e-14)
    # a nearly vertical photo: Range exceeds the altitude by only 3.6e-8 m at a tilt of 1e-4 deg; from ranges
    # formed without cancellation the tilt comes back to 1.4e-5 of itself (the plain arccos: to 9e-4)
    tt = np.radians(1e-4)
    g = (r * r - R_MOON ** 2) / (r * np.cos(tt) + np.sqrt(R_MOON ** 2 - r * r * np.sin(tt) ** 2))
    assert tilt_from_ranges(r, g, R_MOON) == pytest.approx(1e-4, rel=2e-5)
    with pytest.raises(GeometryError, match="impossible"):
        tilt_from_ranges(r, (r - R_MOON) * 0.9, R_MOON)


def test_paper_printed_step3_is_first_order():
    """The printed diag(cos phi, cos theta) block differs from the exact one by sin^2 t sin 2w / 4 off the diagonal."""
    t, w = 5.0, 45.0
    exact = five_rotations(0.0, 270.0 - w, t, 0.0, 0.0)[2]
    printed = paper_step3(t, w)
    st = np.sin(np.radians(t))
    assert abs(exact[0, 1] - printed[0, 1]) == pytest.approx(
        st ** 2 * np.sin(np.radians(2 * w)) / (2 * (1 + np.cos(np.radians(t)))), rel=1e-12)
    assert np.allclose(exact[2], printed[2])
    # at w = 0 the two agree
    assert np.allclose(five_rotations(0.0, 270.0, t, 0.0, 0.0)[2], paper_step3(t, 0.0), atol=1e-15)


def test_vertical_photo_north_up():
    """A vertical photo with +y to the north: AZN = 0 and the camera looks straight down."""
    pos = np.array([[R_MOON + 50e3, 0.0, 0.0]])
    rot = np.array([[[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]])   # x east, y south, z down
    a = orientation_angles(pos, rot, R_MOON)
    assert a["tilt"][0] == pytest.approx(0.0, abs=1e-12) and a["AZN"][0] == pytest.approx(0.0, abs=1e-12)
    assert a["Range"][0] == pytest.approx(50e3) and a["Alt"][0] == pytest.approx(50e3)
    assert np.allclose(sensor_to_body(a["AZN"], a["AZSC"], a["tilt"], a["LATs"], a["LONs"]), rot, atol=1e-12)


# -- tables ---------------------------------------------------------------------------------------------

@pytest.fixture()
def table():
    from lunarmap.missions.ranger_simulation import ranger_sequence

    return ranger_sequence().table


@pytest.mark.parametrize("suffix", [".csv", ".nc"])
def test_table_files_round_trip_exactly(table, tmp_path, suffix):
    path = tmp_path / f"fp{suffix}"
    (table.to_csv if suffix == ".csv" else table.to_netcdf)(path)
    back = read_flight_parameters(path)
    assert back.photo == table.photo and back.radius == table.radius
    for c in COLUMNS + ("et",):
        assert np.array_equal(getattr(back, c), getattr(table, c)), c
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def _csv(tmp_path, header, rows, name="fp.csv"):
    p = tmp_path / name
    p.write_text("\n".join([",".join(header)] + [",".join(str(v) for v in r) for r in rows]) + "\n")
    return p


GOOD = ["435", -12.8, -2.3, -12.83, -2.37, 1771999.7, 40870.2, 35399.7, 61.2, 199.8]


def test_good_row_reads_and_names(tmp_path):
    t = read_flight_parameters(_csv(tmp_path, ["photo", *COLUMNS[:-1], "AZS/C"], [GOOD]))
    assert t.photo == ("435",) and t.AZSC[0] == 199.8


def test_missing_columns_are_named(tmp_path):
    p = _csv(tmp_path, ["photo", "LATs", "LONs", "R", "Range", "AZN", "AZSC"], [GOOD[:3] + GOOD[5:7] + GOOD[8:]])
    with pytest.raises(FlightParameterError, match=r"missing column\(s\) LATp, LONp, Alt") as err:
        read_flight_parameters(p)
    assert str(p) in str(err.value)


@pytest.mark.parametrize("col,value,match", [
    ("Range", 30000.0, "Range 30000.0 m is shorter than the altitude Alt 35399.7 m"),
    ("LATs", -91.0, r"\|LATs\| = 91 deg exceeds 90"),
    ("LATp", 95.0, r"\|LATp\| = 95 deg exceeds 90"),
    ("R", 1736000.0, "at or below"),
    ("Range", 400000.0, "horizon"),
    ("AZN", "north", "column AZN = 'north' is not a number"),
    ("Alt", "nan", "column Alt is not a finite number"),
])
def test_impossible_rows_are_named(tmp_path, col, value, match):
    row = list(GOOD)
    row[1 + COLUMNS.index(col)] = value
    with pytest.raises(FlightParameterError, match=match) as err:
        read_flight_parameters(_csv(tmp_path, ["photo", *COLUMNS], [row]))
    assert "photo 435" in str(err.value)


def test_duplicate_photos_and_empty_tables(tmp_path):
    with pytest.raises(FlightParameterError, match="repeat"):
        read_flight_parameters(_csv(tmp_path, ["photo", *COLUMNS], [GOOD, GOOD]))
    with pytest.raises(FlightParameterError, match="no photos"):
        read_flight_parameters(_csv(tmp_path, ["photo", *COLUMNS], []))
    with pytest.raises(FileNotFoundError):
        read_flight_parameters(tmp_path / "absent.csv")


def test_inconsistent_principal_point_is_named(table):
    cols = {c: getattr(table, c).copy() for c in COLUMNS}
    cols["LATp"][1] += 0.05
    bad = FlightParameters.from_columns({"photo": table.photo, **cols}, radius=table.radius)
    with pytest.raises(FlightParameterError, match="photo 437: LATp/LONp lie 0.05 deg"):
        bad.check_consistency()
    ds = table.check_consistency()
    assert float(ds.principal_point_error.max()) < 1e-10


def test_failed_write_leaves_nothing(table, tmp_path):
    with pytest.raises(InvalidInputError, match="does not exist"):
        table.to_csv(tmp_path / "absent" / "fp.csv")
    assert list(tmp_path.iterdir()) == []


# -- the paper's Tables II and III ---------------------------------------------------------------------
# Rows as printed: X', Y', Z' (m), south latitude, west longitude (deg), elevation (m) for the triplet
# 435-437-439 and the pair 435-439. OCR repairs (checked against the printed lat/lon/h of the same row):
# "I" and "l" are 1, "." before digits is 3 (".184,374" = 384,374), "'1" is 9 ("1,692,40'1" = 1,692,409,
# "68,'106" = 68,906, "1,692,0'13" = 1,692,093, "385,24'1" = 385,249); "1.692, 144" = 1,692,344 (the
# printed h of 268 m needs 3xx,xxx). Table II row 10 of the pair and row 2 are the rows these repairs decide.
TABLE_II = [
    ((1692484, 68318, 384381, 12.785, 2.312, 328), (1692450, 68292, 384374, 12.785, 2.311, 292)),
    ((1692416, 68938, 384641, 12.794, 2.333, 343), (1692344, 68890, 384624, 12.794, 2.331, 268)),
    ((1692434, 69135, 384654, 12.794, 2.339, 372), (1692366, 69088, 384638, 12.794, 2.338, 300)),
    ((1692410, 68947, 384784, 12.799, 2.333, 370), (1692333, 68896, 384765, 12.799, 2.331, 289)),
    ((1692420, 69269, 385050, 12.807, 2.344, 452), (1692348, 69224, 385034, 12.807, 2.342, 376)),
    ((1692405, 68135, 385061, 12.808, 2.305, 394), (1692344, 68092, 385047, 12.808, 2.304, 331)),
    ((1692231, 67785, 385401, 12.820, 2.294, 286), (1692185, 67751, 385392, 12.820, 2.293, 238)),
    ((1692237, 67866, 385374, 12.819, 2.297, 289), (1692209, 67846, 385370, 12.819, 2.296, 261)),
    ((1692150, 67317, 385745, 12.832, 2.278, 266), (1692102, 67281, 385736, 12.832, 2.277, 216)),
    ((1692171, 68657, 386316, 12.850, 2.323, 466), (1692093, 68606, 386304, 12.850, 2.322, 385)),
]
TABLE_III = [
    ((1692409, 68251, 384371, 12.786, 2.309, 250), (1692390, 68234, 384365, 12.786, 2.309, 229)),
    ((1692398, 68915, 384637, 12.794, 2.332, 324), (1692389, 68906, 384636, 12.794, 2.332, 315)),
    ((1692389, 69234, 385040, 12.807, 2.343, 418), (1692359, 69212, 385034, 12.807, 2.342, 387)),
    ((1692593, 68222, 385092, 12.807, 2.308, 588), (1692556, 68196, 385080, 12.807, 2.307, 548)),
    ((1692493, 68972, 385249, 12.813, 2.334, 554), (1692481, 68962, 385249, 12.813, 2.333, 542)),
    ((1692238, 67821, 385395, 12.820, 2.295, 293), (1692221, 67809, 385389, 12.820, 2.295, 275)),
    ((1692407, 68543, 385734, 12.829, 2.319, 562), (1692383, 68526, 385727, 12.829, 2.319, 536)),
    ((1692126, 67283, 385749, 12.832, 2.277, 242), (1692108, 67268, 385744, 12.832, 2.277, 223)),
    ((1692090, 68610, 386309, 12.850, 2.322, 383), (1692048, 68580, 386299, 12.850, 2.321, 338)),
]


@pytest.mark.parametrize("name,rows", [("II", TABLE_II), ("III", TABLE_III)])
def test_paper_tables_lat_lon_h_reproduce_to_their_rounding(name, rows):
    """Printed to 0.001 deg and 1 m from X'Y'Z' printed to 1 m: the tolerance is half the last digit plus the
    effect of the coordinates' own rounding (<= 0.5 (|X|+|Y|+|Z|)/r = 0.62 m, 2e-5 deg)."""
    xyz = np.array([p[:3] for row in rows for p in row], float)
    printed = np.array([p[3:] for row in rows for p in row], float)
    lat_s, lon_w, h = table_coordinates(xyz, radius=1736600.0)
    d_lat, d_lon, d_h = np.abs(lat_s - printed[:, 0]), np.abs(lon_w - printed[:, 1]), np.abs(h - printed[:, 2])
    print(f"Table {name}: {len(xyz)} points, max |d lat| {d_lat.max():.5f} deg, |d lon| {d_lon.max():.5f} deg, "
          f"|d h| {d_h.max():.2f} m")
    assert d_lat.max() <= 0.0005 + 2e-5 and d_lon.max() <= 0.0005 + 2e-5
    assert d_h.max() <= 0.5 + 0.62
    # the coordinates say X' -> 0 deg, Y' -> 90 deg W, Z' -> south: lunarmap's frame turned about X
    from lunarmap.camera.geodesy import xyz_to_lonlat_height
    from lunarmap.missions import paper_to_body_fixed

    lon, lat, hh = xyz_to_lonlat_height(paper_to_body_fixed(xyz), 1736600.0)
    assert np.allclose(lat, -lat_s) and np.allclose(lon, -lon_w) and np.allclose(hh, h)
