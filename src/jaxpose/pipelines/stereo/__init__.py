"""Stereo point-line tracking of a tumbling target (Yang et al. 2024).

Stages, one module each: :mod:`~jaxpose.pipelines.stereo.options` (options and the per-frame
result), :mod:`~jaxpose.pipelines.stereo.landmarks` (the body-frame landmark map),
:mod:`~jaxpose.pipelines.stereo.guided` (search by projection),
:mod:`~jaxpose.pipelines.stereo.frame_pose` (the pose of a frame),
:mod:`~jaxpose.pipelines.stereo.budget` (the features of a frame's pose solve under a budget),
:mod:`~jaxpose.pipelines.stereo.keyframes` (stereo correspondences and the map update),
:mod:`~jaxpose.pipelines.stereo.window` (the joint adjustment of the last frames and their
landmarks),
:mod:`~jaxpose.pipelines.stereo.frames` (a pair's checks and features, before the tracker's
state comes in), :mod:`~jaxpose.pipelines.stereo.tracker` (:class:`StereoTracker`, which runs
them), :mod:`~jaxpose.pipelines.stereo.stream` (a sequence tracked with the next pair's features
extracted ahead) and
:mod:`~jaxpose.pipelines.stereo.smooth` (the whole tracked sequence adjusted afterwards).
"""

from jaxpose.pipelines.stereo.landmarks import LandmarkMap as LandmarkMap
from jaxpose.pipelines.stereo.landmarks import LandmarkSet as LandmarkSet
from jaxpose.pipelines.stereo.options import BUDGET_RULES as BUDGET_RULES
from jaxpose.pipelines.stereo.options import STAGES as STAGES
from jaxpose.pipelines.stereo.options import FrameResult as FrameResult
from jaxpose.pipelines.stereo.options import TrackerOptions as TrackerOptions
from jaxpose.pipelines.stereo.smooth import smooth_sequence as smooth_sequence
from jaxpose.pipelines.stereo.stream import track_stream as track_stream
from jaxpose.pipelines.stereo.tracker import StereoTracker as StereoTracker
from jaxpose.pipelines.stereo.tracker import as_gray_uint8 as as_gray_uint8
from jaxpose.pipelines.stereo.tracker import target_roi as target_roi

__all__ = [
    "BUDGET_RULES",
    "STAGES",
    "FrameResult",
    "LandmarkMap",
    "LandmarkSet",
    "StereoTracker",
    "TrackerOptions",
    "as_gray_uint8",
    "smooth_sequence",
    "target_roi",
    "track_stream",
]
