"""Checks before any work: what a run needs from its files' content, tested before the first step runs.

:func:`lunarmap.workflows.config.load_config` checks the configuration itself (keys, types, that files
exist); :func:`check_before_work` reads what the steps would read late and tests what they would find:

* the ``[points]`` file is a readable control network, and every image it measures is one of
  ``[[images]]`` (else ``[points] other_images = "ignore"`` drops those measures);
* the adjustment has a datum: navigation observations (``[adjust.navigation]``) or at least 3 control
  points measured in the run's images;
* what remains can be adjusted as configured (check points with 2 rays, a tie-point variance factor
  estimated from the tie points alone when there are no other observations);
* every ``[[adjust.terrain.dtm]]`` is a readable DTM with a Moon CRS
  (:class:`~lunarmap.errors.DtmCrsError`, :class:`~lunarmap.errors.TerrainInputError`), and, once the
  images' footprints are known (before any matching), meets at least one of them
  (:func:`check_terrain_coverage`, :class:`~lunarmap.errors.DtmCoverageError`).

Each failure is a :class:`~lunarmap.errors.ConfigError` naming the key, the file and the fix.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError, LunarmapError

__all__ = ["PointsCheck", "check_before_work", "check_terrain_coverage", "restrict_network"]


@dataclass(frozen=True)
class PointsCheck:
    """What the checks found in the configuration's points file.

    Attributes
    ----------
    control, check : int
        Control points with at least one ray and check points with at least two, in the run's images.
    dropped_measures : int
        Measures of images not in the configuration, dropped (``other_images = "ignore"``).
    dropped_points : int
        Points left with too few rays by that, dropped.
    """

    control: int = 0
    check: int = 0
    dropped_measures: int = 0
    dropped_points: int = 0


def restrict_network(net: Any, images: Sequence[str]) -> tuple[Any, int, int]:
    """The control network ``net`` restricted to the measures of ``images``.

    A control point keeps one ray at least, a check or tie point two; points with fewer are dropped.

    Parameters
    ----------
    net : lunarmap.adjust.ControlNetwork
    images : sequence of str
        Image ids to keep.

    Returns
    -------
    network : lunarmap.adjust.ControlNetwork
        The restricted network (``net`` itself when nothing is dropped).
    dropped_measures, dropped_points : int
    """
    from ..adjust.network import ControlNetwork

    keep_img = np.isin(net.image_id, np.asarray(list(images), dtype=str))
    keep_m = keep_img[net.measure_image]
    rays = np.bincount(net.measure_point[keep_m], minlength=net.n_points)
    keep_p = rays >= np.where(net.point_type == "control", 1, 2)
    keep_m &= keep_p[net.measure_point]
    if keep_m.all() and keep_p.all():
        return net, 0, 0
    new_pt = np.cumsum(keep_p) - 1
    new_img = np.cumsum(keep_img) - 1
    out = ControlNetwork(
        point_id=net.point_id[keep_p], point_type=net.point_type[keep_p], xyz=net.xyz[keep_p],
        measure_point=new_pt[net.measure_point[keep_m]], measure_image=new_img[net.measure_image[keep_m]],
        line_sample=net.line_sample[keep_m], measure_sigma=net.measure_sigma[keep_m], image_id=net.image_id[keep_img],
        image_name=net.image_name[keep_img], xyz_cov=None if net.xyz_cov is None else net.xyz_cov[keep_p],
        radius=net.radius, body=net.body, attrs=dict(net.attrs))
    return out, int((~keep_m).sum()), int((~keep_p).sum())


def _points(cfg: Any) -> PointsCheck:
    from ..adjust import read_network

    src, key = cfg.source, f"points.path = {str(cfg.points)!r}"
    try:
        net = read_network(cfg.points)
    except (OSError, LunarmapError) as err:
        raise ConfigError(f"{src}: {key}: not a readable lunarmap control network ({err}); write it with "
                          "lunarmap.adjust.write_network, or remove [points]") from None
    names = [im.name for im in cfg.images]
    measured = np.unique(net.image_id[np.unique(net.measure_image)]) if net.measure_image.size else np.zeros(0, str)
    other = [str(i) for i in measured if str(i) not in names]
    if other and cfg.points_other_images != "ignore":
        raise ConfigError(
            f"{src}: {key}: the points are measured in {len(other)} image(s) that are not in [[images]]: "
            f"{', '.join(other[:6])}{', ...' if len(other) > 6 else ''}; add them to [[images]], or set "
            "[points] other_images = \"ignore\" to drop those measures")
    kept, dm, dp = restrict_network(net, names)
    n_ctl = int(np.sum(kept.point_type == "control"))
    n_chk = int(np.sum(kept.point_type == "check"))
    if kept.measure_point.size == 0:
        raise ConfigError(f"{src}: {key}: none of its points is measured in the run's images "
                          f"({', '.join(names[:6])}{', ...' if len(names) > 6 else ''}); check the image names "
                          "(the network's image_id) or remove [points]")
    return PointsCheck(n_ctl, n_chk, dm, dp)


def _terrain(cfg: Any) -> None:
    """Open every reference DTM's label (CRS, grid): a DTM without a Moon CRS is refused before any work."""
    from ..adjust.terrain import DtmGrid
    from ..errors import TerrainInputError

    for k, d in enumerate(cfg.terrain):
        try:
            DtmGrid.open(d.path)
        except TerrainInputError as err:
            # the same class (DtmCrsError, ...), the key of the configuration named
            raise type(err)(f"{cfg.source}: adjust.terrain.dtm[{k}] ({d.name}): {err}") from None


def check_terrain_coverage(cfg: Any, footprints: dict[str, Sequence[Any]]) -> None:
    """Every reference DTM of ``cfg`` meets the images' footprints (their outlines' extent in its grid).

    A necessary condition for a DTM to cover a tie point, tested once the footprints are known and
    before any pair is matched.

    Parameters
    ----------
    cfg : lunarmap.workflows.RunConfig
    footprints : dict image name -> sequence of lunarmap.evaluate.footprint.Footprint

    Raises
    ------
    DtmCoverageError
        A DTM whose grid no footprint's extent meets (the message names the DTM and its extent).
    """
    from ..adjust.terrain import DtmGrid, point_height
    from ..errors import DtmCoverageError

    def meets(grid: DtmGrid, f: Any) -> bool:
        # the footprint's extent in the grid's pixels overlaps the grid (an outline off the map does not)
        lon, lat, _, _ = point_height(np.asarray(f.xyz, float), grid.radius)
        col, row = grid.to_pixel(lon, lat)
        if not (np.isfinite(col).all() and np.isfinite(row).all()):
            return False
        nl, ns = grid.shape
        return bool(col.max() >= 0 and col.min() <= ns - 1 and row.max() >= 0 and row.min() <= nl - 1)

    for k, d in enumerate(cfg.terrain):
        grid = DtmGrid.open(d.path)
        nl, ns = grid.shape
        if not any(meets(grid, f) for feet in footprints.values() for f in feet or ()):
            raise DtmCoverageError(
                f"{cfg.source}: adjust.terrain.dtm[{k}] ({d.name}): reference DTM {d.path} covers none of the "
                f"run's tie points: its grid ({ns} x {nl} nodes) meets none of the {len(footprints)} images' "
                "footprints; give a DTM of the block's area, or remove it")


def check_before_work(cfg: Any) -> PointsCheck:
    """Test what the run's steps would find in its files, before any of them runs (module docstring).

    Parameters
    ----------
    cfg : lunarmap.workflows.RunConfig

    Returns
    -------
    PointsCheck
        The points file's usable control and check points (zeros without ``[points]``).

    Raises
    ------
    ConfigError
        An unreadable points file, points measured in images not in the configuration, no datum; the
        message names the key, the file and the fix.
    DtmCrsError, TerrainInputError
        A reference DTM of ``[adjust.terrain]`` without a Moon CRS, or unreadable.
    """
    if getattr(cfg, "terrain", ()):
        _terrain(cfg)
    found = _points(cfg) if cfg.points is not None else PointsCheck()
    if cfg.navigation is None and found.control < 3:
        have = (f"{cfg.points} has {found.control} control point(s) measured in the run's images"
                if cfg.points is not None else "there is no [points] file")
        raise ConfigError(
            f"{cfg.source}: the adjustment has no datum: no [adjust.navigation] and {have}; add "
            "[adjust.navigation] (position_sigma, attitude_sigma: the navigation observes every image) or a "
            "[points] file with 3 or more control points")
    return found
