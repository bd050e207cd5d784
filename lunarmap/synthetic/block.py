"""The synthetic imaging block: one site seen on consecutive orbits by three cameras (the truth model).

The LUNARMAP-SIM orbiter (same spacecraft, clock, Moon and Sun as
:func:`lunarmap.synthetic.write_mission`, a new set of cameras, see
:mod:`.block_cameras`) flies a near-circular polar orbit about 50 km up.
On each of ``orbits`` consecutive northbound passes over a mid-latitude
site (default 57 N, on the sunlit side: the orbit plane is
:data:`SUN_OFFSET_DEG` from the subsolar meridian, so the Sun is about 57
degrees from the zenith) the bus is rolled about its +x axis (roughly the
ground-track direction) so that the NAC's boresight passes over the site;
the Moon turns about 1.03 degrees of longitude per orbit, so the tracks of
consecutive orbits are about 17 km apart at 57 N and the rolls differ by
about 20 degrees: cross-orbit stereo with convergence angles of about 20
degrees between consecutive orbits and 40 degrees between the first and the
third (up to 42 with the cameras' 6-degree pitches). The site sits :data:`SITE_TRACK_OFFSET_M` off the middle orbit's
ground track (midway between the tracks for an even number of orbits), so
every pass is rolled.

Per orbit four images see the site (names ``orbit<k>_<kind>``):

* ``nac`` - the NAC-like pushbroom, centred on the site at the pass's
  reference epoch ``t_o``;
* ``tc`` - the Kaguya-TC-like pushbroom, pitched forward, a few seconds earlier;
* ``frame_a``, ``frame_b`` - the Clementine-like frame camera, pitched aft, a
  few seconds later, 40 % of a frame apart along track (60 % overlap).

Pushbroom line times give square ground pixels at the image centre. The bus
attitude is nadir pointing (+z to the Moon's centre, +x along the
ground-track velocity) with the same slow wobble as the single-image mission,
turned by the pass's roll (constant over the pass). Attitude kernels cover
only the passes (:data:`PASS_HALF_WIDTH` seconds either side of ``t_o``).

Several sites (``sites=n``, up to :data:`MAX_SITES`): site 1 is the site
above; site ``k`` lies ``(k - 1) * site_spacing_deg`` degrees of latitude
from it (default :data:`SITE_SPACING_DEG`, southward, so about 150 s of
flight apart), placed relative to the tracks at its own latitude exactly as
site 1 is. On every orbit the bus points the NAC at each site in turn with
the roll that site needs, constant over a window of
:data:`MULTI_SITE_HALF_WIDTH` seconds either side of the site's reference
epoch, and slews between sites outside the windows (the attitude kernels
have gaps there). Every site is seen by the same four images per orbit
(names ``s<k>_orbit<o>_<kind>``); sites are hundreds of kilometres apart, so
images of different sites never overlap. The navigation errors stay per
orbit (one offset and drift per orbit, about one reference epoch midway
between the orbit's first and last site); their drifts then act over
minutes, so the default magnitudes for several sites are
:data:`MULTI_SITE_NAVIGATION` (drifts ten times smaller).

Everything here is numpy; :mod:`.block_writing` writes the kernels.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from ..errors import InvalidInputError
from . import textkernels
from .attitude import NadirAttitude
from .block_cameras import (
    BLOCK_CAMERAS,
    BLOCK_FRAME,
    BLOCK_NAC,
    BLOCK_TC,
    FULL_NAC_LINES,
    FULL_SIZE_CAMERAS,
    BlockCameraSpec,
)
from .bodies import MOON_RADIUS_KM, frame_rotation, j2000_to_iau_moon, moon_spin_rate, moon_state_ssb, sun_state_ssb
from .mission import ALTITUDE_KM, FRAME_EXPOSURE_MS, MISSION_START_TDB, ImageTiming, tdb_to_et
from .nav_errors import NavigationErrors, NavigationErrorSpec, draw_navigation_errors
from .orbit import KeplerOrbit

__all__ = [
    "BlockImagePlan", "BlockPass", "BlockSite", "BlockModel", "build_block_model", "block_geometry",
    "SITE_LATITUDE_DEG", "SUN_OFFSET_DEG", "MAX_SITES", "SITE_SPACING_DEG", "MULTI_SITE_HALF_WIDTH",
    "MIN_SITE_HALF_WIDTH",
    "MIN_SLEW_S", "MULTI_SITE_NAVIGATION", "image_name", "image_footprint",
    "SITE_TRACK_OFFSET_M", "PASS_HALF_WIDTH", "BLOCK_ORBITS", "PUSHBROOM_LINES", "FRAME_ADVANCE",
    "TRUTH_SPK_STEP", "TRUTH_CK_STEP", "NAV_SPK_STEP", "NAV_CK_STEP", "SPK_MARGIN", "LAYOUTS",
    "FULL_SIZE_ORBIT_STAGGER", "FULL_SIZE_ORBITS",
]

#: roll, pitch, yaw-like triples (angles, wobble amplitudes/periods/phases)
_Vec3 = tuple[float, float, float]

#: Default site latitude, degrees (planetocentric).
SITE_LATITUDE_DEG = 57.0
#: Angle between the orbit plane's sunlit half and the subsolar meridian, degrees.
SUN_OFFSET_DEG = 15.0
#: Distance of the site from the middle orbit's ground track (odd number of orbits), m.
SITE_TRACK_OFFSET_M = 2000.0
#: Half-width of each pass (the attitude and navigation kernels' coverage around ``t_o``), s.
PASS_HALF_WIDTH = 300.0
#: Default number of orbits.
BLOCK_ORBITS = 3
#: Lines of each pushbroom image.
PUSHBROOM_LINES = 512
#: Along-track distance between frame_a and frame_b, in frame footprints.
FRAME_ADVANCE = 0.4
#: Record spacing of the truth SPK (continuous over the coverage) and CK (per pass), s.
TRUTH_SPK_STEP = 10.0
TRUTH_CK_STEP = 0.5
#: Record spacing of the navigation SPK and CK (per pass), s: they resolve the errors' random part
#: (periods >= 20 s) to below 1 mm and 1 nrad.
NAV_SPK_STEP = 1.0
NAV_CK_STEP = 0.25
#: Truth SPK coverage beyond the first and last pass, s.
SPK_MARGIN = 600.0
#: Most sites per block.
MAX_SITES = 48
#: Default latitude step from one site to the next, degrees (negative: southward; about 150 s of flight).
SITE_SPACING_DEG = -8.0
#: Half-width of each pass window of a block of several sites (constant roll, kernel coverage), s;
#: ``site_half_width_s`` sets another (at least :data:`MIN_SITE_HALF_WIDTH`).
MULTI_SITE_HALF_WIDTH = 45.0
#: Shortest pass half-width: the TC sees a site about 3.3 s before the NAC, the frame camera 3.3 s after.
MIN_SITE_HALF_WIDTH = 8.0
#: Shortest gap between the pass windows of consecutive sites (the slew), s.
MIN_SLEW_S = 20.0
#: Default navigation errors of a block of several sites: the single-site defaults with ten times smaller
#: drifts (they act over the minutes between sites, not the seconds between images of one site: at most
#: about 25 m and 25 urad at the outer sites of four, as much as the offsets).
MULTI_SITE_NAVIGATION = NavigationErrorSpec(position_drift_m_per_s=(0.02, 0.1),
                                            attitude_drift_rad_per_s=(0.02e-6, 0.1e-6))

#: Image layouts: ``"block"`` (four ~1 m-pixel images of three cameras per pass, the default) and
#: ``"full_size"`` (full-size LRO-NAC-like NAC-L and NAC-R images, two along-track strips per pass).
LAYOUTS = ("block", "full_size")
#: Along-track shift between the strips of consecutive orbits in the full-size layout, fraction of an image.
#: The two strips of one pass follow each other without overlap (an overlap would be the same exposures
#: twice: rays from the same place, no parallax), so the other orbit's strips straddle their seam.
FULL_SIZE_ORBIT_STAGGER = 0.2
#: Default orbits of the full-size layout.
FULL_SIZE_ORBITS = 2

_KINDS = ("nac", "tc", "frame_a", "frame_b")
Array = NDArray[np.float64]


def _unit(v: Array) -> Array:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _ray_sphere(origin: Array, direction: Array, radius: float) -> Array:
    """Nearest intersection of rays with a sphere about the origin (NaN where missed), same units."""
    d = _unit(direction)
    b = np.sum(origin * d, axis=-1)
    c = np.sum(origin * origin, axis=-1) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        s = -b - np.sqrt(disc)
    s = np.where((disc >= 0.0) & (s > 0.0), s, np.nan)
    return origin + s[..., None] * d


def _lonlat_to_xyz(lon_deg: float, lat_deg: float, radius: float) -> Array:
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    return radius * np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def _east_north(lon_deg: float, lat_deg: float) -> tuple[Array, Array]:
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    return east, north


def image_name(site: int, orbit: int, kind: str, sites: int) -> str:
    """An image's name: ``orbit<o>_<kind>`` in a one-site block, ``s<site>_orbit<o>_<kind>`` otherwise."""
    return f"orbit{orbit}_{kind}" if sites == 1 else f"s{site}_orbit{orbit}_{kind}"


@dataclass(frozen=True)
class BlockImagePlan(ImageTiming):
    """One image of the block (planned times; the manifest has the label times).

    Parameters
    ----------
    name : str
        ``orbit<k>_<kind>`` (``s<site>_orbit<k>_<kind>`` with several sites); the label is ``<name>.lbl``.
    camera : BlockCameraSpec
    orbit : int
        1-based orbit number.
    kind : str
        ``'nac'``, ``'tc'``, ``'frame_a'`` or ``'frame_b'``.
    lines : int
    center_et : float
        Planned centre time, ET.
    line_time : float or None
        Pushbroom line period, s (whole nanoseconds).
    exposure : float or None
        Frame exposure, s.
    site : int
        1-based site the image sees.
    """

    name: str
    camera: BlockCameraSpec
    orbit: int
    kind: str
    lines: int
    center_et: float
    line_time: float | None
    exposure: float | None
    site: int = 1


@dataclass(frozen=True)
class BlockPass:
    """One pass over a site.

    Parameters
    ----------
    orbit : int
        1-based orbit number.
    epoch : float
        The NAC boresight meets the site (height 0), ET (``t_o`` of a one-site block).
    roll_deg : float
        Bus roll about its +x axis during the pass, degrees.
    start_et, end_et : float
        The pass window (``epoch -/+`` :data:`PASS_HALF_WIDTH`, or :data:`MULTI_SITE_HALF_WIDTH` with
        several sites).
    site : int
        1-based site.
    """

    orbit: int
    epoch: float
    roll_deg: float
    start_et: float
    end_et: float
    site: int = 1


@dataclass(frozen=True)
class BlockSite:
    """One site of the block.

    Parameters
    ----------
    site : int
        1-based number.
    latitude_deg, longitude_deg : float
        The site (planetocentric), degrees.
    extent_m : float
        Side of the square around the site that every footprint of its images fits in, m.
    extent_east_m, extent_north_m : float, optional
        Sides of the rectangle (east-west, north-south) that every footprint fits in, m, when it is
        not that square (the full-size layout's long strips); see :attr:`extents`.
    """

    site: int
    latitude_deg: float
    longitude_deg: float
    extent_m: float = 0.0
    extent_east_m: float | None = None
    extent_north_m: float | None = None

    @property
    def extents(self) -> tuple[float, float]:
        """East-west and north-south sides of the rectangle about the site holding its footprints, m."""
        return (self.extent_m if self.extent_east_m is None else self.extent_east_m,
                self.extent_m if self.extent_north_m is None else self.extent_north_m)


@dataclass(frozen=True)
class BlockModel:
    """Truth (and navigation) model of the block, all numpy.

    Parameters
    ----------
    seed : int
    orbits : int
    site_latitude_deg, site_longitude_deg : float
        The site (site 1), degrees.
    site_extent_m : float
        Side of the square around the site (site 1) that every footprint of its images fits in, m.
    start_et, end_et : float
        Truth SPK coverage, ET.
    sclk_zero_et : float
    orbit : KeplerOrbit
    nadir : NadirAttitude
        The unrolled bus attitude (never yaw-flipped).
    passes : tuple of BlockPass
    mounting_angles_deg : dict
        Instrument id -> TK angles (about bus x, y, z), degrees.
    images : tuple of BlockImagePlan
    navigation : NavigationErrors
    navigation_spec : NavigationErrorSpec
    cameras : tuple of BlockCameraSpec
    sites : tuple of BlockSite
        Every site (site 1 first).
    site_spacing_deg : float
        Latitude step between consecutive sites, degrees (0 with one site).
    layout : str
        One of :data:`LAYOUTS`.
    """

    seed: int
    orbits: int
    site_latitude_deg: float
    site_longitude_deg: float
    site_extent_m: float
    start_et: float
    end_et: float
    sclk_zero_et: float
    orbit: KeplerOrbit
    nadir: NadirAttitude
    passes: tuple[BlockPass, ...]
    mounting_angles_deg: dict[int, tuple[float, float, float]]
    images: tuple[BlockImagePlan, ...]
    navigation: NavigationErrors
    navigation_spec: NavigationErrorSpec
    cameras: tuple[BlockCameraSpec, ...] = field(default=BLOCK_CAMERAS)
    sites: tuple[BlockSite, ...] = ()
    site_spacing_deg: float = 0.0
    layout: str = "block"

    # -- truth -------------------------------------------------------------------
    def state(self, et: ArrayLike) -> Array:
        """True spacecraft state relative to the Moon, J2000, km and km/s; shape ``et.shape + (6,)``."""
        return self.orbit.state(et)

    def pass_index(self, et: ArrayLike) -> NDArray[np.intp]:
        """0-based pass of each epoch; raises outside every pass (no attitude is defined there)."""
        et = np.asarray(et, dtype=float)
        w = np.array([[p.start_et, p.end_et] for p in self.passes]).reshape(-1, 2)
        # 1 s of slack, as the navigation errors have, for derivatives at the window ends
        inside = (et[..., None] >= w[:, 0] - 1.0) & (et[..., None] <= w[:, 1] + 1.0)
        if not np.all(inside.any(axis=-1)):
            bad = et[~inside.any(axis=-1)]
            raise InvalidInputError(f"ET {bad.ravel()[:3]} is outside every pass of the block "
                                    f"(windows {w.tolist()}): the bus attitude is defined only there")
        return np.argmax(inside, axis=-1)

    def roll(self, et: ArrayLike) -> Array:
        """Bus roll at ``et``, rad."""
        rolls = np.radians([p.roll_deg for p in self.passes])
        return rolls[self.pass_index(et)]

    def bus_matrix(self, et: ArrayLike) -> Array:
        """True J2000 -> bus matrices (``pxform('J2000', 'SIM_SC_BUS', et)`` of the truth CK)."""
        et = np.asarray(et, dtype=float)
        return frame_rotation(self.roll(et), 1) @ self.nadir.matrix(et)

    def bus_angular_velocity(self, et: ArrayLike) -> Array:
        """True bus angular velocity relative to J2000, J2000 components, rad/s.

        The roll is constant over a pass, so it leaves the angular velocity of the nadir attitude unchanged.
        """
        self.pass_index(et)
        return self.nadir.angular_velocity(np.asarray(et, dtype=float))

    def mounting(self, naif_id: int) -> Array:
        """Bus -> instrument matrix of a camera (its TK frame; SPICE's ANGLES with AXES (1, 2, 3))."""
        if naif_id not in self.mounting_angles_deg:
            raise InvalidInputError(f"no instrument {naif_id} in the block; have {sorted(self.mounting_angles_deg)}")
        a = np.radians(self.mounting_angles_deg[naif_id])
        return frame_rotation(-a[2], 3) @ frame_rotation(-a[1], 2) @ frame_rotation(-a[0], 1)

    def camera(self, naif_id: int) -> BlockCameraSpec:
        for c in self.cameras:
            if c.naif_id == naif_id:
                return c
        raise InvalidInputError(f"no instrument {naif_id} in the block")

    def position_body_fixed(self, et: ArrayLike) -> Array:
        """True spacecraft position, body-fixed (IAU_MOON), metres."""
        et = np.asarray(et, dtype=float)
        return np.einsum("...ij,...j->...i", j2000_to_iau_moon(et), self.state(et)[..., :3]) * 1000.0

    def sensor_to_body(self, naif_id: int, et: ArrayLike) -> Array:
        """True rotation sensor frame -> body-fixed frame (what an ISD's EO holds)."""
        et = np.asarray(et, dtype=float)
        inst = self.mounting(naif_id) @ self.bus_matrix(et)
        return j2000_to_iau_moon(et) @ np.swapaxes(inst, -1, -2)

    # -- navigation ----------------------------------------------------------------
    def navigation_state(self, et: ArrayLike) -> Array:
        """Navigation state (truth + error), J2000, km and km/s."""
        et = np.asarray(et, dtype=float)
        b = j2000_to_iau_moon(et)
        h = 0.5  # s; B turns at 2.7e-6 rad/s, so the central difference is exact to ~1e-17 relative
        db = (j2000_to_iau_moon(et + h) - j2000_to_iau_moon(et - h)) / (2.0 * h)
        e, de = self.navigation.position(et), self.navigation.position_rate(et)
        bt, dbt = np.swapaxes(b, -1, -2), np.swapaxes(db, -1, -2)
        dp = np.einsum("...ij,...j->...i", bt, e) / 1000.0
        dv = (np.einsum("...ij,...j->...i", bt, de) + np.einsum("...ij,...j->...i", dbt, e)) / 1000.0
        return self.state(et) + np.concatenate([dp, dv], axis=-1)

    def navigation_bus_matrix(self, et: ArrayLike) -> Array:
        """Navigation J2000 -> bus matrices, ``Rv(th)^T C_true``."""
        et = np.asarray(et, dtype=float)
        th = self.navigation.attitude(et)
        rv = Rotation.from_rotvec(th.reshape(-1, 3)).as_matrix().reshape(th.shape + (3,))
        return np.swapaxes(rv, -1, -2) @ self.bus_matrix(et)

    def navigation_bus_angular_velocity(self, et: ArrayLike) -> Array:
        """Navigation bus angular velocity relative to J2000, J2000 components, rad/s (central differences)."""
        et = np.asarray(et, dtype=float)
        h = 0.05
        c = self.navigation_bus_matrix(et)
        dc = (self.navigation_bus_matrix(et + h) - self.navigation_bus_matrix(et - h)) / (2.0 * h)
        s = -np.swapaxes(c, -1, -2) @ dc
        return 0.5 * np.stack([s[..., 2, 1] - s[..., 1, 2], s[..., 0, 2] - s[..., 2, 0],
                               s[..., 1, 0] - s[..., 0, 1]], axis=-1)

    def attitude_error_body_fixed(self, et: ArrayLike) -> Array:
        """``w = B C_true^T th``: the navigation attitude error as a body-fixed rotation vector, rad."""
        et = np.asarray(et, dtype=float)
        m = j2000_to_iau_moon(et) @ np.swapaxes(self.bus_matrix(et), -1, -2)
        return np.einsum("...ij,...j->...i", m, self.navigation.attitude(et))

    def orbit_frame(self, et: ArrayLike) -> Array:
        """Rows: along-track, cross-track, radial unit vectors (body-fixed) of the true orbit at ``et``.

        Along-track is the horizontal part of the velocity relative to the
        rotating Moon, radial points away from the Moon's centre and
        ``cross = radial x along``.
        """
        et = np.asarray(et, dtype=float)
        b = j2000_to_iau_moon(et)
        st = self.state(et)
        r = np.einsum("...ij,...j->...i", b, st[..., :3])
        pole = b[..., 2, :]
        v_j = st[..., 3:] - moon_spin_rate() * np.cross(pole, st[..., :3])
        v = np.einsum("...ij,...j->...i", b, v_j)
        up = _unit(r)
        along = _unit(v - np.sum(v * up, axis=-1, keepdims=True) * up)
        cross = np.cross(up, along)
        return np.stack([along, cross, up], axis=-2)

    # -- images ------------------------------------------------------------------
    def image(self, name: str) -> BlockImagePlan:
        for im in self.images:
            if im.name == name:
                return im
        raise InvalidInputError(f"no image {name!r} in the block; have {[i.name for i in self.images]}")

    @property
    def image_names(self) -> tuple[str, ...]:
        return tuple(im.name for im in self.images)

    def tick_aligned(self, et: float) -> float:
        """The clock tick (1/65536 s) nearest to ``et``, as ET."""
        ticks = round((et - self.sclk_zero_et) * textkernels.SCLK_MODULI[1])
        return self.sclk_zero_et + ticks / textkernels.SCLK_MODULI[1]

    @property
    def n_sites(self) -> int:
        return max(1, len(self.sites))

    def site(self, site: int = 1) -> BlockSite:
        """Site ``site`` (1-based)."""
        for s in self.sites:
            if s.site == site:
                return s
        if site == 1 and not self.sites:  # a model under construction
            return BlockSite(1, self.site_latitude_deg, self.site_longitude_deg, self.site_extent_m)
        raise InvalidInputError(f"no site {site!r} in the block; it has sites 1 to {self.n_sites}")

    def site_xyz(self, height: float = 0.0, site: int = 1) -> Array:
        """Site ``site``, body-fixed metres, at ``height`` metres above the reference sphere."""
        s = self.site(site)
        return _lonlat_to_xyz(s.longitude_deg, s.latitude_deg, MOON_RADIUS_KM * 1000.0 + height)

    def pass_of(self, orbit: int, site: int = 1) -> BlockPass:
        """The pass of ``orbit`` over ``site``."""
        for p in self.passes:
            if p.orbit == orbit and p.site == site:
                return p
        raise InvalidInputError(f"no pass of orbit {orbit!r} over site {site!r} in the block")

    def site_image_names(self, site: int) -> tuple[str, ...]:
        """The images of one site, in block order."""
        self.site(site)
        return tuple(im.name for im in self.images if im.site == site)

    def bus_ground(self, et: ArrayLike, look: ArrayLike = (0.0, 0.0, 1.0)) -> Array:
        """Where a bus-frame look vector (default the bus +z axis) meets the reference sphere, body-fixed m."""
        et = np.asarray(et, dtype=float)
        m = j2000_to_iau_moon(et) @ np.swapaxes(self.bus_matrix(et), -1, -2)
        d = np.einsum("...ij,j->...i", m, np.asarray(look, dtype=float))
        return _ray_sphere(self.position_body_fixed(et), d, MOON_RADIUS_KM * 1000.0)

    def pointing_ground(self, et: ArrayLike) -> Array:
        """The ground point the bus is pointed at the site with: the NAC's boresight, or the bus +z axis
        (between the full-size layout's NAC-L and NAC-R)."""
        return self.boresight_ground(BLOCK_NAC.naif_id, et) if self.layout == "block" else self.bus_ground(et)

    def boresight_ground(self, naif_id: int, et: ArrayLike, look: ArrayLike = (0.0, 0.0, 1.0)) -> Array:
        """Where a sensor-frame look vector meets the reference sphere, body-fixed m (truth, no distortion)."""
        et = np.asarray(et, dtype=float)
        d = np.einsum("...ij,j->...i", self.sensor_to_body(naif_id, et), np.asarray(look, dtype=float))
        return _ray_sphere(self.position_body_fixed(et), d, MOON_RADIUS_KM * 1000.0)

    def sun_direction_body_fixed(self, et: float) -> Array:
        """Unit vector Moon -> Sun (geometric), body-fixed."""
        s = sun_state_ssb(et)[:3] - moon_state_ssb(et)[:3]
        return _unit(j2000_to_iau_moon(et) @ s)


# -- construction ----------------------------------------------------------------

def _latitude_crossing(orbit: KeplerOrbit, lat_deg: float, revolution: int, start_arg_lat: float) -> float:
    """Time of the northbound crossing of a latitude in a revolution (1 = first after the epoch)."""
    u = np.radians(lat_deg) + 2.0 * np.pi * (revolution - 1)
    guess = orbit.epoch + (u - start_arg_lat) / orbit.mean_motion

    def f(t: float) -> float:
        p = j2000_to_iau_moon(t) @ orbit.state(np.asarray(t))[:3]
        return float(np.degrees(np.arcsin(p[2] / np.linalg.norm(p))) - lat_deg)

    return float(brentq(f, guess - 150.0, guess + 150.0, xtol=1e-7, rtol=1e-15))


def _is_int(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, np.integer))


def _is_number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and bool(np.isfinite(v))


def _check_args(seed: Any, orbits: Any, latitude: Any, sites: Any = 1, spacing: Any = SITE_SPACING_DEG,
                half_width: Any = None, layout: Any = "block") -> None:
    if layout not in LAYOUTS:
        raise InvalidInputError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if layout == "full_size" and sites != 1:
        raise InvalidInputError(f"the full-size layout has one site, got sites={sites!r}")
    if not _is_int(seed) or seed < 0:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    if not _is_int(orbits) or not 2 <= orbits <= 4:
        raise InvalidInputError(f"orbits must be an integer from 2 to 4, got {orbits!r}")
    if not _is_number(latitude) or not 10.0 <= abs(latitude) <= 75.0:
        raise InvalidInputError(f"site latitude must be a number with 10 <= |latitude| <= 75 degrees "
                                f"(consecutive tracks must stay within ~30 km), got {latitude!r}")
    if not _is_int(sites) or not 1 <= sites <= MAX_SITES:
        raise InvalidInputError(f"sites must be an integer from 1 to {MAX_SITES}, got {sites!r}")
    if half_width is not None and (not _is_number(half_width) or not half_width >= MIN_SITE_HALF_WIDTH):
        raise InvalidInputError(f"site_half_width_s must be a number >= {MIN_SITE_HALF_WIDTH:g} s (the TC and the "
                                f"frame camera see a site a few seconds before and after the NAC), got {half_width!r}")
    if sites > 1:
        if not _is_number(spacing) or not 1.0 <= abs(spacing) <= 20.0:
            raise InvalidInputError(f"site_spacing_deg must be a number with 1 <= |spacing| <= 20 degrees "
                                    f"(the pass windows and a slew between sites must fit), got {spacing!r}")
        lats = [float(latitude) + k * float(spacing) for k in range(int(sites))]
        # site 1 as above; the others may cross the equator, where the tracks are 31 km apart
        bad = [lat for lat in lats if not abs(lat) <= 75.0]
        if bad:
            raise InvalidInputError(f"site latitudes {[round(v, 6) for v in lats]} (site_latitude_deg "
                                    f"{latitude!r}, site_spacing_deg {spacing!r}, {sites} sites) leave "
                                    f"|latitude| <= 75 degrees at {bad}")


def build_block_model(seed: int = 0, *, orbits: int = BLOCK_ORBITS, site_latitude_deg: float = SITE_LATITUDE_DEG,
                      navigation: NavigationErrorSpec | None = None, sites: int = 1,
                      site_spacing_deg: float = SITE_SPACING_DEG,
                      site_half_width_s: float | None = None, layout: str = "block") -> BlockModel:
    """The truth and navigation model of the imaging block (no files, no SPICE).

    Parameters
    ----------
    seed : int
        Seed of every random choice (orbit perturbations, wobble, camera
        misalignments, navigation errors).
    orbits : int
        Consecutive orbits over the site, 2 to 4.
    site_latitude_deg : float
        Latitude of the site (site 1), degrees (``10 <= |lat| <= 75``).
    navigation : NavigationErrorSpec, optional
        Magnitudes of the navigation errors (defaults: see the class; with
        several sites :data:`MULTI_SITE_NAVIGATION`).
    sites : int
        Sites along the ground track, 1 to :data:`MAX_SITES`; each is seen on
        every orbit by the same four images.
    site_spacing_deg : float
        Latitude of site ``k + 1`` minus that of site ``k``, degrees
        (``1 <= |spacing| <= 20``; ignored with one site). Site 1 must
        satisfy ``10 <= |lat| <= 75``, the others ``|lat| <= 75``; the pass
        windows of consecutive sites must leave :data:`MIN_SLEW_S` between them.
    site_half_width_s : float, optional
        Half-width of each pass window of a block of several sites, seconds
        (default :data:`MULTI_SITE_HALF_WIDTH`; at least :data:`MIN_SITE_HALF_WIDTH`):
        shorter windows let sites lie closer (e.g. 12 s and 2.5 degrees: 40 sites, 480 images).
    layout : str
        ``"block"`` (default): per pass the NAC-like, TC-like and two frame images of ~1 m pixels.
        ``"full_size"`` (one site): per pass four full-size LRO-NAC-like images (52,224 lines x
        5,064 samples, ~0.5 m pixels), NAC-L and NAC-R side by side (their footprints overlap by
        ~140 pixels) in two along-track strips that follow each other (one line apart); the strips
        of consecutive orbits are shifted along track by :data:`FULL_SIZE_ORBIT_STAGGER` of an image,
        so that every strip overlaps both strips of the other orbit. The bus +z axis (between the
        two NACs) is pointed at the site at each pass's reference epoch. Names ``orbit<k>_nacl_a``, ``orbit<k>_nacr_a``, ``orbit<k>_nacl_b``,
        ``orbit<k>_nacr_b`` (``a``: the earlier, southern strip of the northbound pass).

    Returns
    -------
    BlockModel
    """
    _check_args(seed, orbits, site_latitude_deg, sites, site_spacing_deg, site_half_width_s, layout)
    n_sites = int(sites)
    if navigation is None:
        spec = NavigationErrorSpec() if n_sites == 1 else MULTI_SITE_NAVIGATION
    else:
        spec = navigation
    if not isinstance(spec, NavigationErrorSpec):
        raise InvalidInputError(f"navigation must be a NavigationErrorSpec, got {type(spec).__name__}")
    orbits, lat0 = int(orbits), float(site_latitude_deg)
    spacing = float(site_spacing_deg) if n_sites > 1 else 0.0
    lats = [lat0 + k * spacing for k in range(n_sites)]
    rng = np.random.default_rng(int(seed))
    ecc = float(rng.uniform(0.001, 0.002))
    periapsis = float(rng.uniform(0.0, 2.0 * np.pi))
    periapsis_rate = float(np.radians(rng.uniform(-3.0, 3.0)) / 86400.0)
    node_jitter = float(np.radians(rng.uniform(-2.0, 2.0)))
    wobble_amp = cast(_Vec3, tuple(float(np.radians(a)) for a in rng.uniform(0.008, 0.012, 3)))
    wobble_period = cast(_Vec3, tuple(float(p) for p in rng.uniform(1500.0, 2400.0, 3)))
    wobble_phase = cast(_Vec3, tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, 3)))
    misalign = rng.choice([-1.0, 1.0], (3, 3)) * rng.uniform(0.01, 0.05, (3, 3))
    cameras = BLOCK_CAMERAS if layout == "block" else FULL_SIZE_CAMERAS
    mounting = {c.naif_id: cast(_Vec3, tuple(float(round(n + m, 6)) for n, m in zip(c.nominal_angles_deg, misalign[i])))
                for i, c in enumerate(cameras)}

    start = tdb_to_et(MISSION_START_TDB)
    # first crossing of the site latitude 60 degrees of orbit (~19 min) after the start
    start_u = np.radians(lat0 - 60.0)
    probe = KeplerOrbit(start, MOON_RADIUS_KM + ALTITUDE_KM, 0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0)
    sun_dir = probe.moon_equator_to_j2000.T @ (sun_state_ssb(start)[:3] - moon_state_ssb(start)[:3])
    node = float(np.mod(np.arctan2(sun_dir[1], sun_dir[0]) + np.radians(SUN_OFFSET_DEG) + node_jitter, 2 * np.pi))
    orbit = KeplerOrbit(epoch=start, semi_major_axis=MOON_RADIUS_KM + ALTITUDE_KM, eccentricity=ecc,
                        inclination=np.pi / 2, node=node, periapsis=periapsis, periapsis_rate=periapsis_rate,
                        mean_anomaly=KeplerOrbit.mean_anomaly_for(start_u - periapsis, ecc))
    never = start - 1.0  # an empty yaw-flip interval
    nadir = NadirAttitude(orbit, wobble_amp, wobble_period, wobble_phase, never, never)

    # each site: between the tracks (or beside the middle one) at its latitude
    crossings: list[list[float]] = []  # [site][orbit]
    site_list = []
    for s, lat in enumerate(lats):
        crossings.append([_latitude_crossing(orbit, lat, k + 1, start_u) for k in range(orbits)])
        lons = []
        for t in crossings[s]:
            p = j2000_to_iau_moon(t) @ orbit.state(np.asarray(t))[:3]
            lons.append(float(np.degrees(np.arctan2(p[1], p[0]))))
        lons_u = np.degrees(np.unwrap(np.radians(lons)))
        offset = SITE_TRACK_OFFSET_M if orbits % 2 else 0.0
        lon = float(np.mean(lons_u) + np.degrees(offset / (MOON_RADIUS_KM * 1000.0 * np.cos(np.radians(lat)))))
        site_list.append(BlockSite(s + 1, lat, float(np.mod(lon + 180.0, 360.0) - 180.0)))
    lon0 = site_list[0].longitude_deg

    # rolls and reference epochs: the NAC boresight meets each site
    stub = BlockModel(seed=int(seed), orbits=orbits, site_latitude_deg=lat0, site_longitude_deg=lon0,
                      site_extent_m=0.0, start_et=start, end_et=start,
                      sclk_zero_et=tdb_to_et(textkernels.SCLK_ZERO_TDB),
                      orbit=orbit, nadir=nadir, passes=(), mounting_angles_deg=mounting, images=(),
                      navigation=None, navigation_spec=spec,  # type: ignore[arg-type]
                      cameras=cameras, sites=tuple(site_list), site_spacing_deg=spacing, layout=str(layout))
    half = PASS_HALF_WIDTH if n_sites == 1 else float(site_half_width_s or MULTI_SITE_HALF_WIDTH)
    passes = []
    for k in range(orbits):
        for site in site_list:
            east, north = _east_north(site.longitude_deg, site.latitude_deg)
            t_o, roll = _point_at_site(stub, crossings[site.site - 1][k], stub.site_xyz(site=site.site), east, north)
            passes.append(BlockPass(k + 1, t_o, float(np.degrees(roll)), t_o - half, t_o + half, site.site))
    passes.sort(key=lambda p: p.epoch)
    gaps = [(b.start_et - a.end_et, a, b) for a, b in zip(passes, passes[1:])]
    short = [(g, a, b) for g, a, b in gaps if g < MIN_SLEW_S]
    if short:
        g, a, b = short[0]
        raise InvalidInputError(f"sites {a.site} and {b.site} are {b.epoch - a.epoch:.1f} s apart on orbit {a.orbit}: "
                                f"their pass windows (+-{half:g} s) leave {g:.1f} s (< {MIN_SLEW_S:g} s) to slew; "
                                f"space the sites further apart")
    # navigation: one reference epoch per orbit, midway between its first and last site (the site, with one)
    epochs = []
    for k in range(orbits):
        ts = [p.epoch for p in passes if p.orbit == k + 1]
        epochs.append(0.5 * (min(ts) + max(ts)))
    windows = [[p.start_et, p.end_et] for p in passes]
    nav = draw_navigation_errors(rng, epochs, windows, spec, [p.orbit - 1 for p in passes])
    model = _replace(stub, passes=tuple(passes), navigation=nav,
                     start_et=passes[0].start_et - SPK_MARGIN, end_et=passes[-1].end_et + SPK_MARGIN)
    model = _replace(model, images=tuple(_plan_images(model)))
    sized = tuple(_sized(model, s) for s in site_list)
    return _replace(model, sites=sized, site_extent_m=sized[0].extent_m)


def _replace(model: BlockModel, **changes: Any) -> BlockModel:
    return dataclasses.replace(model, **changes)


def _with_roll(model: BlockModel, roll: float, t: float) -> BlockModel:
    """A one-pass stub model with ``roll`` (rad) around ``t``, for the pointing solution."""
    return _replace(model, passes=(BlockPass(1, t, float(np.degrees(roll)), t - 1e3, t + 1e3),))


def _point_at_site(stub: BlockModel, t_cross: float, site: Array, east: Array, north: Array) -> tuple[float, float]:
    """``(t_o, roll)`` putting the NAC boresight on the site at height 0 (Newton, numerical Jacobian)."""

    def miss(x: Array) -> Array:
        t = t_cross + x[0]
        g = _with_roll(stub, x[1], t).pointing_ground(t)
        d = g - site
        return np.array([d @ east, d @ north])  # m

    x = np.zeros(2)
    steps = np.array([1e-3, 1e-6])  # s, rad
    for _ in range(20):
        r = miss(x)
        # 0.1 mm: an ET near 8e8 s is resolved to 1.2e-7 s, i.e. 0.2 mm along track
        if np.max(np.abs(r)) < 1e-4:
            return float(t_cross + x[0]), float(x[1])
        jac = np.column_stack([(miss(x + d) - miss(x - d)) / (2.0 * d.sum()) for d in np.diag(steps)])
        x = x - np.linalg.solve(jac, r)
        if not np.all(np.isfinite(x)) or abs(x[1]) > np.radians(45.0):
            break
    raise InvalidInputError(f"cannot point the NAC at the block site from the orbit crossing at ET {t_cross:.3f}")


def _closest_time(model: BlockModel, naif_id: int, t_guess: float, site: Array, along: Array,
                  window: tuple[float, float] | None = None) -> float:
    """Time at which a camera's boresight ground point passes the site along track (within the pass ``window``)."""

    def f(t: float) -> float:
        return float((model.boresight_ground(naif_id, t) - site) @ along)

    lo, hi = t_guess - 30.0, t_guess + 30.0
    if window is not None:      # short pass windows: the attitude exists only there
        lo, hi = max(lo, window[0] + 0.5), min(hi, window[1] - 0.5)
    return float(brentq(f, lo, hi, xtol=1e-9, rtol=1e-15))


def _pushbroom_line_time(model: BlockModel, cam: BlockCameraSpec, t: float) -> float:
    """Line period (s, whole ns) giving square ground pixels at the image centre at ``t``."""
    half = 0.5 * cam.pixel_pitch_mm
    g1 = model.boresight_ground(cam.naif_id, t, (0.0, -half, cam.focal_length_mm))
    g2 = model.boresight_ground(cam.naif_id, t, (0.0, half, cam.focal_length_mm))
    h = 0.05
    v = (model.boresight_ground(cam.naif_id, t + h) - model.boresight_ground(cam.naif_id, t - h)) / (2 * h)
    return round(float(np.linalg.norm(g2 - g1) / np.linalg.norm(v)), 9)


def _plan_full_size(model: BlockModel) -> list[BlockImagePlan]:
    """The full-size layout's images of every pass: strip ``a`` then ``b``, NAC-L then NAC-R in each."""
    out = []
    for k in range(1, model.orbits + 1):
        p = model.pass_of(k, 1)
        # the strips' centre times: the pass's reference (the bus axis on the site) -/+ half a strip and
        # half a line (strip b starts one line after strip a ends), plus this orbit's stagger; the line
        # time of the first camera at the reference serves both cameras
        nacl = model.cameras[0]
        lt = _pushbroom_line_time(model, nacl, p.epoch)
        duration = FULL_NAC_LINES * lt
        stagger = (k - 0.5 * (model.orbits + 1)) * FULL_SIZE_ORBIT_STAGGER * duration
        shift = 0.5 * (duration + lt)
        for strip, centre in (("a", p.epoch + stagger - shift), ("b", p.epoch + stagger + shift)):
            for cam in model.cameras:
                kind = f"{cam.kind}_{strip}"
                out.append(BlockImagePlan(image_name(1, k, kind, 1), cam, k, kind, FULL_NAC_LINES, centre, lt, None, 1))
    return out


def _plan_images(model: BlockModel) -> list[BlockImagePlan]:
    """The four images of every pass: site by site, orbit by orbit."""
    if model.layout == "full_size":
        return _plan_full_size(model)
    out = []
    n = model.n_sites
    for s in model.sites:
        site = model.site_xyz(site=s.site)
        for k in range(1, model.orbits + 1):
            p = model.pass_of(k, s.site)
            along = model.orbit_frame(p.epoch)[0]
            lt = _pushbroom_line_time(model, BLOCK_NAC, p.epoch)
            out.append(BlockImagePlan(image_name(s.site, k, "nac", n), BLOCK_NAC, k, "nac", PUSHBROOM_LINES,
                                      p.epoch, lt, None, s.site))
            t_tc = _closest_time(model, BLOCK_TC.naif_id, p.epoch, site, along, (p.start_et, p.end_et))
            lt = _pushbroom_line_time(model, BLOCK_TC, t_tc)
            out.append(BlockImagePlan(image_name(s.site, k, "tc", n), BLOCK_TC, k, "tc", PUSHBROOM_LINES, t_tc,
                                      lt, None, s.site))
            t_fr = _closest_time(model, BLOCK_FRAME.naif_id, p.epoch, site, along, (p.start_et, p.end_et))
            h = 0.05
            speed = np.linalg.norm(model.boresight_ground(BLOCK_FRAME.naif_id, t_fr + h)
                                   - model.boresight_ground(BLOCK_FRAME.naif_id, t_fr - h)) / (2 * h)
            # along-track footprint: the frame's samples run along track
            c = BLOCK_FRAME
            a = model.boresight_ground(c.naif_id, t_fr, (-0.5 * c.samples * c.pixel_pitch_mm, 0.0, c.focal_length_mm))
            b = model.boresight_ground(c.naif_id, t_fr, (0.5 * c.samples * c.pixel_pitch_mm, 0.0, c.focal_length_mm))
            step = round(FRAME_ADVANCE * float(np.linalg.norm(b - a)) / float(speed), 3)
            for kind, t in (("frame_a", t_fr - step / 2), ("frame_b", t_fr + step / 2)):
                out.append(BlockImagePlan(image_name(s.site, k, kind, n), BLOCK_FRAME, k, kind, BLOCK_FRAME.lines,
                                          t, None, FRAME_EXPOSURE_MS / 1000.0, s.site))
    return out


def image_footprint(model: BlockModel, im: BlockImagePlan) -> Array:
    """The four corners of an image's footprint on the reference sphere (truth, no distortion), body-fixed m."""
    corners = im.camera.fov_corners() * im.camera.focal_length_mm
    if im.line_time is not None:
        times = np.array([im.planned_start_et, im.planned_start_et, im.planned_start_et + im.duration,
                          im.planned_start_et + im.duration])
    else:
        times = np.full(4, im.center_et)
    return np.array([model.boresight_ground(im.camera.naif_id, t, look) for t, look in zip(times, corners)])


def _site_reach(model: BlockModel, site: int) -> tuple[float, float]:
    """Largest east-west and north-south distances (m) of a site's image footprint corners from the site."""
    s = model.site(site)
    centre = model.site_xyz(site=site)
    east, north = _east_north(s.longitude_deg, s.latitude_deg)
    reach_e = reach_n = 0.0
    for im in model.images:
        if im.site != site:
            continue
        for g in image_footprint(model, im):
            d = g - centre
            reach_e, reach_n = max(reach_e, abs(float(d @ east))), max(reach_n, abs(float(d @ north)))
    return reach_e, reach_n


def _side(reach: float) -> float:
    # 300 m: terrain relief moves footprints (tens of metres) and the DTM needs a border
    return float(100.0 * np.ceil((2.0 * reach + 600.0) / 100.0))


def _site_extent(model: BlockModel, site: int) -> float:
    """Side (m, rounded up to 100 m) of a square about a site holding its images' footprints plus 300 m."""
    return _side(max(_site_reach(model, site)))


def _sized(model: BlockModel, s: BlockSite) -> BlockSite:
    """A site with its extent; the full-size layout's long strips also get their rectangle."""
    if model.layout == "block":
        return dataclasses.replace(s, extent_m=_site_extent(model, s.site))
    reach_e, reach_n = _site_reach(model, s.site)
    return dataclasses.replace(s, extent_m=_side(max(reach_e, reach_n)), extent_east_m=_side(reach_e),
                               extent_north_m=_side(reach_n))


def block_geometry(model: BlockModel) -> dict[str, Any]:
    """Per-image viewing geometry at its site and the convergence angle of every pair of images of one site (deg)."""
    views, out = {}, {}
    for im in model.images:
        site = model.site_xyz(site=im.site)
        up = _unit(site)
        pos = model.position_body_fixed(im.center_et)
        view = _unit(pos - site)
        views[im.name] = (im.site, view)
        sun = model.sun_direction_body_fixed(im.center_et)
        cam = im.camera
        slant = float(np.linalg.norm(pos - site))
        out[im.name] = {
            "emission_deg": float(np.degrees(np.arccos(view @ up))),
            "incidence_deg": float(np.degrees(np.arccos(sun @ up))),
            "slant_range_m": slant,
            "gsd_m": slant * cam.ifov,  # nominal: slant range times IFOV
            "roll_deg": model.pass_of(im.orbit, im.site).roll_deg,
        }
    names = list(views)
    conv = {f"{a}|{b}": float(np.degrees(np.arccos(np.clip(views[a][1] @ views[b][1], -1.0, 1.0))))
            for i, a in enumerate(names) for b in names[i + 1:] if views[a][0] == views[b][0]}
    return {"images": out, "convergence_deg": conv}
