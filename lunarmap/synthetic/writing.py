"""Writing the synthetic mission: kernels, ISIS-like image labels, manifest, meta-kernel.

:func:`write_mission` stages everything in a hidden folder inside the
destination and moves the files into place only once all are complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import spiceypy
from numpy.typing import NDArray

from ..errors import KernelError
from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
from ..spice.kernelset import parse_text_kernel_data
from ..spice.pool import SPICE_LOCK, spice_errors
from ..spice.writer import CkSegment, SpkSegment, loaded_temporarily, write_ck, write_spk, write_text_kernel
from . import ids, textkernels
from .bodies import MOON_RADIUS_KM, moon_state_ssb, sun_state_ssb
from .cameras import FRAME_CAMERA, NAC
from .labels import isis_label
from .mission import CK_STEP, PLANET_MARGIN, PLANET_STEP, SPK_DEGREE, SPK_STEP, SimMission, build_mission

__all__ = ["write_mission", "load_manifest", "metakernel_text"]


def metakernel_text() -> str:
    """The meta-kernel of the written set (the text of ``kernels_meta/synthetic_mission.tm``)."""
    lines = [
        "KPL/MK",
        "",
        "Meta-kernel of the synthetic LUNARMAP-SIM mission written by",
        "lunarmap.synthetic.write_mission. It lives next to the kernels; the",
        "relative PATH_VALUES '.' means this file's folder to lunarmap's",
        "KernelSet.from_metakernel (for plain furnsh, run from this folder).",
        "",
        "\\begindata",
        "",
        "   PATH_VALUES     = ( '.' )",
        "   PATH_SYMBOLS    = ( 'KERNELS' )",
        "",
    ]
    for i, f in enumerate(ids.KERNEL_FILES):
        head = "   KERNELS_TO_LOAD = ( " if i == 0 else " " * 22
        tail = " )" if i == len(ids.KERNEL_FILES) - 1 else ""
        lines.append(f"{head}'$KERNELS/{f}'{tail}")
    lines += ["", "\\begintext", ""]
    return "\n".join(lines) + "\n"


def _template_path() -> Path:
    return Path(__file__).resolve().parents[2] / "kernels_meta" / ids.METAKERNEL_NAME


def _metakernel_source() -> str:
    """The template from the source tree if present (editable install), else the built-in text."""
    p = _template_path()
    if not p.is_file():
        return metakernel_text()
    text = p.read_text(encoding="ascii")
    listed = [str(v).split("/")[-1] for v in parse_text_kernel_data(text).get("KERNELS_TO_LOAD", [])]
    if listed != list(ids.KERNEL_FILES):
        raise KernelError(f"meta-kernel template {p} lists {listed}, but the writer writes {list(ids.KERNEL_FILES)}")
    return text


def _binary_comments(mission: SimMission, what: str) -> list[str]:
    return [f"{what} of the synthetic LUNARMAP-SIM mission (fictional; not real data).",
            f"Written by lunarmap.synthetic.write_mission, seed {mission.seed}."]


def _write_kernels(mission: SimMission, d: Path) -> None:
    """All kernels of the set into folder ``d``."""
    lsk, sclk, pck, fk, nac_ik, frame_ik = (d / f for f in ids.KERNEL_FILES[:6])
    planets, orbit_spk, ck = (d / f for f in ids.KERNEL_FILES[6:])
    c, s = textkernels.lsk()
    write_text_kernel(lsk, "LSK", s, c)
    c, s = textkernels.sclk(mission.sclk_zero_et)
    write_text_kernel(sclk, "SCLK", s, c)
    c, s = textkernels.pck()
    write_text_kernel(pck, "PCK", s, c)
    c, s = textkernels.fk(mission.nac_angles_deg, mission.frame_angles_deg)
    write_text_kernel(fk, "FK", s, c)
    for cam, path in ((NAC, nac_ik), (FRAME_CAMERA, frame_ik)):
        c, s = textkernels.ik(cam)
        write_text_kernel(path, "IK", s, c)

    n_planet = int(round((mission.end_et - mission.start_et + 2 * PLANET_MARGIN) / PLANET_STEP))
    tp = mission.start_et - PLANET_MARGIN + PLANET_STEP * np.arange(n_planet + 1)
    sun, moon = sun_state_ssb(tp), moon_state_ssb(tp)
    write_spk(planets, [
        SpkSegment(ids.SUN_ID, ids.SSB_ID, "J2000", tp, sun[:, :3], sun[:, 3:], "SIM SUN", SPK_DEGREE),
        SpkSegment(ids.MOON_ID, ids.SSB_ID, "J2000", tp, moon[:, :3], moon[:, 3:], "SIM MOON", SPK_DEGREE),
    ], internal_name="LUNARMAP-SIM PLANETS", comments=_binary_comments(mission, "Sun and Moon SPK"))

    n_sc = int(round((mission.end_et - mission.start_et) / SPK_STEP))
    ts = mission.start_et + SPK_STEP * np.arange(n_sc + 1)
    st = mission.state(ts)
    write_spk(orbit_spk, [SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "J2000", ts, st[:, :3], st[:, 3:],
                                     "LUNARMAP-SIM ORBIT", SPK_DEGREE)],
              internal_name="LUNARMAP-SIM ORBIT", comments=_binary_comments(mission, "Spacecraft SPK"))

    att = mission.attitude
    grid = mission.ck_grid()
    segments = []
    pieces = ((mission.start_et, att.flip_start, False, "SIM BUS NOMINAL 1"),
              (att.flip_start, att.flip_end, True, "SIM BUS YAW FLIPPED"),
              (att.flip_end, mission.end_et, False, "SIM BUS NOMINAL 2"))
    for t0, t1, flipped, segid in pieces:
        t = grid[(grid >= t0 - 1e-6) & (grid <= t1 + 1e-6)]
        # both end records belong to this segment's attitude; where two
        # segments share an epoch the later one (the next interval) wins
        q = _aligned_quats(att.matrix(t, flipped=np.full(t.shape, flipped)))
        segments.append(CkSegment(ids.BUS_FRAME_ID, "J2000", t, q, att.angular_velocity(t), segid))
    write_ck(ck, segments, time_kernels=[lsk, sclk], sclk_id=ids.SCLK_ID,
             internal_name="LUNARMAP-SIM BUS", comments=_binary_comments(mission, "Bus attitude CK"))


def _aligned_quats(m: NDArray[np.float64]) -> NDArray[np.float64]:
    return align_quaternion_signs(matrix_to_quat(m))


def _image_records(mission: SimMission, d: Path) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Write the labels (times via SPICE, LSK and SCLK loaded temporarily).

    Returns the manifest's image entries, coverage and yaw-flip interval.
    """
    out: dict[str, dict[str, Any]] = {}
    lsk, sclk = d / ids.KERNEL_FILES[0], d / ids.KERNEL_FILES[1]
    with SPICE_LOCK, loaded_temporarily([lsk, sclk]), spice_errors("synthetic image times"):
        for im in mission.images:
            start_et = mission.tick_aligned(im.planned_start_et)
            sclk_start = spiceypy.sce2s(ids.SCLK_ID, start_et)
            if abs(spiceypy.scs2e(ids.SCLK_ID, sclk_start) - start_et) > 1e-7:
                raise KernelError(f"{im.name}: clock string {sclk_start} does not reproduce ET {start_et}")
            # microseconds: StartTime is within 0.5 us of the exact clock count
            start_utc = spiceypy.et2utc(start_et, "ISOC", 6)
            stop_et = start_et + im.duration
            stop_utc = spiceypy.et2utc(stop_et, "ISOC", 6)
            center = start_et + 0.5 * im.duration
            lat, lon = mission.sub_spacecraft(np.asarray(center))
            flipped = bool(mission.attitude.flipped(np.asarray(center)))
            rec: dict[str, Any] = {
                "label": f"{im.name}.lbl",
                "instrument": im.camera.name,
                "instrument_id": im.camera.naif_id,
                "frame": im.camera.frame_name,
                "camera_type": im.camera.camera_type,
                "samples": im.samples,
                "lines": im.lines,
                "start_time_utc": start_utc,
                # exact: the clock count's ET (StartTime is rounded to the microsecond)
                "start_et": start_et,
                "center_et": center,
                "stop_et": stop_et,
                "sclk_start": sclk_start,
                "target_latitude_deg": im.target_latitude_deg,
                "sub_spacecraft_latitude_deg": float(lat),
                "sub_spacecraft_longitude_deg": float(lon),
                "yaw_flipped": flipped,
                # sign of the velocity along bus +x (ISIS/ALE "spacecraft direction" for LRO NAC)
                "spacecraft_direction": -1 if flipped else 1,
            }
            if im.line_time is not None:
                line_ms = round(im.line_time * 1000.0, 6)
                rec["line_time_ms"] = line_ms
                rec["line_time_s"] = line_ms / 1000.0
                label = isis_label(samples=im.samples, lines=im.lines, spacecraft_name=ids.SPACECRAFT_NAME,
                                   instrument_id=im.camera.name, start_time=start_utc, stop_time=stop_utc,
                                   sclk_start=sclk_start, naif_frame_code=im.camera.naif_id,
                                   line_time_ms=line_ms)
            else:
                assert im.exposure is not None      # frame images have an exposure
                rec["exposure_ms"] = float(im.exposure) * 1000.0
                rec["exposure_s"] = float(im.exposure)
                label = isis_label(samples=im.samples, lines=im.lines, spacecraft_name=ids.SPACECRAFT_NAME,
                                   instrument_id=im.camera.name, start_time=start_utc, stop_time=stop_utc,
                                   sclk_start=sclk_start, naif_frame_code=im.camera.naif_id,
                                   exposure_ms=float(im.exposure) * 1000.0)
            (d / rec["label"]).write_text(label, encoding="ascii")
            out[im.name] = rec
        cover = {"start_et": mission.start_et, "end_et": mission.end_et,
                 "start_utc": spiceypy.et2utc(mission.start_et, "ISOC", 3),
                 "end_utc": spiceypy.et2utc(mission.end_et, "ISOC", 3)}
        flip = {"start_et": mission.attitude.flip_start, "end_et": mission.attitude.flip_end,
                "start_utc": spiceypy.et2utc(mission.attitude.flip_start, "ISOC", 3),
                "end_utc": spiceypy.et2utc(mission.attitude.flip_end, "ISOC", 3)}
    return out, cover, flip


def _manifest(mission: SimMission, images: dict[str, Any], cover: dict[str, Any],
              flip: dict[str, Any]) -> dict[str, Any]:
    o = mission.orbit
    cams = {}
    for cam, angles in ((NAC, mission.nac_angles_deg), (FRAME_CAMERA, mission.frame_angles_deg)):
        cams[cam.name] = {"id": cam.naif_id, "frame": cam.frame_name, "camera_type": cam.camera_type,
                          "distortion_model": cam.distortion_model, "samples": cam.samples,
                          "detector_lines": cam.lines, "focal_length_mm": cam.focal_length_mm,
                          "pixel_pitch_mm": cam.pixel_pitch_mm, "mounting_angles_deg": list(angles),
                          "ik": ids.KERNEL_FILES[4] if cam is NAC else ids.KERNEL_FILES[5]}
    return {
        "mission": ids.SPACECRAFT_NAME,
        "description": "fictional lunar orbiter written by lunarmap.synthetic (not real data)",
        "seed": mission.seed,
        "spacecraft": {"name": ids.SPACECRAFT_NAME, "id": ids.SPACECRAFT_ID, "sclk_id": ids.SCLK_ID},
        "target": {"name": "MOON", "id": ids.MOON_ID, "frame": ids.MOON_FRAME, "radius_km": MOON_RADIUS_KM},
        "frames": {
            ids.BUS_FRAME: {"id": ids.BUS_FRAME_ID, "class": "CK", "relative_to": ids.INERTIAL_FRAME},
            ids.NAC_FRAME: {"id": ids.NAC_ID, "class": "TK", "relative_to": ids.BUS_FRAME},
            ids.FRAME_CAMERA_FRAME: {"id": ids.FRAME_CAMERA_ID, "class": "TK", "relative_to": ids.BUS_FRAME},
        },
        "instruments": cams,
        "coverage": cover,
        "yaw_flip": flip,
        "orbit": {"epoch_et": o.epoch, "semi_major_axis_km": o.semi_major_axis,
                  "eccentricity": o.eccentricity, "inclination_deg": float(np.degrees(o.inclination)),
                  "node_deg": float(np.degrees(o.node)), "periapsis_deg": float(np.degrees(o.periapsis)),
                  "periapsis_rate_deg_per_day": float(np.degrees(o.periapsis_rate) * 86400.0),
                  "period_s": o.period, "frame": "Moon equator of the epoch (IAU pole), inertial"},
        "sampling": {"spk_step_s": SPK_STEP, "spk_degree": SPK_DEGREE, "ck_step_s": CK_STEP,
                     "planet_step_s": PLANET_STEP},
        "images": images,
        "kernels": list(ids.KERNEL_FILES),
        "metakernel": ids.METAKERNEL_NAME,
    }


def write_mission(folder: str | os.PathLike[str], *, seed: int = 0) -> Path:
    """Write the synthetic mission's kernel set, image labels and manifest into a folder.

    Everything is written into a hidden staging folder inside ``folder`` and
    moved into place only when complete (the meta-kernel last), so a failure
    leaves no partial set behind. Existing files of the same names are replaced.

    Parameters
    ----------
    folder : path-like
        Destination (created if missing).
    seed : int
        Seed of the random perturbations; the same seed gives byte-identical
        text kernels, labels and manifest and binary kernels with identical content.

    Returns
    -------
    pathlib.Path
        The meta-kernel ``synthetic_mission.tm``; load it with
        ``KernelSet.from_metakernel``.
    """
    mission = build_mission(seed)
    dest = Path(folder).expanduser()
    dest.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".lunarmap-sim-", dir=dest))
    try:
        _write_kernels(mission, staging)
        manifest = _manifest(mission, *_image_records(mission, staging))
        (staging / ids.MANIFEST_NAME).write_text(json.dumps(manifest, indent=2) + "\n", encoding="ascii")
        (staging / ids.METAKERNEL_NAME).write_text(_metakernel_source(), encoding="ascii")
        names = [*ids.KERNEL_FILES, *(f"{n}.lbl" for n in ids.IMAGE_NAMES), ids.MANIFEST_NAME,
                 ids.METAKERNEL_NAME]
        for name in names:
            os.replace(staging / name, dest / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return dest / ids.METAKERNEL_NAME


def load_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read ``mission.json`` given its path, the meta-kernel's path or their folder."""
    p = Path(path)
    if p.is_dir():
        p = p / ids.MANIFEST_NAME
    elif p.suffix == ".tm":
        p = p.with_name(ids.MANIFEST_NAME)
    return json.loads(p.read_text(encoding="ascii"))
