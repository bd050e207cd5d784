"""Tie points: Förstner interest points, prediction through sensor models, pyramid NCC,
least-squares matching (Eq. 14 of the LROC multi-image study), RANSAC, multi-image tracks,
the tie-point table (netCDF) and its dask graph."""

from ..errors import BlankTileWarning, InvalidPixelsWarning, MatchingWarning, NoOverlapWarning
from .interest import InterestPoints, foerstner, invalid_mask
from .lsm import LsmResult, lsm_match
from .ncc import NccResult, ncc_match, window_offsets
from .pairs import STATUS, MatchParams, PairMatches, as_array, match_points
from .parallel import WORKER_ENVIRON, find_tiepoints, tiepoint_graph
from .predict import Prediction, predict_conjugates
from .pyramid import build_pyramid, downsample
from .ransac import RansacParams, ransac_local_affine
from .resample import bicubic, bicubic_with_gradient, bilinear
from .tiepoints import (
    DetectParams,
    TiePointParams,
    assemble_tiepoints,
    detect_tile,
    match_pair,
    read_tiepoints,
    tile_windows,
    write_tiepoints,
)
from .tracks import Observations, build_tracks

__all__ = [
    "MatchingWarning", "BlankTileWarning", "NoOverlapWarning", "InvalidPixelsWarning",
    "InterestPoints", "foerstner", "invalid_mask",
    "LsmResult", "lsm_match", "NccResult", "ncc_match", "window_offsets",
    "STATUS", "MatchParams", "PairMatches", "as_array", "match_points",
    "tiepoint_graph", "WORKER_ENVIRON", "Prediction", "predict_conjugates",
    "build_pyramid", "downsample", "RansacParams", "ransac_local_affine",
    "bicubic", "bicubic_with_gradient", "bilinear",
    "DetectParams", "TiePointParams", "assemble_tiepoints", "detect_tile", "find_tiepoints", "match_pair",
    "read_tiepoints", "tile_windows", "write_tiepoints", "Observations", "build_tracks",
]
