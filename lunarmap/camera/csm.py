"""ISDs that usgscsm loads and applies as lunarmap does (``lunarmap isd --csm``, ``write_json(csm=True)``).

usgscsm knows the distortion models ``transverse``, ``radial``, ``kaguyalism``, ``dawnfc``,
``lrolrocnac``, ``radtan``, ``kplo_shadowcam`` (and ``cahvor``); an unknown name silently becomes
``transverse`` and then fails to parse (the Apollo metric ISD is refused), and ``lunarorbiter`` is parsed
but never applied (usgscsm treats Lunar Orbiter images as undistorted: 4.3 px off lunarmap). For those
:func:`csm_image_support` replaces the model by the one of two usgscsm models fitted to it over the image
that fits best: the third-order ``transverse`` polynomial
(:func:`~lunarmap.camera.distortion_csm.fit_transverse`; Lunar Orbiter: 2e-4 px) or the
radial-tangential ``radtan`` about the optical axis, the focal plane shifted to put it at the origin
(:func:`~lunarmap.camera.distortion_csm.fit_radtan`; Apollo metric, whose 7th-order radial terms a cubic
cannot follow: 0.24 px RMS, 1.6 px in the corners, against 5 / 58 px for the cubic), and records the fit
error, in pixels on an independent check grid, in the ISD's ``lunarmap`` block. Every other ISD is returned as it is (``none`` becomes a zero
``radial`` model, which usgscsm reads).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from ..errors import InvalidInputError
from ..orientation.isd import ImageSupport
from .distortion import distortion_from_interior
from .distortion_csm import fit_radtan, fit_transverse
from .frame import image_to_focal

__all__ = ["USGSCSM_DISTORTIONS", "csm_image_support"]

#: Distortion models usgscsm parses *and* applies (``Distortion.cpp``).
USGSCSM_DISTORTIONS = ("transverse", "radial", "kaguyalism", "dawnfc", "lrolrocnac", "radtan", "kplo_shadowcam")

_GRID = 41          # fit grid per image axis, edges included
_CHECK = 57         # independent check grid (between the fit nodes)


def csm_image_support(isd: ImageSupport) -> ImageSupport:
    """The ISD with a distortion model usgscsm applies; a fitted ``transverse`` where it has none.

    Parameters
    ----------
    isd : ImageSupport
        Any image support.

    Returns
    -------
    ImageSupport
        A copy; when the model was replaced, ``provenance["csm_distortion"]`` holds the replaced model's
        name and the fit's RMS and largest error in pixels on an independent check grid.

    Raises
    ------
    InvalidInputError
        A line-scan or push-frame image whose distortion usgscsm does not apply (no lunar driver makes one).
    """
    out = copy.deepcopy(isd)
    if out.model == "sar":
        return out
    model = str(next(iter(out.optical_distortion), "none")).lower()
    if model in USGSCSM_DISTORTIONS:
        return out
    if model == "none":
        out.optical_distortion = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
        return out
    if out.model != "frame":
        raise InvalidInputError(f"usgscsm does not apply the {model!r} distortion of the {out.model} image "
                                f"{out.name_sensor!r}; a transverse fit is made for framing cameras only")
    from .factory import interior_from_isd

    io = interior_from_isd(isd)
    dist = distortion_from_interior(io)

    def focal(n: int) -> tuple[np.ndarray, np.ndarray]:
        L, S = np.meshgrid(np.linspace(0.0, io.n_lines, n), np.linspace(0.0, io.n_samples, n), indexing="ij")
        return image_to_focal(io, L.ravel(), S.ravel())

    a = np.array([[io.focal2pixel_lines[1], io.focal2pixel_lines[2]],
                  [io.focal2pixel_samples[1], io.focal2pixel_samples[2]]])
    scale = np.array([io.line_summing, io.sample_summing], dtype=float)
    x, y = focal(_CHECK)                  # the check grid, between the fit grid's nodes
    ux, uy = dist.undistort(x, y)

    def error_px(model: Any, shift: tuple[float, float]) -> np.ndarray:
        """Pixel distance of the same rays' distorted positions, replaced model vs original."""
        px, py = model.distort(ux, uy)
        return np.linalg.norm(np.stack([px + shift[0] - x, py + shift[1] - y], -1) @ a.T / scale, axis=-1)

    transverse, _ = fit_transverse(dist, *focal(_GRID))
    radtan, shift, _ = fit_radtan(dist, *focal(_GRID), focal_length=io.focal_length)
    candidates = [("transverse", transverse, (0.0, 0.0), error_px(transverse, (0.0, 0.0))),
                  ("radtan", radtan, shift, error_px(radtan, shift))]
    name, model_fit, shift, err = min(candidates, key=lambda c: float(np.nanmax(c[3])))
    if name == "transverse":      # model_fit is transverse
        out.optical_distortion = {"transverse": {"x": transverse.cx.tolist(), "y": transverse.cy.tolist()}}
    else:                         # model_fit is radtan
        k = [radtan.k1, radtan.k2, radtan.p1, radtan.p2, radtan.k3]
        out.optical_distortion = {"radtan": {"coefficients": [float(v) for v in k]}}
        # radtan is centred on the focal-plane origin: move the optical axis there (x' = x - shift)
        f2l, f2s = list(out.focal2pixel_lines), list(out.focal2pixel_samples)
        f2l[0] += f2l[1] * shift[0] + f2l[2] * shift[1]
        f2s[0] += f2s[1] * shift[0] + f2s[2] * shift[1]
        out.focal2pixel_lines, out.focal2pixel_samples = f2l, f2s
    others = {c[0]: float(np.nanmax(c[3])) for c in candidates}
    out.provenance["csm_distortion"] = {
        "replaced": model, "by": f"{name} (fitted over the image)",
        "fit_rms_px": float(np.sqrt(np.nanmean(err ** 2))), "fit_max_px": float(np.nanmax(err)),
        "check_grid": f"{_CHECK} x {_CHECK}", "max_px_by_model": others}
    return out


def csm_fit_report(isd: ImageSupport) -> dict[str, Any] | None:
    """The ``csm_distortion`` record of a converted ISD, or ``None`` when nothing was replaced."""
    return isd.provenance.get("csm_distortion")
