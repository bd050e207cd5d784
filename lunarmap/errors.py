"""Every exception and warning that lunarmap raises.

All exceptions derive from :class:`LunarmapError`; most also derive from the
built-in exception a Python user would expect (``FileNotFoundError``,
``ValueError``, ``KeyError``), so ``except ValueError`` keeps working.
Each message names the cause: the file, body, frame, instrument or time
involved.
"""

from __future__ import annotations

import warnings

__all__ = [
    "LunarmapError",
    "KernelError",
    "MissingKernelError",
    "KernelCoverageError",
    "SpiceError",
    "UnknownInstrumentError",
    "LabelError",
    "InvalidInputError",
    "GeometryError",
    "NoIntersectionError",
    "DistortionPartialsError",
    "JitterKnotSpacingError",
    "ConvergenceError",
    "LunarmapWarning",
    "warn",
    "RpcError",
    "RpcInputError",
    "RpcFormatError",
    "RpcGridError",
    "RpcLimbError",
    "RpcFitError",
    "RpcConvergenceError",
    "MatchingWarning",
    "BlankTileWarning",
    "NoOverlapWarning",
    "InvalidPixelsWarning",
    "SimulationWarning",
    "AdjustmentError",
    "AdjustmentInputError",
    "InsufficientObservationsError",
    "UnobservedParameterError",
    "DatumDefectError",
    "AdjustmentDivergedError",
    "NetworkFormatError",
    "IsdFormatError",
    "IsdConventionWarning",
    "OrientationKernelError",
    "OrientationCoverageError",
    "OrientationConflictError",
    "MissingClockError",
    "TrajectoryFitError",
    "BlockMissionError",
    "ConfigError",
    "WorkflowError",
    "EvaluationError",
    "EvaluationInputError",
    "NoOverlapError",
    "CheckPointError",
    "MissingDependencyError",
    "MissionError",
    "FlightParameterError",
    "ReseauError",
    "CubeError",
    "CubeFormatError",
    "CubeWriteError",
    "MissingSpiceTablesError",
    "IsisNetworkFormatError",
    "UnknownImageError",
    "QualityControlError",
    "TerrainInputError",
    "DtmCrsError",
    "DtmCoverageError",
    "AltimetryInputError",
    "AltimetryCoverageError",
    "QualityControlInputError",
    "QualityControlWarning",
    "VarianceComponentError",
]


class LunarmapError(Exception):
    """Base class of every lunarmap exception."""


class KernelError(LunarmapError):
    """A SPICE kernel could not be loaded or used."""


class MissingKernelError(KernelError, FileNotFoundError):
    """A kernel file (or meta-kernel) named by the user or a meta-kernel does not exist."""


class KernelCoverageError(KernelError):
    """The loaded kernels hold no data for the requested body, frame or time.

    Raised for a time outside SPK or CK coverage, a missing frame chain or a
    missing clock kernel. The message names the object and the epoch.
    """


class SpiceError(LunarmapError):
    """Any other error reported by the SPICE toolkit; the SPICE message is kept."""


class UnknownInstrumentError(LunarmapError, KeyError):
    """No driver or kernel-pool entry exists for the instrument named or implied."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class LabelError(LunarmapError, ValueError):
    """An image label (ISIS cube label, PDS3 label) is malformed or lacks a keyword."""


class InvalidInputError(LunarmapError, ValueError):
    """An argument is unusable: NaN or infinite coordinates, wrong shape, empty range."""


class GeometryError(LunarmapError):
    """The requested geometry cannot be computed."""


class NoIntersectionError(GeometryError):
    """A look ray misses the body (or the DTM) altogether."""


class DistortionPartialsError(InvalidInputError):
    """A distortion model has no analytic partial derivatives, so it cannot be adjusted."""


class JitterKnotSpacingError(InvalidInputError):
    """A line-scan jitter spline's knot spacing is not a finite number of lines >= 1 (the attitude
    cannot be resolved below one exposure)."""


class ConvergenceError(GeometryError):
    """An iterative solution (ground-to-image, DTM intersection) did not converge."""


class LunarmapWarning(UserWarning):
    """Base class of lunarmap warnings."""


def warn(message: str, category: type[Warning] = LunarmapWarning, stacklevel: int = 2) -> None:
    """Issue a lunarmap warning, attributed to the caller's caller."""
    warnings.warn(message, category, stacklevel=stacklevel + 1)


# --- Rational function models (lunarmap.rpc) -------------------------------

class RpcError(LunarmapError):
    """Base class of the RPC package's errors."""


class RpcInputError(RpcError, InvalidInputError):
    """An argument of an RPC function is unusable (NaN, empty height range, wrong shape)."""


class RpcFormatError(RpcError, InvalidInputError):
    """An RPC file or dataset is malformed: missing keyword, wrong count, non-finite value."""


class RpcGridError(RpcError, NoIntersectionError):
    """The virtual control grid cannot be built: its rays miss the body."""


class RpcLimbError(RpcGridError):
    """The image footprint reaches the limb: some grid rays miss the body or graze it."""


class RpcFitError(RpcError, GeometryError):
    """The fitted rational function is unusable (denominator near zero, footprint over a pole)."""


class RpcConvergenceError(RpcError, ConvergenceError):
    """The RFM image-to-ground Newton iteration did not converge."""


# --- Tie-point matching (lunarmap.matching) --------------------------------

class MatchingWarning(LunarmapWarning):
    """Base class of matching warnings: some points could not be detected or matched."""


class BlankTileWarning(MatchingWarning):
    """A tile has no usable texture (constant, saturated or mostly NaN); no interest points there."""


class NoOverlapWarning(MatchingWarning):
    """Two images do not overlap (no predicted conjugate inside the second image)."""


class InvalidPixelsWarning(MatchingWarning):
    """An image holds NaN, infinite or saturated pixels; windows touching them are not matched."""


# --- Image simulation (lunarmap.simulate) ----------------------------------

class SimulationWarning(LunarmapWarning):
    """A rendered image is incomplete: some pixels see no DTM or orthoimage and are NaN."""


# --- Block adjustment (lunarmap.adjust) ------------------------------------

class AdjustmentError(LunarmapError):
    """Base class of block-adjustment errors."""


class AdjustmentInputError(AdjustmentError, InvalidInputError):
    """An adjustment input is unusable (NaN, wrong shape, index out of range, bad sigma)."""


class InsufficientObservationsError(AdjustmentInputError):
    """Fewer observations than unknowns: the problem has no redundancy."""


class UnobservedParameterError(AdjustmentInputError):
    """An image or point has no (or too few) observations to determine its unknowns."""


class DatumDefectError(AdjustmentError):
    """The normal equations are singular: the datum (gauge) is not defined.

    Add control points, navigation observations, or fix parameters.
    """


class AdjustmentDivergedError(AdjustmentError, ConvergenceError):
    """The Levenberg-Marquardt iteration could not reduce the cost any further from a non-finite state."""


class NetworkFormatError(AdjustmentInputError):
    """A control-network file or dataset is malformed: missing variable, bad point type, index out of range."""


class TerrainInputError(AdjustmentInputError):
    """A reference DTM cannot serve as terrain observations (bad sigma, unreadable file, rotated grid);
    the message names the file and the cause."""


class DtmCrsError(TerrainInputError):
    """A reference DTM has no coordinate reference system, or one that is not a Moon sphere (the heights
    would be measured from an unknown datum)."""


class DtmCoverageError(TerrainInputError):
    """A reference DTM covers none of the block's tie points (outside its grid or on NaN nodes)."""


class AltimetryInputError(TerrainInputError):
    """A laser-altimetry shot table cannot serve as observations (missing column, NaN value, a track with
    one shot, bad sigma, unreadable file); the message names the file, the column or the track."""


class AltimetryCoverageError(AltimetryInputError):
    """No laser-altimetry shot falls inside the tie points' triangulation (the tracks miss the block)."""


# --- ISD JSON files (lunarmap.orientation.isd_reader, feature isd-json) -----

class IsdFormatError(LunarmapError, ValueError):
    """An ISD JSON document is unusable; the message names the file and the key.

    Malformed JSON, a missing key, a wrong type or shape, a non-finite number,
    an unknown ``name_model`` or distortion model.
    """


class IsdConventionWarning(LunarmapWarning):
    """An ISD follows a convention lunarmap reads the way usgscsm does, which a user should know.

    E.g. a camera whose boresight points away from the body: usgscsm intersects the whole line of
    sight, in either direction, so such ISDs (its own test ISDs) image the body behind the camera;
    lunarmap reads them looking the other way, as usgscsm sees them.
    """


# --- Adjusted orientation written back as ISDs and kernels (lunarmap.orientation.update / .kernels) ---

class OrientationKernelError(LunarmapError):
    """Base class of the errors raised while writing adjusted orientation back as ISDs or kernels."""


class OrientationCoverageError(OrientationKernelError, InvalidInputError):
    """An adjusted exterior orientation does not cover the epochs of its image (or has another body frame)."""


class OrientationConflictError(OrientationKernelError, InvalidInputError):
    """Images overlapping in time want different orientations of one spacecraft or one CK frame.

    One SPK holds one trajectory per spacecraft and one CK one attitude per frame; the
    message names both images, the object and the size of the disagreement.
    """


class MissingClockError(OrientationKernelError, KernelCoverageError):
    """The spacecraft clock a CK frame is encoded with is not defined by the kernel set."""


class TrajectoryFitError(OrientationKernelError, ConvergenceError):
    """The geometric trajectory reproducing the adjusted (aberration-corrected) positions was not found."""
# --- Synthetic block mission (lunarmap.synthetic.block, lunarmap.simulate.mission) ---

class BlockMissionError(InvalidInputError, FileNotFoundError):
    """A synthetic block-mission folder is missing, incomplete or does not match its manifest."""


# --- Workflows (lunarmap.workflows) ---------------------------------------------

class ConfigError(LunarmapError, ValueError):
    """A run configuration is unusable: unknown section or key, wrong type, missing file (all named)."""


class WorkflowError(LunarmapError):
    """A step of a run failed; the message names the step, the image or pair, and the cause."""


# -- evaluation and planning (lunarmap.evaluate, issue 12) ---------------------------------------

class EvaluationError(LunarmapError):
    """Base class of the errors of :mod:`lunarmap.evaluate`."""


class EvaluationInputError(EvaluationError, InvalidInputError):
    """Bad input to an evaluation: a single image where a pair is needed, unknown image names, bad arrays."""


class NoOverlapError(EvaluationError, GeometryError):
    """Two images (named) have no common ground coverage."""


class CheckPointError(EvaluationInputError):
    """Check points that cannot be evaluated (named): outside the images, too few rays, no reference."""


class MissingDependencyError(LunarmapError, ImportError):
    """An optional dependency (named, with the extra that installs it) is not installed."""



# --- Historical missions (lunarmap.missions, issue 13: Ranger flight parameters, reseau, multi-ray) ---

class MissionError(LunarmapError):
    """Base class of the errors of :mod:`lunarmap.missions` (historical missions)."""


class FlightParameterError(MissionError, InvalidInputError):
    """A flight-parameter table is unusable: a missing column, a non-number, an impossible geometry
    (``Range`` shorter than the altitude, ``|LAT| > 90``, a camera below the surface) or values that
    contradict each other; the message names the file, the photo and the column."""


class ReseauError(MissionError, InvalidInputError):
    """Reseau marks cannot define the correction: fewer marks than the grid needs, missing or
    non-finite marks, a degenerate (folded) grid cell, or a point outside the reseau."""


# --- ISIS cubes, ISIS control networks, ASP files (lunarmap.io, issue 14) ---

class CubeError(LunarmapError):
    """Base class of the errors raised while reading or writing image cubes and rasters."""


class CubeFormatError(CubeError, LabelError):
    """An image file is unusable: truncated, an unsupported pixel type or layout, a malformed label.

    The message names the file and the keyword or byte range involved.
    """


class CubeWriteError(CubeError, OSError):
    """An image file could not be written: its folder is missing or read-only, the disk is full.

    The message names the file and the operating system's cause; nothing is left under the file's
    name (a partial file stays under a hidden temporary name only if the process was killed).
    """


class ImageWindowError(CubeError, InvalidInputError):
    """A window of an image cannot be read: outside the image, or the file is missing, damaged or shorter
    than its header says where the window lies (the message names the file and the window)."""


class PyramidError(CubeError):
    """An image pyramid (overview) store is missing, damaged or does not belong to its image."""


__all__ += ["ImageWindowError", "PyramidError"]


class MissingSpiceTablesError(CubeError, LabelError):
    """An ISIS cube lacks the tables ``spiceinit`` attaches (``InstrumentPointing``, ...), or a keyword
    a camera without kernels needs (``NaifKeywords``, a ``CLOCK_ET_..._COMPUTED`` entry)."""


class IsisNetworkFormatError(NetworkFormatError):
    """An ISIS control network file is unusable: unknown version, malformed protobuf or PVL."""


class UnknownImageError(IsisNetworkFormatError):
    """A control measure refers to an image (ISIS serial number) that is not in the image list."""

# --- Quality control of the adjustment (issue 11: lunarmap.adjust.qc) -------------------------------

class QualityControlError(AdjustmentError):
    """Quality control of an adjustment (pre-screening, robust reweighting, data snooping, variance
    components, offset/drift detection) cannot go on; the message names the step and the cause."""


class QualityControlInputError(QualityControlError, AdjustmentInputError):
    """A quality-control setting is unusable: a limit <= 0, an unknown step or weight function, groups
    that do not fit the block."""


class QualityControlWarning(LunarmapWarning):
    """Quality control ended without a clean block: its budget spent, a step failed on the data, sigma0
    outside its chi-square bounds, w-tests or untestable residuals above the limit left (the message lists
    them; ``QCReport.summary["flags"]`` has them one by one)."""


class VarianceComponentError(QualityControlError, AdjustmentInputError):
    """A group of observations has too little redundancy for its variance component to be estimated
    (the message names the group and its redundancy)."""


# --- Reliability (issue 15): named errors for what fuzzing the readers found ---

class LabelKeywordError(LabelError, KeyError):
    """A label lacks a keyword or group that was asked for; the message names the label file and the keyword path."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class TiePointFormatError(InvalidInputError):
    """A tie-point table file is unreadable or is not a tie-point table (missing variable, bad index, NaN)."""


__all__ += ["LabelKeywordError", "TiePointFormatError"]


# -- reliability of runs (issue 28) ----------------------------------------------------------------

class StoreDamageWarning(LunarmapWarning):
    """A stored step output is damaged or unverifiable (checksum mismatch, missing, unreadable): it is
    recomputed, never reused. The message names the file."""


class DiskError(WorkflowError, OSError):
    """Writing failed because of the disk; the message names the path and what was being written."""

    def __str__(self) -> str:  # OSError would format (errno, strerror)
        return str(self.args[0]) if self.args else ""


class DiskFullError(DiskError):
    """No space left (``ENOSPC``, ``EDQUOT``), or less free space than a run needs, found before any work."""


class DiskWriteError(DiskError, PermissionError):
    """A folder or file is not writable: read-only file system (``EROFS``), permission denied."""


class RunLockedError(WorkflowError):
    """Another run holds the run folder's lock (``<run>/run.lock``, named with its pid, host and start)."""


__all__ += ["StoreDamageWarning", "DiskError", "DiskFullError", "DiskWriteError", "RunLockedError"]
