"""Adjusted orientation for Ames Stereo Pipeline: ``.adjust`` files and adjusted CSM ISDs.

ASP reads adjusted cameras two ways:

* a CSM ISD JSON per image (``<image>.json``, the ``USGS_ASTRO_*_SENSOR_MODEL`` of usgscsm):
  :func:`write_asp_outputs` writes the *adjusted* ISD of every image
  (:func:`lunarmap.orientation.update.updated_image_support`): exact, line by line;
* an ``.adjust`` file beside the original camera (``bundle_adjust``'s output,
  ``<prefix>-<image>.adjust``): a translation ``T`` (body-fixed metres), a rotation quaternion
  ``q = (w, x, y, z)`` and optionally a pixel offset and a scale. ASP's
  ``vw::camera::AdjustedCameraModel`` moves the *whole* original camera rigidly about a rotation
  centre ``C0``, the original camera's centre at its first pixel: a ground point ``P`` is imaged
  where the original camera images ``R^T (P - C0 - T) + C0`` (``R`` the matrix of ``q``).

A rigid motion reproduces a frame camera's corrections (an attitude and a position shift)
exactly; a line-scan camera's corrections vary along the image (polynomials in time), so
:func:`asp_adjustment` finds the rigid motion that best reproduces the adjusted camera in the
image (least squares over a grid of ground points) and reports what remains (``rms_px``,
``max_px``): use the adjusted ISD when that is too large.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..atomic import atomic_write
from ..errors import AdjustmentInputError, InvalidInputError
from ..orientation.isd import ImageSupport
from ..orientation.update import updated_image_support

__all__ = ["AspAdjustment", "asp_adjustment", "asp_project", "write_asp_adjust", "read_asp_adjust",
           "write_asp_outputs"]


@dataclass(frozen=True)
class AspAdjustment:
    """One ASP ``.adjust``: ``translation`` (m), ``quaternion`` ``(w, x, y, z)``, and the fit's residuals.

    ``rotation_center`` is the original camera's centre at its first pixel (m, body-fixed): ASP
    computes it itself when it reads the file; ``rms_px`` / ``max_px`` are the differences between
    the rigidly moved original camera and the adjusted camera over the fit grid.
    """

    translation: NDArray[np.float64]
    quaternion: NDArray[np.float64]
    rotation_center: NDArray[np.float64]
    rms_px: float = 0.0
    max_px: float = 0.0

    @property
    def rotation(self) -> NDArray[np.float64]:
        """The 3x3 matrix of :attr:`quaternion`."""
        w, x, y, z = self.quaternion
        return Rotation.from_quat([x, y, z, w]).as_matrix()


def _center(camera: Any) -> NDArray[np.float64]:
    origin, _ = camera.rays(np.array([0.5]), np.array([0.5]))  # ASP's pixel (0, 0) = CSM (0.5, 0.5)
    return np.asarray(origin, float).reshape(3)


def asp_project(original: Any, adjustment: AspAdjustment, xyz: NDArray) -> tuple[NDArray, NDArray]:
    """``(line, sample)`` of points ``(n, 3)`` through ``original`` moved as ASP moves it (module docstring)."""
    c0, t = adjustment.rotation_center, adjustment.translation
    moved = (np.asarray(xyz, float) - c0 - t) @ adjustment.rotation + c0   # R^T (P - C0 - T) + C0, row vectors
    return original.ground_to_image(moved, within_image=False)


def _grid(camera: Any, n: int, heights: tuple[float, ...]) -> tuple[NDArray, NDArray]:
    line, sample = np.meshgrid(np.linspace(0.5, camera.n_lines - 0.5, n), np.linspace(0.5, camera.n_samples - 0.5, n),
                               indexing="ij")
    pts = [camera.image_to_ground(line.ravel(), sample.ravel(), height=h) for h in heights]
    return np.concatenate(pts), np.tile(np.column_stack([line.ravel(), sample.ravel()]), (len(heights), 1))


def asp_adjustment(original: Any, adjusted: Any, n: int = 15, heights: tuple[float, ...] = (-2000.0, 0.0, 2000.0)
                   ) -> AspAdjustment:
    """The ASP ``.adjust`` (rigid motion of ``original``) that best reproduces ``adjusted`` in the image.

    Parameters
    ----------
    original, adjusted : FrameCamera or LineScanCamera
        The camera ASP loads (from the original ISD) and the adjusted camera of the same image.
    n : int
        Grid of ``n x n`` pixels per height for the fit.
    heights : tuple of float
        Heights (m) of the ground points the grid is projected to.

    Returns
    -------
    AspAdjustment
        With the fit's RMS and largest image difference (pixels).

    Raises
    ------
    AdjustmentInputError
        A sensor without camera centre (an RFM: use its affine correction instead).
    """
    for cam in (original, adjusted):
        if not hasattr(cam, "eo"):
            raise AdjustmentInputError(f"asp_adjustment needs rigorous cameras, got {type(cam).__name__}")
    c0 = _center(original)
    xyz, pix = _grid(adjusted, n, heights)
    # start: the adjusted camera's attitude and position change at its first pixel
    t_first = original.image_time(0.5) if hasattr(original, "image_time") else original.time
    r0 = adjusted.eo.rotation_at(np.atleast_1d(t_first))[0] @ original.eo.rotation_at(np.atleast_1d(t_first))[0].T
    start = np.concatenate([Rotation.from_matrix(r0).as_rotvec(), _center(adjusted) - c0])
    scale = np.array([1e-6] * 3 + [1.0] * 3)

    def residual(p: NDArray) -> NDArray:
        q = Rotation.from_rotvec(p[:3] * scale[:3]).as_quat()
        adj = AspAdjustment(p[3:] * scale[3:], np.array([q[3], q[0], q[1], q[2]]), c0)
        line, sample = asp_project(original, adj, xyz)
        return np.concatenate([line - pix[:, 0], sample - pix[:, 1]])

    fit = least_squares(residual, start / scale, method="lm", x_scale="jac")
    q = Rotation.from_rotvec(fit.x[:3] * scale[:3]).as_quat()
    r = residual(fit.x).reshape(2, -1)
    d = np.hypot(r[0], r[1])
    return AspAdjustment(fit.x[3:] * scale[3:], np.array([q[3], q[0], q[1], q[2]]), c0,
                         rms_px=float(np.sqrt(np.mean(d * d))), max_px=float(d.max()))


def write_asp_adjust(path: str | os.PathLike[str], adjustment: AspAdjustment) -> Path:
    """Write an ASP ``.adjust`` file (translation; quaternion w x y z; pixel offset 0 0; scale 1), atomically."""
    t, q = np.asarray(adjustment.translation, float), np.asarray(adjustment.quaternion, float)
    if t.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise InvalidInputError("an ASP adjustment needs a finite translation (3) and quaternion (4)")
    text = (" ".join(repr(float(v)) for v in t) + "\n" + " ".join(repr(float(v)) for v in q) + "\n0 0\n1\n")
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def read_asp_adjust(path: str | os.PathLike[str], original: Any | None = None) -> AspAdjustment:
    """Read an ASP ``.adjust`` file; ``original`` (the camera it adjusts) gives the rotation centre.

    Raises
    ------
    InvalidInputError
        Fewer than 7 numbers, a pixel offset or scale other than 0 / 1 (not modelled).
    """
    values = [float(v) for v in Path(path).read_text().split()]
    if len(values) < 7:
        raise InvalidInputError(f"ASP adjustment {path}: expected translation and quaternion (7 numbers), "
                                f"found {len(values)}")
    if len(values) >= 9 and (values[7] != 0.0 or values[8] != 0.0) or len(values) >= 10 and values[9] != 1.0:
        raise InvalidInputError(f"ASP adjustment {path}: a pixel offset or scale is not supported")
    c0 = _center(original) if original is not None else np.full(3, np.nan)
    return AspAdjustment(np.array(values[:3]), np.array(values[3:7]), c0)


def write_asp_outputs(adjusted: Mapping[str, Any], originals: Mapping[str, Any], isds: Mapping[str, ImageSupport],
                      folder: str | os.PathLike[str], prefix: str = "lunarmap") -> dict[str, dict[str, Any]]:
    """Per image: the adjusted ISD ``<image>.adjusted.json`` and ``<prefix>-<image>.adjust``.

    Parameters
    ----------
    adjusted : mapping image -> camera
        Adjusted cameras (``BlockResult.adjusted_sensors()``).
    originals : mapping image -> camera
        The cameras the block started from (built from ``isds``).
    isds : mapping image -> ImageSupport
        Original image support data.
    folder : path-like
        Output folder (must exist).
    prefix : str
        ``bundle_adjust``'s output prefix.

    Returns
    -------
    dict image -> {"isd": path, "adjust": path, "rms_px": float, "max_px": float}
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"output folder {folder} does not exist")
    missing = [k for k in adjusted if k not in originals or k not in isds]
    if missing:
        raise AdjustmentInputError(f"no original camera or ISD for image(s) {', '.join(missing)}")
    out: dict[str, dict[str, Any]] = {}
    for name, cam in adjusted.items():
        isd_path = folder / f"{name}.adjusted.json"
        updated_image_support(isds[name], cam.eo).write_json(isd_path)
        adj = asp_adjustment(originals[name], cam)
        out[name] = {"isd": isd_path, "adjust": write_asp_adjust(folder / f"{prefix}-{name}.adjust", adj),
                     "rms_px": adj.rms_px, "max_px": adj.max_px}
    return out
