"""Writing the synthetic imaging block: shared text kernels, TRUTH and NAVIGATION SPK/CK, labels, manifest.

Folder layout written by :func:`write_block_mission`::

    lunarmap_sim.tls  lunarmap_sim.tsc  lunarmap_sim.tpc    LSK, SCLK, PCK (as write_mission's)
    lunarmap_block.tf                                      bus CK frame + three camera TK frames
    lunarmap_block_nac.ti  lunarmap_block_tc.ti  lunarmap_block_frame.ti
    lunarmap_sim_planets.bsp                               Sun and Moon
    block_truth.bsp  block_truth.bc                        true trajectory (continuous) and attitude (passes)
    block_navigation.bsp  block_navigation.bc              the same with the navigation errors (passes)
    truth.tm  navigation.tm                                meta-kernels (shared kernels + one pair)
    orbit<k>_<kind>.lbl                                    ISIS-like labels, shared by both kernel sets
                                                           (s<site>_orbit<k>_<kind>.lbl with several sites)
    block_mission.json                                     manifest (see :func:`write_block_mission`)

Everything is written into a hidden staging folder inside the destination
and moved into place only when complete (the meta-kernels last), so a
failure leaves nothing behind.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..atomic import atomic_write
from ..errors import BlockMissionError, InvalidInputError, KernelError
from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
from ..spice import KernelSet, kernels
from ..spice import queries as q
from ..spice.writer import Append, CkSegment, SpkSegment, Value, write_ck, write_spk, write_text_kernel
from . import ids, textkernels
from .block import (
    FULL_SIZE_ORBITS,
    MULTI_SITE_NAVIGATION,
    NAV_CK_STEP,
    NAV_SPK_STEP,
    SITE_SPACING_DEG,
    TRUTH_CK_STEP,
    TRUTH_SPK_STEP,
    BlockModel,
    BlockPass,
    block_geometry,
    build_block_model,
)
from .block_cameras import FULL_SIZE_CAMERAS, BlockCameraSpec
from .bodies import MOON_RADIUS_KM, moon_state_ssb, sun_state_ssb
from .labels import isis_label
from .mission import PLANET_MARGIN, PLANET_STEP, SPK_DEGREE
from .nav_errors import NavigationErrorSpec

__all__ = [
    "BlockMission", "write_block_mission", "open_block_mission", "BLOCK_MANIFEST_NAME", "TRUTH_METAKERNEL",
    "NAVIGATION_METAKERNEL", "SHARED_KERNELS", "TRUTH_KERNELS", "NAVIGATION_KERNELS", "block_fk", "block_ik",
    "shared_kernels",
]

BLOCK_MANIFEST_NAME = "block_mission.json"
TRUTH_METAKERNEL = "truth.tm"
NAVIGATION_METAKERNEL = "navigation.tm"
#: Kernels of both sets, in load order.
SHARED_KERNELS = ("lunarmap_sim.tls", "lunarmap_sim.tsc", "lunarmap_sim.tpc", "lunarmap_block.tf",
                  "lunarmap_block_nac.ti", "lunarmap_block_tc.ti", "lunarmap_block_frame.ti",
                  "lunarmap_sim_planets.bsp")
TRUTH_KERNELS = ("block_truth.bsp", "block_truth.bc")


def shared_kernels(layout: str = "block") -> tuple[str, ...]:
    """The kernels of both sets of a layout, in load order (:data:`SHARED_KERNELS` for the default)."""
    if layout == "block":
        return SHARED_KERNELS
    iks = tuple(f"lunarmap_block_{c.kind}.ti" for c in FULL_SIZE_CAMERAS)
    return (*SHARED_KERNELS[:4], *iks, SHARED_KERNELS[-1])
NAVIGATION_KERNELS = ("block_navigation.bsp", "block_navigation.bc")


# -- text kernels -------------------------------------------------------------------

def block_fk(model: BlockModel) -> tuple[str, list[tuple[str, Mapping[str, Value]]]]:
    """Frames kernel: spacecraft and camera names, the CK bus frame and the three camera TK frames."""
    names: dict[str, Value] = {
        "NAIF_BODY_NAME": Append([ids.SPACECRAFT_NAME, *(c.name for c in model.cameras)]),
        "NAIF_BODY_CODE": Append([ids.SPACECRAFT_ID, *(c.naif_id for c in model.cameras)]),
    }
    b = ids.BUS_FRAME_ID
    bus: dict[str, Value] = {
        f"FRAME_{ids.BUS_FRAME}": b, f"FRAME_{b}_NAME": ids.BUS_FRAME, f"FRAME_{b}_CLASS": 3,
        f"FRAME_{b}_CLASS_ID": b, f"FRAME_{b}_CENTER": ids.SPACECRAFT_ID, f"CK_{b}_SCLK": ids.SCLK_ID,
        f"CK_{b}_SPK": ids.SPACECRAFT_ID,
    }
    sections: list[tuple[str, Mapping[str, Value]]] = [("Names and ids.", names), ("Spacecraft bus (CK frame).", bus)]
    for c in model.cameras:
        sections.append((f"{c.name}: {c.description}",
                         textkernels._tk(c.naif_id, c.frame_name, ids.BUS_FRAME, model.mounting_angles_deg[c.naif_id])))
    over = "the site" if model.n_sites == 1 else "a site"
    if model.layout == "full_size":
        comments = ("Frames of the LUNARMAP-SIM full-size imaging block (lunarmap.synthetic.write_block_mission).\n"
                    f"  {ids.BUS_FRAME} ({b}): spacecraft bus, CK frame relative to J2000; +z nadir, +x roughly\n"
                    f"      along the ground-track velocity; rolled about +x during each pass over {over}.\n"
                    "  Cameras (TK frames relative to the bus, boresight +z): SIM_FULL_NACL and SIM_FULL_NACR are\n"
                    "  rolled by +/-1.42 degrees about the bus +x so that their fields of view meet across the bus\n"
                    "  +z axis; SIM_FULL_NACR is also turned 180 degrees about its boresight, as LRO's NAC-R; each\n"
                    "  with a random misalignment of a few hundredths of a degree.")
        return comments, sections
    comments = ("Frames of the LUNARMAP-SIM imaging block (lunarmap.synthetic.write_block_mission).\n"
                f"  {ids.BUS_FRAME} ({b}): spacecraft bus, CK frame relative to J2000; +z nadir, +x roughly\n"
                f"      along the ground-track velocity; rolled about +x during each pass over {over}.\n"
                "  Cameras (TK frames relative to the bus, boresight +z): SIM_BLK_NAC looks along the bus +z,\n"
                "  SIM_BLK_TC is pitched forward and SIM_BLK_FRAME aft by 6 degrees about the bus +y, each\n"
                "  with a random misalignment of a few hundredths of a degree.")
    return comments, sections


def block_ik(cam: BlockCameraSpec) -> tuple[str, Any]:
    """Instrument kernel of a block camera (the single-image mission's IK plus Kaguya-style terms)."""
    comments, sections = textkernels.ik(cam)
    if cam.distortion_model != "kaguyalism":
        return comments, sections
    p = f"INS{cam.naif_id}_"
    geometry, fov = dict(sections[0][1]), dict(sections[1][1])
    del geometry[p + "OD_K"]
    geometry[p + "DISTORTION_COEF_X"] = list(cam.coef_x)
    geometry[p + "DISTORTION_COEF_Y"] = list(cam.coef_y)
    f = cam.focal_length_mm
    fov[p + "BORESIGHT"] = [cam.boresight_offset_mm[0] / f, cam.boresight_offset_mm[1] / f, 1.0]
    comments = (f"Instrument kernel of {cam.name} (NAIF id {cam.naif_id}) of the LUNARMAP-SIM imaging block:\n"
                f"{cam.description}\n"
                "Units: FOCAL_LENGTH, PIXEL_PITCH mm; TRANSX/TRANSY mm per pixel; ITRANSS/ITRANSL pixels\n"
                "per mm; IFOV rad/pixel. BORESIGHT_SAMPLE/LINE use the ISIS convention (first pixel centre\n"
                "1.0). Distortion: Kaguya TC's model ('kaguyalism', SEL_TC_V01.TI): with r the distance of\n"
                "the measured focal-plane point (x, y) from the centre, mm,\n"
                "  x_ideal = x + a0 + a1 r + a2 r^2 + a3 r^3 + bx,  y_ideal = y + b0 + b1 r + b2 r^2 + b3 r^3 + by,\n"
                "DISTORTION_COEF_X = (a0..a3), DISTORTION_COEF_Y = (b0..b3) (mm, 1, 1/mm, 1/mm^2) and\n"
                "(bx, by) = BORESIGHT(1:2) * FOCAL_LENGTH / BORESIGHT(3), mm. The coefficients are TC1's\n"
                "rescaled to this 3.6 mm detector (see lunarmap.synthetic.block_cameras).")
    return comments, [(sections[0][0], geometry), (sections[1][0], fov), sections[2]]


def _metakernel_text(kind: str, layout: str = "block") -> str:
    files = [*shared_kernels(layout), *(TRUTH_KERNELS if kind == "truth" else NAVIGATION_KERNELS)]
    what = ("TRUTH: the true trajectory and attitude" if kind == "truth"
            else "NAVIGATION: trajectory and attitude with per-orbit navigation errors")
    lines = ["KPL/MK", "", "Meta-kernel of the LUNARMAP-SIM imaging block written by",
             "lunarmap.synthetic.write_block_mission:", what + ".",
             "The relative PATH_VALUES '.' means this file's folder to lunarmap's",
             "KernelSet.from_metakernel (for plain furnsh, run from this folder).", "", "\\begindata", "",
             "   PATH_VALUES     = ( '.' )", "   PATH_SYMBOLS    = ( 'KERNELS' )", ""]
    for i, f in enumerate(files):
        head = "   KERNELS_TO_LOAD = ( " if i == 0 else " " * 22
        lines.append(f"{head}'$KERNELS/{f}'{' )' if i == len(files) - 1 else ''}")
    lines += ["", "\\begintext", ""]
    return "\n".join(lines) + "\n"


# -- binary kernels --------------------------------------------------------------------

def _grid(p: BlockPass, step: float) -> np.ndarray:
    n = int(round((p.end_et - p.start_et) / step))
    return p.start_et + step * np.arange(n + 1)


def _pass_name(p: BlockPass, sites: int) -> str:
    """``ORBIT <o>`` (``ORBIT <o> SITE <s>`` with several sites), for segment ids (at most 40 characters)."""
    return f"ORBIT {p.orbit}" if sites == 1 else f"ORBIT {p.orbit} SITE {p.site}"


def _comments(model: BlockModel, what: str) -> list[str]:
    return [f"{what} of the LUNARMAP-SIM imaging block (fictional; not real data).",
            f"Written by lunarmap.synthetic.write_block_mission, seed {model.seed}."]


def _write_kernels(model: BlockModel, d: Path) -> None:
    lsk, sclk, pck, fk, *iks, planets = (d / f for f in shared_kernels(model.layout))
    for path, kind, (c, s) in ((lsk, "LSK", textkernels.lsk()), (sclk, "SCLK", textkernels.sclk(model.sclk_zero_et)),
                               (pck, "PCK", textkernels.pck()), (fk, "FK", block_fk(model))):
        write_text_kernel(path, kind, s, c)
    for cam, path in zip(model.cameras, iks):
        c, s = block_ik(cam)
        write_text_kernel(path, "IK", s, c)

    n_planet = int(round((model.end_et - model.start_et + 2 * PLANET_MARGIN) / PLANET_STEP))
    tp = model.start_et - PLANET_MARGIN + PLANET_STEP * np.arange(n_planet + 1)
    sun, moon = sun_state_ssb(tp), moon_state_ssb(tp)
    write_spk(planets, [
        SpkSegment(ids.SUN_ID, ids.SSB_ID, "J2000", tp, sun[:, :3], sun[:, 3:], "SIM SUN", SPK_DEGREE),
        SpkSegment(ids.MOON_ID, ids.SSB_ID, "J2000", tp, moon[:, :3], moon[:, 3:], "SIM MOON", SPK_DEGREE),
    ], internal_name="LUNARMAP-SIM PLANETS", comments=_comments(model, "Sun and Moon SPK"))

    n_sc = int(round((model.end_et - model.start_et) / TRUTH_SPK_STEP))
    ts = model.start_et + TRUTH_SPK_STEP * np.arange(n_sc + 1)
    st = model.state(ts)
    write_spk(d / TRUTH_KERNELS[0], [SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "J2000", ts, st[:, :3], st[:, 3:],
                                                "LUNARMAP-SIM BLOCK TRUTH", SPK_DEGREE)],
              internal_name="LUNARMAP-SIM BLOCK TRUTH", comments=_comments(model, "True trajectory SPK"))
    nav_spk = []
    n = model.n_sites
    nav_label = "LUNARMAP-SIM BLOCK NAVIGATION" if n == 1 else "LUNARMAP-SIM BLOCK NAV"
    for p in model.passes:
        t = _grid(p, NAV_SPK_STEP)
        st = model.navigation_state(t)
        nav_spk.append(SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "J2000", t, st[:, :3], st[:, 3:],
                                  f"{nav_label} {_pass_name(p, n)}", SPK_DEGREE))
    write_spk(d / NAVIGATION_KERNELS[0], nav_spk, internal_name="LUNARMAP-SIM BLOCK NAVIGATION",
              comments=_comments(model, "Navigation trajectory SPK (truth + per-orbit errors)"))

    truth_ck, nav_ck = [], []
    for p in model.passes:
        t = _grid(p, TRUTH_CK_STEP)
        q_true = align_quaternion_signs(matrix_to_quat(model.bus_matrix(t)))
        truth_ck.append(CkSegment(ids.BUS_FRAME_ID, "J2000", t, q_true, model.bus_angular_velocity(t),
                                  f"SIM BLOCK BUS TRUTH {_pass_name(p, n)}"))
        t = _grid(p, NAV_CK_STEP)
        q_nav = align_quaternion_signs(matrix_to_quat(model.navigation_bus_matrix(t)))
        nav_ck.append(CkSegment(ids.BUS_FRAME_ID, "J2000", t, q_nav, model.navigation_bus_angular_velocity(t),
                                f"SIM BLOCK BUS NAVIGATION {_pass_name(p, n)}"))
    for name, segs, what in ((TRUTH_KERNELS[1], truth_ck, "True bus attitude CK"),
                             (NAVIGATION_KERNELS[1], nav_ck, "Navigation bus attitude CK (truth + errors)")):
        write_ck(d / name, segs, time_kernels=[lsk, sclk], sclk_id=ids.SCLK_ID,
                 internal_name="LUNARMAP-SIM BLOCK BUS", comments=_comments(model, what))


# -- labels and manifest ---------------------------------------------------------------

def _sclk_string(model: BlockModel, et: float) -> str:
    """The clock string of a tick-aligned ET (partition 1, seconds:ticks)."""
    ticks = int(round((et - model.sclk_zero_et) * textkernels.SCLK_MODULI[1]))
    return f"1/{ticks // textkernels.SCLK_MODULI[1]:010d}:{ticks % textkernels.SCLK_MODULI[1]:05d}"


def _navigation_error(model: BlockModel, et: float) -> dict[str, Any]:
    """The true navigation error at ``et`` in the manifest's representations."""
    e = model.navigation.position(np.asarray(et))
    along, cross, up = model.orbit_frame(np.asarray(et))
    th = model.navigation.attitude(np.asarray(et))
    return {
        "et": et,
        "position_m": e.tolist(),
        "position_orbit_frame_m": {"along_track": float(e @ along), "cross_track": float(e @ cross),
                                   "radial": float(e @ up)},
        "attitude_bus_rad": th.tolist(),
        "attitude_body_fixed_rad": model.attitude_error_body_fixed(np.asarray(et)).tolist(),
        "attitude_angle_rad": float(np.linalg.norm(th)),
    }


def _image_records(model: BlockModel, d: Path) -> dict[str, Any]:
    """Write the labels (UTC via SPICE with the LSK and SCLK loaded) and return the manifest's image entries."""
    geometry = block_geometry(model)["images"]
    out: dict[str, Any] = {}
    kset = KernelSet.from_files([d / SHARED_KERNELS[0], d / SHARED_KERNELS[1]])   # LSK and SCLK: every layout
    with kernels(kset):
        for im in model.images:
            start = model.tick_aligned(im.planned_start_et)
            sclk = _sclk_string(model, start)
            if abs(q.scs2e(ids.SPACECRAFT_ID, sclk) - start) > 1e-7:
                raise KernelError(f"{im.name}: clock string {sclk} does not reproduce ET {start}")
            stop = start + im.duration
            center = start + 0.5 * im.duration
            rec: dict[str, Any] = {
                "label": f"{im.name}.lbl", "camera": im.camera.name, "kind": im.kind, "orbit": im.orbit,
                **({} if model.n_sites == 1 else {"site": im.site}),
                "instrument_id": im.camera.naif_id, "frame": im.camera.frame_name,
                "camera_type": im.camera.camera_type, "samples": im.samples, "lines": im.lines,
                "start_time_utc": q.et2utc(start, "ISOC", 6), "stop_time_utc": q.et2utc(stop, "ISOC", 6),
                "sclk_start": sclk, "start_et": start, "center_et": center, "stop_et": stop,
                # the pass's reference: the NAC's view of the image's site on this orbit
                "seconds_from_orbit_reference": center - model.pass_of(im.orbit, im.site).epoch,
                "geometry": geometry[im.name],
                "navigation_error": _navigation_error(model, center),
            }
            common = dict(samples=im.samples, lines=im.lines, spacecraft_name=ids.SPACECRAFT_NAME,
                          instrument_id=im.camera.name, start_time=rec["start_time_utc"],
                          stop_time=rec["stop_time_utc"], sclk_start=sclk, naif_frame_code=im.camera.naif_id)
            if im.line_time is not None:
                line_ms = round(im.line_time * 1000.0, 6)
                rec["line_time_ms"], rec["line_time_s"] = line_ms, line_ms / 1000.0
                text = isis_label(line_time_ms=line_ms, **common)
            else:
                assert im.exposure is not None      # frame images have an exposure
                rec["exposure_ms"], rec["exposure_s"] = float(im.exposure) * 1000.0, float(im.exposure)
                text = isis_label(exposure_ms=float(im.exposure) * 1000.0, **common)
            (d / rec["label"]).write_text(text, encoding="ascii")
            out[im.name] = rec
    return out


def _manifest(model: BlockModel, images: dict[str, Any], params: dict[str, Any]) -> dict[str, Any]:
    o = model.orbit
    geo = block_geometry(model)
    cams = {}
    shared = shared_kernels(model.layout)
    for c in model.cameras:
        cams[c.name] = {"id": c.naif_id, "frame": c.frame_name, "camera_type": c.camera_type,
                        "distortion_model": c.distortion_model, "samples": c.samples, "detector_lines": c.lines,
                        "focal_length_mm": c.focal_length_mm, "pixel_pitch_mm": c.pixel_pitch_mm,
                        "ifov_rad": c.ifov, "mounting_angles_deg": list(model.mounting_angles_deg[c.naif_id]),
                        "ik": shared[4 + model.cameras.index(c)]}
    nav = model.navigation.to_dict()
    several = model.n_sites > 1
    if several:
        site = {"sites": [{"site": s.site, "latitude_deg": s.latitude_deg, "longitude_deg": s.longitude_deg,
                           "extent_m": s.extent_m, "images": list(model.site_image_names(s.site))}
                          for s in model.sites],
                "site_note": ("site k lies (k - 1) * site_spacing_deg degrees of latitude from site 1; on every "
                              "orbit the bus points the NAC at each site in turn (one pass window per site, "
                              "constant roll) and slews between them outside the windows")}
        orbits = {"orbits": [{"orbit": o["orbit"], "reference_et": o["reference_et"], "window_et": o["window_et"]}
                             for o in nav["orbits"]],
                  "passes": [{"orbit": p.orbit, "site": p.site, "reference_et": p.epoch, "roll_deg": p.roll_deg,
                              "window_et": [p.start_et, p.end_et]} for p in model.passes]}
    else:
        site, orbits = {}, {"orbits": [{"orbit": p.orbit, "reference_et": p.epoch, "roll_deg": p.roll_deg,
                                        "window_et": [p.start_et, p.end_et]} for p in model.passes]}
    return {
        "mission": ids.SPACECRAFT_NAME,
        "scenario": "block",
        "description": ("imaging block of the fictional LUNARMAP-SIM orbiter written by "
                        "lunarmap.synthetic.write_block_mission (not real data)"),
        "seed": model.seed,
        "parameters": params,
        "spacecraft": {"name": ids.SPACECRAFT_NAME, "id": ids.SPACECRAFT_ID, "sclk_id": ids.SCLK_ID,
                       "bus_frame": ids.BUS_FRAME, "bus_frame_id": ids.BUS_FRAME_ID},
        "target": {"name": "MOON", "id": ids.MOON_ID, "frame": ids.MOON_FRAME, "radius_km": MOON_RADIUS_KM},
        "site": {"latitude_deg": model.site_latitude_deg, "longitude_deg": model.site_longitude_deg,
                 "extent_m": model.site_extent_m,
                 "note": "every image footprint fits in the square of side extent_m centred on the site"
                 + (" (site 1 and its images; every site: sites)" if several else "")
                 + ("; and in the rectangle of sides extent_east_m x extent_north_m" if model.layout != "block" else ""),
                 **({"extent_east_m": model.site(1).extents[0], "extent_north_m": model.site(1).extents[1]}
                    if model.layout != "block" else {})},
        **site,
        "instruments": cams,
        **orbits,
        "orbit": {"epoch_et": o.epoch, "semi_major_axis_km": o.semi_major_axis, "eccentricity": o.eccentricity,
                  "inclination_deg": float(np.degrees(o.inclination)), "node_deg": float(np.degrees(o.node)),
                  "period_s": o.period},
        "coverage": {"truth_spk_et": [model.start_et, model.end_et],
                     "attitude_and_navigation": "the passes' window_et only" if several
                     else "the orbits' window_et only"},
        "sampling": {"truth_spk_step_s": TRUTH_SPK_STEP, "truth_ck_step_s": TRUTH_CK_STEP,
                     "navigation_spk_step_s": NAV_SPK_STEP, "navigation_ck_step_s": NAV_CK_STEP,
                     "spk_degree": SPK_DEGREE},
        "navigation_errors": {
            "definition": ("NAVIGATION = TRUTH + errors. For ET t in the window of orbit o (reference epoch t_o): "
                           "position p_nav = p_true + c_o + (t - t_o) d_o + n_p(t) in body-fixed (IAU_MOON) axes, "
                           "metres; attitude: the bus turned by the rotation vector th = a_o + (t - t_o) b_o + "
                           "n_a(t) in bus axes, radians (C_nav = Rv(th)^T C_true for the J2000 -> bus matrices, "
                           "Rv(v) = exp([v]x)); for every camera the sensor-to-body rotation becomes "
                           "R_nav = Rv(w) R_true with w = B C_true^T th (attitude_body_fixed_rad). n_p, n_a: "
                           "smooth random parts (sums of sinusoids, listed below). Per image, navigation_error "
                           "gives these errors at the image centre time."
                           + (" With several sites, t_o is the orbit's reference_et (midway between its first "
                              "and last site) and the errors are defined in its pass_windows_et." if several
                              else "")),
            "magnitudes": model.navigation_spec.to_dict(),
            **nav,
        },
        "images": images,
        "convergence_deg": geo["convergence_deg"],
        "kernels": {"shared": list(shared), "truth": list(TRUTH_KERNELS),
                    "navigation": list(NAVIGATION_KERNELS)},
        "metakernels": {"truth": TRUTH_METAKERNEL, "navigation": NAVIGATION_METAKERNEL},
    }


# -- public API -------------------------------------------------------------------------

@dataclass(frozen=True)
class BlockMission:
    """A written imaging block: its folder, truth model and manifest.

    Parameters
    ----------
    folder : pathlib.Path
    model : BlockModel
        The numpy truth and navigation model (rebuilt from the seed and parameters).
    manifest : dict
        The contents of ``block_mission.json``.
    """

    folder: Path
    model: BlockModel
    manifest: dict[str, Any]

    @property
    def truth_metakernel(self) -> Path:
        """``truth.tm``: the true trajectory and attitude."""
        return self.folder / TRUTH_METAKERNEL

    @property
    def navigation_metakernel(self) -> Path:
        """``navigation.tm``: trajectory and attitude with the navigation errors."""
        return self.folder / NAVIGATION_METAKERNEL

    def metakernel(self, kind: str) -> Path:
        """``'truth'`` or ``'navigation'`` meta-kernel."""
        if kind not in ("truth", "navigation"):
            raise InvalidInputError(f"kernel set must be 'truth' or 'navigation', got {kind!r}")
        return self.truth_metakernel if kind == "truth" else self.navigation_metakernel

    @property
    def image_names(self) -> tuple[str, ...]:
        return self.model.image_names

    @property
    def n_sites(self) -> int:
        """Number of sites."""
        return self.model.n_sites

    def site_image_names(self, site: int) -> tuple[str, ...]:
        """The images of one site (1-based)."""
        return self.model.site_image_names(site)

    def label(self, name: str) -> Path:
        """The label file of an image."""
        self.model.image(name)
        return self.folder / f"{name}.lbl"

    def navigation_error(self, name: str) -> dict[str, Any]:
        """The manifest's true navigation error of an image at its centre time."""
        self.model.image(name)
        return self.manifest["images"][name]["navigation_error"]


def _params(orbits: int, site_latitude_deg: float, spec: NavigationErrorSpec, sites: int = 1,
            site_spacing_deg: float = SITE_SPACING_DEG, site_half_width_s: float | None = None,
            layout: str = "block") -> dict[str, Any]:
    out = {"orbits": int(orbits), "site_latitude_deg": float(site_latitude_deg), "navigation": spec.to_dict()}
    if sites > 1:  # a one-site manifest stays as it was before sites existed
        out.update({"sites": int(sites), "site_spacing_deg": float(site_spacing_deg)})
        if site_half_width_s is not None:
            out["site_half_width_s"] = float(site_half_width_s)
    if layout != "block":  # so does the default layout's
        out["layout"] = layout
    return out


def _spec(navigation: NavigationErrorSpec | Mapping[str, Any] | None, sites: Any = 1) -> NavigationErrorSpec:
    if navigation is None:
        return MULTI_SITE_NAVIGATION if isinstance(sites, (int, np.integer)) and sites > 1 else NavigationErrorSpec()
    if isinstance(navigation, NavigationErrorSpec):
        return navigation
    if isinstance(navigation, Mapping):
        try:
            kw: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in navigation.items()}
            return NavigationErrorSpec(**kw)
        except TypeError as exc:
            raise InvalidInputError(f"navigation error parameters: {exc}") from None
    raise InvalidInputError(f"navigation must be a NavigationErrorSpec or a mapping, got {type(navigation).__name__}")


def write_block_mission(folder: str | os.PathLike[str], seed: int = 0, *, orbits: int | None = None,
                        site_latitude_deg: float = 57.0,
                        navigation: NavigationErrorSpec | Mapping[str, Any] | None = None, sites: int = 1,
                        site_spacing_deg: float = SITE_SPACING_DEG,
                        site_half_width_s: float | None = None, layout: str = "block") -> BlockMission:
    """Write the imaging block: kernels (TRUTH and NAVIGATION sets), labels and manifest.

    Parameters
    ----------
    folder : path-like
        Destination, created if missing; files of the same names are replaced.
    seed : int
        Seed of every random choice; the same arguments give byte-identical
        text kernels, labels and manifest.
    orbits : int, optional
        Consecutive orbits over the site (2 to 4; default 3: convergence angles of
        about 20 and 40 degrees between the orbits; 2 for the full-size layout: 20 degrees).
    site_latitude_deg : float
        Site latitude (site 1), degrees.
    navigation : NavigationErrorSpec or mapping, optional
        Magnitudes of the navigation errors (defaults: per-orbit position
        offsets of 20-50 m, attitude offsets of 20-50 urad; see
        :class:`~lunarmap.synthetic.nav_errors.NavigationErrorSpec`; with
        several sites :data:`~lunarmap.synthetic.block.MULTI_SITE_NAVIGATION`,
        whose drifts are ten times smaller).
    sites : int
        Sites along the ground track (1 to 48), each seen on every orbit by
        the same four images: ``4 * orbits * sites`` images, named
        ``s<site>_orbit<k>_<kind>`` when ``sites > 1`` (``orbit<k>_<kind>``
        with one site, whose files are exactly those written before sites
        existed).
    site_spacing_deg : float
        Latitude of site ``k + 1`` minus that of site ``k``, degrees (default
        -8: southward, about 150 s of flight apart; ``1 <= |spacing| <= 20``).
    site_half_width_s : float, optional
        Pass half-width of a block of several sites, seconds (see
        :func:`~lunarmap.synthetic.block.build_block_model`).
    layout : str
        ``"block"`` (default) or ``"full_size"``: eight full-size LRO-NAC-like images (NAC-L and
        NAC-R, 52,224 x 5,064 pixels of ~0.5 m, two along-track strips per orbit) on 2 orbits by
        default; see :func:`~lunarmap.synthetic.block.build_block_model`.

    Returns
    -------
    BlockMission

    Raises
    ------
    InvalidInputError
        Bad seed, number of orbits, latitude or navigation parameters (nothing is written).
    BlockMissionError
        ``folder`` exists and is not a folder.
    """
    spec = _spec(navigation, sites)
    if orbits is None:
        orbits = FULL_SIZE_ORBITS if layout == "full_size" else 3
    model = build_block_model(seed, orbits=orbits, site_latitude_deg=site_latitude_deg, navigation=spec, sites=sites,
                              site_spacing_deg=site_spacing_deg, site_half_width_s=site_half_width_s,
                              layout=layout)
    dest = Path(folder).expanduser()
    if dest.exists() and not dest.is_dir():
        raise BlockMissionError(f"cannot write the block mission into {dest}: it exists and is not a folder")
    created = not dest.exists()
    dest.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".lunarmap-block-", dir=dest))
    try:
        _write_kernels(model, staging)
        images = _image_records(model, staging)
        manifest = _manifest(model, images, _params(orbits, site_latitude_deg, spec, model.n_sites,
                                                    site_spacing_deg, site_half_width_s, model.layout))
        atomic_write(staging / BLOCK_MANIFEST_NAME, lambda tmp: tmp.write_text(
            json.dumps(manifest, indent=1) + "\n", encoding="ascii"))
        (staging / TRUTH_METAKERNEL).write_text(_metakernel_text("truth", model.layout), encoding="ascii")
        (staging / NAVIGATION_METAKERNEL).write_text(_metakernel_text("navigation", model.layout), encoding="ascii")
        names = [*shared_kernels(model.layout), *TRUTH_KERNELS, *NAVIGATION_KERNELS, *(f"{n}.lbl" for n in model.image_names),
                 BLOCK_MANIFEST_NAME, TRUTH_METAKERNEL, NAVIGATION_METAKERNEL]
        for name in names:
            os.replace(staging / name, dest / name)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created and not any(dest.iterdir()):
            dest.rmdir()
        raise
    shutil.rmtree(staging, ignore_errors=True)
    return BlockMission(dest, model, manifest)


def open_block_mission(folder: str | os.PathLike[str] | BlockMission) -> BlockMission:
    """Open a block written by :func:`write_block_mission` (rebuilds the model from the manifest).

    Raises
    ------
    BlockMissionError
        The folder, its manifest or a file the manifest names is missing, or
        the manifest does not describe a block of this lunarmap version.
    """
    if isinstance(folder, BlockMission):
        return folder
    d = Path(folder).expanduser()
    if not d.is_dir():
        raise BlockMissionError(f"block mission folder {d} does not exist")
    path = d / BLOCK_MANIFEST_NAME
    if not path.is_file():
        raise BlockMissionError(f"{d} holds no block mission: {BLOCK_MANIFEST_NAME} is missing")
    try:
        man = json.loads(path.read_text(encoding="ascii"))
        p = man["parameters"]
        if man.get("scenario") != "block":
            raise KeyError("scenario")
        model = build_block_model(int(man["seed"]), orbits=int(p["orbits"]),
                                  site_latitude_deg=float(p["site_latitude_deg"]),
                                  navigation=_spec(p["navigation"]), sites=int(p.get("sites", 1)),
                                  site_spacing_deg=float(p.get("site_spacing_deg", SITE_SPACING_DEG)),
                                  site_half_width_s=p.get("site_half_width_s"),
                                  layout=str(p.get("layout", "block")))
    except (ValueError, KeyError, TypeError) as exc:
        raise BlockMissionError(f"{path} is not a valid block-mission manifest ({exc!r})") from None
    # the kernels were written from this model: a different lunarmap version must not reinterpret them
    epochs = [o.get("reference_et") for o in man.get("passes", man.get("orbits", []))]
    if sorted(model.image_names) != sorted(man["images"]) or len(epochs) != len(model.passes) or any(
            abs(float(e) - p.epoch) > 1e-6 for e, p in zip(epochs, model.passes)) \
            or abs(man["site"]["longitude_deg"] - model.site_longitude_deg) > 1e-9:
        raise BlockMissionError(f"{path}: the model rebuilt from the manifest's seed and parameters does not "
                                f"match its images, orbits or site (written by another lunarmap version?)")
    for name in [*shared_kernels(model.layout), *TRUTH_KERNELS, *NAVIGATION_KERNELS, TRUTH_METAKERNEL, NAVIGATION_METAKERNEL,
                 *(im["label"] for im in man["images"].values())]:
        if not (d / name).is_file():
            raise BlockMissionError(f"block mission {d} is incomplete: {name} is missing")
    return BlockMission(d, model, man)
