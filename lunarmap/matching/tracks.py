"""Multi-image tracks: one point id per ground feature seen in two or more images.

Observations are graph nodes: an interest point of image ``i`` is one node
however many images it is matched into, every matched position is a node,
and nodes of the same image closer than ``tol`` pixels are merged (the same
feature found from different anchors). Connected components
(``scipy.sparse.csgraph``) are the tracks. A track holding two positions in
one image further apart than ``tol`` is contradictory and dropped whole.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import InvalidInputError

__all__ = ["Observations", "build_tracks"]


@dataclass
class Observations:
    """Rows of image measurements with the node (feature-in-image) each belongs to.

    ``node`` ties rows that are the same measurement (an anchor reused by
    several pairs); ``edge_a``/``edge_b`` index rows that a match links.
    """

    image: NDArray[np.int64]
    node: NDArray[np.int64]
    line: NDArray[np.float64]
    sample: NDArray[np.float64]
    sigma_line: NDArray[np.float64]
    sigma_sample: NDArray[np.float64]
    correlation: NDArray[np.float64]
    edge_a: NDArray[np.int64]
    edge_b: NDArray[np.int64]


def build_tracks(obs: Observations, tol: float = 0.5) -> tuple[pd.DataFrame, int]:
    """Group observations into tracks.

    Parameters
    ----------
    obs : Observations
    tol : float
        Positions of one image closer than this (pixels) are the same feature.

    Returns
    -------
    table : pandas.DataFrame
        One row per (track, image): ``point_id``, ``image_id``, ``line``,
        ``sample``, ``sigma_line``, ``sigma_sample``, ``correlation``; only
        tracks seen in >= 2 images; point ids are 0..n-1.
    n_conflicts : int
        Tracks dropped because they held contradictory positions in one image.
    """
    n = obs.line.size
    cols = ["point_id", "image_id", "line", "sample", "sigma_line", "sigma_sample", "correlation"]
    if n == 0:
        return pd.DataFrame({c: pd.Series(dtype=float) for c in cols}), 0
    if tol <= 0:
        raise InvalidInputError(f"track merge tolerance must be > 0 pixels, got {tol}")
    # Row graph: rows of one node, matched rows, and rows of one image within tol.
    _, node_first = np.unique(obs.node, return_inverse=True)
    order = np.argsort(node_first, kind="stable")
    same_node = order[1:][np.diff(node_first[order]) == 0]
    prev_node = order[:-1][np.diff(node_first[order]) == 0]
    ea, eb = [obs.edge_a, same_node], [obs.edge_b, prev_node]
    for img in np.unique(obs.image):
        rows = np.flatnonzero(obs.image == img)
        pairs = cKDTree(np.column_stack([obs.line[rows], obs.sample[rows]])).query_pairs(tol, output_type="ndarray")
        if pairs.size:
            ea.append(rows[pairs[:, 0]])
            eb.append(rows[pairs[:, 1]])
    a = np.concatenate(ea)
    b = np.concatenate(eb)
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    df = pd.DataFrame({"track": comp, "image_id": obs.image, "line": obs.line, "sample": obs.sample,
                       "sigma_line": obs.sigma_line, "sigma_sample": obs.sigma_sample,
                       "correlation": obs.correlation})
    g = df.groupby(["track", "image_id"], sort=True)
    spread = np.hypot(g["line"].max() - g["line"].min(), g["sample"].max() - g["sample"].min())
    bad_tracks = np.unique(spread.index.get_level_values("track")[spread.to_numpy() > 2.0 * tol])
    agg = g.agg(line=("line", "mean"), sample=("sample", "mean"), sigma_line=("sigma_line", "mean"),
                sigma_sample=("sigma_sample", "mean"), correlation=("correlation", "mean")).reset_index()
    agg = agg[~agg["track"].isin(bad_tracks)]
    n_img = agg.groupby("track")["image_id"].transform("size")
    agg = agg[n_img >= 2]
    agg.insert(0, "point_id", pd.factorize(agg["track"], sort=True)[0])
    return agg.drop(columns="track")[cols].reset_index(drop=True), int(bad_tracks.size)
