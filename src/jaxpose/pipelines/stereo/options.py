"""Options of the stereo tracker and its per-frame result."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jaxpose.core._checks import check_fields, is_finite_number
from jaxpose.core.geometry import Pose
from jaxpose.core.residuals import ROBUST_KINDS
from jaxpose.vision.stereo_features import FeatureOptions
from jaxpose.vision.stereo_match import StereoMatchOptions

__all__ = ["BUDGET_NOISE", "BUDGET_RULES", "STAGES", "FrameResult", "TrackerOptions"]

#: Stages timed by :meth:`~jaxpose.pipelines.stereo.StereoTracker.process` (seconds each).
STAGES = ("features", "match", "stereo", "triangulate", "budget", "pose", "map")

#: Rules of ``TrackerOptions.feature_budget`` (:mod:`jaxpose.pipelines.stereo.budget`).
BUDGET_RULES = ("dop", "random", "response")

#: Feature noise models of the ``"dop"`` budget rule (:mod:`jaxpose.pipelines.stereo.budget`).
BUDGET_NOISE = ("pixel", "landmark", "measured", "both")

#: Weights of the ``"dop"`` budget rule's criterion (:mod:`jaxpose.pipelines.stereo.budget`).
BUDGET_WEIGHTS = ("chaser", "relative")


#: Where the anchored patches' warp takes the surface plane through each landmark
#: (:mod:`jaxpose.pipelines.stereo.anchor`): the plane facing the reference camera, the plane of
#: the nearest landmarks, or the slant of the reference frame's stereo disparity.
ANCHOR_NORMALS = ("facing", "map", "stereo")
#: What holds the windowed adjustment's gauge once the given first frame has left the window
#: (``TrackerOptions.window_gauge``): ``"rays"`` the rays of the frames that left it (each
#: landmark's prior), ``"oldest"`` the oldest frame's pose, held where it is.
WINDOW_GAUGES = ("rays", "oldest")


#: Kinds of the plain fields of :class:`TrackerOptions` (:func:`jaxpose.core._checks.check_fields`).
_FIELD_KINDS = dict(
    flags=(
        "use_lines",
        "adaptive_radius",
        "frame_rays",
        "stereo_residuals",
        "line_planes",
        "frame_planes",
        "line_stereo_residuals",
        "row_lines",
        "measured_line_sigma",
        "predicted_disparity",
        "threads",
        "window_free_lines",
        "window_held_lines",
        "keep_history",
        "budget_window",
        "anchor_points",
        "measured_point_sigma",
        "landmark_point_sigma",
    ),
    integers={
        "feature_budget": 4,
        "window_frames": 0,
        "window_frames_far": 2,
        "max_points": 1,
        "max_lines": 1,
        "min_features": 1,
        "keyframe_every": 1,
        "keyframe_min": 0,
        "passes": 1,
        "max_obs": 1,
        "cull_after": 1,
        "keep_obs": 0,
        "descriptor_memory": 1,
        "keypoint_floor": 1,
        "mature_obs": 0,
        "window_iterations": 1,
        "window_every": 1,
        "window_points": 1,
        "window_anchors": 0,
        "window_anchor_every": 1,
        "window_anchor_points": 1,
        "anchor_half_px": 1,
        "anchor_follow_px": 0,
        "predicted_disparity_after": 0,
    },
    positive=(
        "depth_margin_m",
        "sigma_px",
        "line_sigma_px",
        "search_radius_px",
        "line_angle_deg",
        "inlier_px",
        "keypoint_spacing_px",
        "lsd_area_px",
        "fine_corners_area_px",
        "neighbour_px",
        "window_depth_m",
        "window_far_m",
        "budget_subsample",
        "anchor_turn_deg",
    ),
    limits=(
        "max_rms_px",
        "max_jump_deg",
        "max_jump_m",
        "reject_px",
        "max_view_deg",
        "refine_disparity_px",
    ),
    non_negative=(
        "duplicate_px",
        "disparity_margin_px",
        "budget_repeat_discount",
        "anchor_affine_prior",
    ),
    fractions=("cull_ratio", "line_scale_memory", "anchor_cornerness"),
    optional=(
        "feature_budget",
        "depth_margin_m",
        "keypoint_spacing_px",
        "lsd_area_px",
        "fine_corners_area_px",
        "window_depth_m",
        "window_far_m",
        "anchor_turn_deg",
        "anchor_affine_prior",
    ),
)


def _as_pair(value):
    """A list or 1-D NumPy array of two numbers as a tuple (a frozen option stays hashable and
    prints as the documented tuple); anything else as it is, for the checks to judge."""
    if isinstance(value, np.ndarray) and value.shape == (2,) and value.dtype.kind in "iuf":
        return tuple(float(v) for v in value)
    if isinstance(value, list) and len(value) == 2:
        return tuple(value)
    return value


@dataclass(frozen=True)
class TrackerOptions:
    """Options of :class:`~jaxpose.pipelines.stereo.StereoTracker`.

    Attributes:
        use_lines: fuse line features (``False``: points-only mode).
        depth_range_m: depths searched by the epipolar search (sets the disparity range).
        depth_margin_m: once the target depth is known, search only ``depth +- margin`` (the
            target's half size plus a margin; ``None`` searches the whole range every frame).
        robust: kernel of eq. 10 (``"huber"``, ``"cauchy"``, ``"tukey"`` or ``None``).
        sigma_px, line_sigma_px: pixel noise of points and line distances (information matrices).
        max_points, max_lines: padding sizes of the solver (one compiled function for a
            sequence); beyond ``max_points`` matches the most observed landmarks are kept.
        min_features: fewer matched features (points + lines) than this is LOST.
        max_rms_px: a post-fit RMS reprojection error above this is LOST.
        max_jump_deg, max_jump_m: a pose further than this from the prediction is LOST.
        search_radius_px: search-by-projection radius around the landmarks' predicted pixels
            (constant-velocity prediction) on the first tracked frame; doubled on the frame
            after a lost one.
        adaptive_radius: afterwards the radius follows the measured prediction error: three
            times the 90th percentile of the distance between the landmarks' pixels predicted
            from the constant-velocity pose and from the fitted pose, plus ``3 sigma_px``, within
            ``[search_radius_px / 2, 4 search_radius_px]``.
        line_angle_deg: a current segment is a candidate for a landmark segment when their
            directions differ by less than this (and they overlap, within the radius).
        keyframe_every, keyframe_min: the map is updated (stereo triangulation of the frame's
            features) every ``keyframe_every`` tracked frames, or when fewer than
            ``keyframe_min`` inliers remain.
        inlier_px: post-fit residual below which a feature counts as an inlier.
        passes, reject_px: LM passes; features with a residual above ``reject_px`` after a pass
            are left out of the next.
        max_view_deg, max_obs, cull_after, cull_ratio, keep_obs: visibility cone, running-mean
            cap and culling of the :class:`~jaxpose.pipelines.stereo.LandmarkMap`.
        descriptor_memory: ORB descriptors each point landmark keeps, those of its latest
            keyframe observations; the search by projection takes the nearest of them. ORB
            finds one corner on another pyramid level and at another orientation from one
            frame to the next, and one descriptor then misses it (at 4.3 m two thirds of the
            corners found again within 1.5 px change level, their descriptors a median 79 bits
            apart against 37 on the same level; ``bench/stereo_matching.py``). Four match 8% more
            landmarks rightly at 5 m, but the poses moved within the tracker's scatter from run
            to run (6% lower on the development scenes, 7% higher on a drawn set; 1, the
            default, keeps the latest only: ``docs/stereo-evaluation.md``, *Descriptor memory*).
        refine_disparity_px: a landmark's new triangulation is averaged in only when its
            disparity is within this of the landmark's predicted disparity (stereo mismatches
            are left out).
        duplicate_px: an unmatched feature within this of an unmatched landmark's projection
            does not become a new landmark.
        frame_rays: add every tracked frame's left observation rays to the landmarks'
            triangulations (else only those of keyframes with a stereo match).
        stereo_residuals: also fit the right-image pixels of the matched landmarks.
        features: the feature options; 2000 ORB keypoints instead of 1200 (chosen on the clean
            2 m sequences, noise seeds 0-2: per-axis RMS position errors at most 10.5 mm instead
            of at most 16.5 mm, at about 2/3 of the frame rate), and ORB's corners on three
            pyramid levels at the sub-pixel peak of their corner response (``orb_levels=3``,
            ``subpixel="peak"``) instead of eight levels refined by ``cornerSubPix`` (the
            default until 2026-12-01): on the development scenes and draws the errors are the
            same within their scatter (the worst axes summed 7% lower beyond 3.5 m, 23 of 25 far
            runs meeting the targets either way), and a frame at 1.5-2 m takes 0.83-0.85 of the
            wall time, 0.79-0.80 of the CPU (no ``cornerSubPix`` and five levels fewer to
            detect, a cheaper search by projection and map upkeep); the same at 4 m
            (``docs/stereo-evaluation.md``, *Three pyramid levels at the response's peak*).
        keypoint_spacing_px: the ORB budget of a frame is the target's apparent area (its bright
            pixels on the dark sky, measured on the frame) divided by ``spacing^2``: one keypoint
            per ``spacing x spacing`` pixels of target, within ``[keypoint_floor,
            features.n_points]`` (about 2000 at 2 m for the 1 m target, 700 at 3 m). A near target
            seen with more gets weak extra corners. ``None``: always ``features.n_points``.
        keypoint_floor: the least ORB budget a frame gets from ``keypoint_spacing_px`` (at most
            ``features.n_points``). ORB shares its budget among its pyramid levels and
            keeps the strongest corners of each, so a small budget on a small target keeps a
            few of many similar corners, a different few every frame: on the 5 m development
            scene (``d6``, frame 0) a budget of 250 gave 230 keypoints of which 13-34 were found
            again within 12 px of their true pixels 1-8 frames later, 1000 gave 795 and 174-233,
            2000 836 and 176-243 (ray-cast truth; ``bench/stereo_diagnose.py --repeat``): 1000
            keeps about all the corners the target holds at 5 m. It acts beyond about 2.5 m for
            the 1 m target; chosen on the development scenes at 3-5 m against 100, 1500 and
            ``n_points`` (``docs/stereo-evaluation.md``).
        lsd_area_px: on a target of apparent area ``A`` above this (pixels; the 1 m target at
            about 2 m), LSD runs at ``features.lsd_scale * sqrt(lsd_area_px / A)`` (at least 0.4)
            instead of ``features.lsd_scale``: it then scans about as many pixels of target as
            at 2 m, and the near target's edges are long enough to be found on the coarser image
            (on ``d3``, 1.5 m: scale 0.6, 12 ms instead of 21 ms of LSD, as many segments longer
            than eq. 1's bound). ``None``: always ``features.lsd_scale``.
        fine_corners_area_px: on a target of apparent area at least this (pixels), the
            keypoints are ORB's full-resolution corners at the sub-pixel peak of their corner
            response (``features.orb_levels=1``, ``features.subpixel="peak"``) instead of the
            default's three pyramid levels (measured against eight levels refined by
            ``cornerSubPix``, the default then); a sequence leaves them only below
            the threshold over :data:`~jaxpose.pipelines.stereo.frames.FINE_CORNERS_BAND`
            (hysteresis). A speed option, off by default (``None``): at 100 000 (the 1 m
            target nearer than about 2.3 m) a frame at 1.5-2 m takes two thirds of the CPU
            (fewer, distinct corners, cheaper to find, search in stereo and match), and the
            clean and glinting development scenes at 1.5-2 m gain a little accuracy, but on a
            tumbling, blurred target at 2 m the errors about double (a development scene of
            our own, noise seeds 0-2: worst axes 5.0, 8.6, 6.7 mm against 2.4, 3.6, 5.3), and
            at 2.5 m and beyond too few corners remain (``docs/stereo-evaluation.md``).
        line_planes: refine the line landmarks from all their observation planes (the planes
            through each camera centre and the segment, body frame, of every stereo pair that
            matched the landmark; :meth:`~jaxpose.pipelines.stereo.LandmarkMap.observe_lines`)
            instead of keeping the first stereo triangulation. A matched segment's planes are
            used only when its stereo triangulation agrees with the landmark line to
            ``refine_disparity_px`` at both endpoints (the point rays' gate): a stereo or LBD
            mismatch would otherwise tilt the line for good.
        frame_planes: with ``line_planes``, add every tracked frame's left-image plane of each
            line kept in its pose solve to the line's multi-view fit (the lines' ``frame_rays``;
            :func:`~jaxpose.pipelines.stereo.keyframes.observe_left_planes`), else only those of
            keyframes whose stereo triangulation agrees with the landmark. A line whose first
            triangulation was off then moves with its later views, and the windowed adjustment
            frees it. Off: measured against the lines held in the window (the default before
            2026-12-02), the development scenes' worst axes summed 0.96 of it over seeds 0-5
            (``d5`` 0.61) and 32 of 36 runs beyond 3.5 m of the development draws met the
            targets against 28, but on one tumbling scene at 4.3 m a line moved with the
            drifting pose and the run went 225 mm astray, on both noise seeds tried
            (``docs/stereo-evaluation.md``, *Lines held in the window*).
        line_stereo_residuals: with ``stereo_residuals``, also fit the right-image lines of the
            matched segments that have a stereo match (the landmark segment shifted by
            ``R^T t_rl``, as the points), so that a line counts in both images as a point does.
        row_lines: also make line landmarks of the segments along the image rows (within
            ``stereo.min_epipolar_angle_deg``), which have no stereo match of their own, with
            the depth of the stereo keypoints beside them
            (:mod:`~jaxpose.pipelines.stereo.row_lines`); their depth enters the line's planes
            as a plane across the line of sight
            (:func:`~jaxpose.pipelines.stereo.keyframes.observe_line_planes`), and only their
            left image is fitted. The matched lines measure the motion along the rows, these
            the motion across them.
        measured_line_sigma: weight the lines by their measured noise: ``line_sigma_px`` is
            scaled by the ratio of the line to the point residual scales (medians of the
            residuals kept by the last pass), averaged over frames with weight
            ``line_scale_memory`` on the past.
        mature_obs: landmarks triangulated in fewer stereo frames than this (the first frame's
            excepted) are matched and refined but left out of the pose solve, so that a new
            landmark's position averages several frames' poses before a pose leans on it
            (0 or 1: every landmark is used at once).
        predicted_disparity: search each feature's right match only in its own disparity window
            (:meth:`~jaxpose.pipelines.stereo.StereoTracker.feature_disparities`): a feature
            matched to a landmark around the landmark's disparity at the predicted pose, plus or
            minus a margin measured on the previous frame (``4 sigma + 2`` px within 3-24 px,
            ``sigma`` the robust scale of the measured minus predicted disparities of the
            matched points); an unmatched feature with matched points within ``neighbour_px``
            around the range of their predicted disparities; the others over the map's depth
            window. On by default since the anchored observations: at 1.5-2.2 m the stereo stage
            takes 12-24% less wall time (the depth window sends every feature through the coarse
            search there) and the frame 0-3% less, paired on the same frames; nothing at 2.5 m
            and beyond; the development scenes' errors within their scatter
            (summed over seeds 0-2, 2% lower; ``docs/stereo-evaluation.md``, *Per-feature
            disparity windows by default*).
        predicted_disparity_after: with ``predicted_disparity``, the frames tracked in a row (since
            the first or since a lost frame) before the windows narrow; until then every feature
            is searched over the map's depth window and the margin is measured all the same.
            The first frames' predictions have no velocity yet and their margin no measure:
            started from the identity at 1.2 m (``jaxpose stereo-track --range-m 1.2 --frames
            20 --init identity``) the RMS error is 30.3 mm and 1.77 degree on the worst axes
            with 0, 18.1 mm and 1.06 degree with 1, 6.7 mm and 0.40 degree with 2 and 3, as
            with the windows off (6.7 mm, 0.39 degree).
        disparity_margin_px: the margin of the first frame whose windows narrow.
        neighbour_px: radius of the matched points that predict an unmatched feature's
            disparity.
        threads: run the line detection (LSD + LBD) in a second thread beside the points', and
            the lines' stereo search with a share of the points' in a second thread beside the
            other points' (:func:`~jaxpose.vision.stereo_match.match_stereo`; the same results;
            on two cores the wall times overlap).
        window_frames: jointly adjust the poses of the last ``window_frames`` tracked frames
            and the point landmarks they observed, every ``k``-th frame (``window_every``)
            (:mod:`~jaxpose.pipelines.stereo.window`; each landmark keeps its rays from older
            frames as a prior, the first frame's pose is fixed while it is in the window); an
            adjusted frame's result is its adjusted pose. ``0``: off. 8 chosen on the
            development scenes ``d2`` and ``d6`` against 6 and 12.
        window_frames_far, window_far_m: the window holds ``window_frames_far`` frames instead
            (``window_frames`` if that is more) while the target is far: from a frame whose
            inlier point landmarks lie at a median depth of ``window_far_m`` or more (metres,
            in the left camera; measured from the map, so the same whether the first pose was
            given or the identity) until one whose median depth falls below ``window_far_m /``
            :data:`~jaxpose.pipelines.stereo.frames.WINDOW_FAR_BAND`. At range the rotation
            across the line of sight is weakly determined and its offset is made in the early
            frames (``docs/stereo.md``, *What still fails*); a longer window keeps them free
            longer. Up close it costs accuracy (development scenes at 1.5-3 m, seeds 0-2: worst
            axes summed 16% higher with 12 frames throughout). ``window_far_m=None``: always
            ``window_frames``. 12 frames from 3.3 m (the visible faces of the suite's target
            at a range of about 3.5 m) chosen on development scenes and draws
            (``docs/stereo-evaluation.md``, *A longer window at range*); it costs about 7% of
            the frame's time at 4 m.
        window_iterations: Gauss-Newton iterations of each adjustment.
        window_every, window_depth_m: run the windowed adjustment every ``k``-th tracked frame
            only, ``k = floor(window_depth_m / depth)`` within ``[1, window_every]`` (``depth``:
            the ``t_z`` of the frame's pose of the map, whose origin lies within the target
            whatever the start, :func:`~jaxpose.pipelines.stereo.landmarks.map_origin`;
            ``window_depth_m=None``: ``k = window_every``). The frames in between keep their
            single-frame poses (the next adjustment moves them in the window). Near the target
            the single-frame poses are already good and the adjustment costs the most; at range
            it is cheap and needed.
            Chosen on the development scenes (``docs/stereo-evaluation.md``): ``k = 1`` beyond
            3 m, 2 at 2-3 m, 3 at 1.5-2 m, 4 at 1.5 m and nearer.
        window_points: most point landmarks in each adjustment (those observed most often in
            the window).
        window_motion_sigma: ``(deg, mm)``: the windowed adjustment holds the target's motion
            to a constant twist (a rigid body spinning about a fixed axis at a constant rate,
            seen from a camera at rest), the second difference of consecutive frames' relative
            motions with these standard deviations against 1 px of the pixel residuals
            (:func:`jaxpose.core.refine.motion_residual`); ``None``: no motion prior. On by
            default since 2026-11-25 at the values first measured (0.3 degree, 5 mm), chosen
            on the development scenes (seeds 0-1) and a development draw of fast turns at
            range, where the rotation about an axis across the line of sight and the lateral
            translation are told apart by little else (``docs/stereo-evaluation.md``). It
            assumes evenly spaced frames.
        window_gauge: what holds the windowed adjustment's gauge once the given first frame
            has left the window (:data:`WINDOW_GAUGES`): ``"rays"`` (the default since
            2026-12-02) the rays of the frames that left it, which each landmark keeps as a
            prior, the oldest frame free (held only where fewer than ten of the window's
            landmarks have such rays that meet); ``"oldest"`` the oldest frame's pose, held
            where it is (the default before). Chosen on development scenes and draws: the
            suite's six over noise seeds 0-2 within 0.4% (18 of 18 runs meet either way); the
            28 development-draw scenes at 3.3-5 m over seeds 0-1 meet the targets on 50 of 56
            runs against 45 (five gained, none lost), their worst axes 3% higher in the
            geometric mean; evaluation draws 2104-2111, run both ways after the choice, about
            neutral, 91 of 96 against 90 (``docs/stereo-evaluation.md``, *The window's
            gauge*).
        window_free_lines: the windowed adjustment adjusts the line landmarks with the poses
            (their endpoints free, observed by the stereo planes of the window's frames, the
            planes of older frames as a prior; the adjusted planes re-solve the lines); off,
            the lines' endpoints are held where they were placed.
        window_held_lines: with ``window_free_lines``, also hold the lines the adjustment does
            not free (matched in the window's left images but with no observation plane there,
            or whose planes do not meet) where the map has them, in the pose blocks (the
            default until 2026-12-02); off, they are left out of the adjustment (their frames'
            own pose solves still fit them). A held line is taken as exact: on the tumbling
            ``d5`` (seed 1) one line placed askew by its only stereo pair moved the window's
            last pose by 5 mm. Off, the development scenes' worst axes summed over seeds 0-5
            are 0.966 of on (``d5`` 0.65, the others 0.96-1.02), and 29 of 36 runs beyond 3.5 m
            of the development draws meet the targets against 28 (``docs/stereo-evaluation.md``,
            *Lines held in the window*).
        window_anchors, window_anchor_every, window_anchor_points: the first adjustment at
            least ``window_anchor_every`` tracked frames after the last global one is a global
            one: the recent window together with up to ``window_anchors`` past frames spread
            over the whole run (the given first frame among them; the ``anchors`` of
            :class:`~jaxpose.pipelines.stereo.window.WindowAdjuster`), at most
            ``window_anchor_points`` landmarks, so
            the first frames' poses and the landmarks placed at them keep being re-estimated
            with the later frames' rays. ``window_anchors=0``: off (measured on the development
            scenes, ``docs/stereo-evaluation.md``: no gain at 4-5 m at the defaults of
            2026-12-01, one 5 m run of three over its target).
        keep_history: keep every tracked frame's observations (its point rays and line planes)
            so that :func:`jaxpose.pipelines.stereo.smooth_sequence` can adjust the whole
            sequence after the last frame (offline smoothing); memory grows with the sequence
            (a few hundred kB a frame). Needs the windowed adjustment (``window_frames > 0``).
        feature_budget, budget_rule: solve the pose on at most ``feature_budget`` of the matched
            points and lines (``None``: all), chosen by ``budget_rule``: ``"dop"`` (lowest
            dilution of precision at the predicted pose), ``"random"`` or ``"response"``
            (strongest ORB responses, longest segments); see
            :mod:`jaxpose.pipelines.stereo.budget`.
        budget_noise: the ``"dop"`` rule's noise of a feature: ``"pixel"`` (``sigma_px``),
            ``"landmark"`` (plus its landmark's position covariance projected into both images),
            ``"measured"`` (the running RMS of its landmark's post-fit residual) or ``"both"``.
        budget_subsample: the ``"dop"`` rule's greedy runs on this random share of the
            candidates (a new draw each frame; at least ``2 N``).
        budget_weight: the ``"dop"`` rule's criterion: ``"chaser"``, the variance of the
            chaser's position plus the lever arm squared times the attitude variance;
            ``"relative"``, the sum over the six axes of the tracker's error metric (the
            chaser's position in the target frame, the attitude about the camera's axes) of
            each axis's variance over its variance with every candidate (so that no axis loses
            much more of its precision than the others).
        budget_repeat_discount: with ``budget_window``, the ``"dop"`` rule counts a landmark it
            chose in ``k`` of its last ``window_frames - 1`` selections with its information
            divided by ``(1 + k) ** budget_repeat_discount``: the observations of one landmark
            across the window share its position error
            (:mod:`jaxpose.pipelines.stereo.repeats`). 0: every frame's features taken as
            independent.
        budget_window: with a ``feature_budget``, the windowed adjustment is the budgeted
            pose's estimator: the frame's observations that it and the landmarks' ray priors
            take in are the budget's features, and it runs on every tracked frame (whatever
            ``window_every`` and ``window_depth_m``), so each reported pose is fitted to the
            last ``window_frames`` frames' ``N`` features each. Off: every matched feature
            within ``reject_px`` of the budgeted pose, at the depth's cadence, so the budget
            bounds the frame's own solve only (and at depths where the window runs every frame,
            not the reported pose). On: measured on the development scenes
            (``docs/stereo-evaluation.md``, *The window's cadence under a budget*).
        anchor_points: observe each matched point landmark at the pixel where its patch from
            the frame that created it, warped by the predicted pose, aligns best near the
            detected keypoint (:mod:`jaxpose.pipelines.stereo.anchor`; SVO's feature
            alignment), instead of at the keypoint ORB finds anew, so that every frame observes
            the same physical point. ``anchor_turn_deg``: a landmark's patch is taken anew
            (at its aligned pixel) once the view has turned this far from its reference
            (``None``: never). ``anchor_half_px``: the aligned template is ``2 half + 1``
            pixels square. ``anchor_cornerness``: the least ratio of the aligned window's
            gradient eigenvalues (0: any; along an edge the shift is not fixed). On since
            2026-11-30, chosen on development scenes only: the suite's six over noise seeds
            0-2 within 1% of off (summed over axes; 18 of 18 runs meet either way) and two
            development draws of twelve (draw seeds 9 and 10) 17% and 21% lower, 23 of 24
            meeting the targets against 21 (``docs/stereo-evaluation.md``, *Anchored
            observations by default*).
            Its time (about 13 ms of CPU a frame at 1.5 m) is in the ``match`` stage.
            ``anchor_normals``: the plane through each landmark that warps its patch:
            ``"facing"`` (the default) the plane facing the reference camera; ``"map"`` the
            plane of the 40 nearest landmarks where they lie flat
            (:func:`~jaxpose.pipelines.stereo.landmarks.surface_normals`); ``"stereo"`` the
            plane that the slant of the stereo disparity about the keypoint fixes in the frame
            that creates the landmark (:func:`~jaxpose.vision.stereo_slant.slanted_disparity`,
            a median 4-9 degrees from the true faces where the facing plane is 25-73 off).
            With the true face normals (an oracle) a fast turn at 3.7 m falls from 60 to 16 mm
            of lateral drift, but the oracle raises the development scenes' worst axes by 31%
            (seeds 0-1), ``"stereo"`` by 21% and ``"map"`` by 30%
            (``docs/stereo-evaluation.md``, *Surface normals from the stereo slant*).
            ``anchor_follow_px``: the point landmarks of the last frame's pose solve that ORB
            does not match in this one are followed by their patch alone (SVO's tracking
            without a detection): aligned from their predicted pixel after an integer ZNCC
            search of this many pixels each way, and kept where the alignment holds
            (:mod:`~jaxpose.pipelines.stereo.follow`); 0: off, the default. At 3 on the 56
            development-draw runs at 3.3-5 m the worst axis is 22% lower in the geometric mean
            but 49 meet the targets against 50, the suite's development scenes are 8% higher,
            and a frame costs about 30% more CPU at range (``docs/stereo-evaluation.md``,
            *Landmarks followed by their patch*).
            ``anchor_affine_prior``: a weight ``lambda >= 0``: the alignment also corrects the
            predicted warp by a 2 x 2 map, held to the prediction by a prior of ``lambda``
            times the data's own weight of the correction
            (:class:`~jaxpose.pipelines.stereo.anchor.PatchAnchors`); ``None``: the
            translation only (SVO's alignment, the default before 2026-12-03). On a face
            turned 45 degrees from the reference view the facing plane's warp leaves the
            translation 0.23 px off the landmark; the correction leaves 0.01 px free, 0.05 at
            0.25 and 0.12 at 1. 0.5 by default since 2026-12-03, chosen on development scenes
            and draws only: 0.25, 0.5 and 1 on the suite's six scenes over noise seeds 0-2 and
            the 20 scenes at 3.3-5 m of development draws 7, 9 and 10 over seeds 0-1; at 0.5,
            18 of 18 development runs meet as without it (the worst axes 4% higher in the
            geometric mean) and 35 of the 40 far runs against 32 (``docs/stereo-evaluation.md``,
            *The warp corrected by the alignment*).
        measured_point_sigma: weight each point of the all-features solve by its landmark's
            running post-fit residual RMS instead of ``sigma_px``.
        landmark_point_sigma: weight each point of the all-features solve by its landmark's
            triangulation covariance, per image: the left and right residuals' noise
            ``sqrt(sigma_px^2 + trace(J C_X J^T) / 2)`` with that image's projection Jacobian
            (:func:`~jaxpose.pipelines.stereo.budget.point_sigma_images`). A landmark placed by
            one stereo pair carries its depth error, ``z^2 sqrt(2) sigma / (f b)``, into its
            right-image residual at every later frame; weighted, the directions fix the pose
            and the depths count as much as they are known. Off: on the development scenes
            (noise seeds 0-2) it lowered the 5 m scene's worst axis by up to 20% and raised the
            2.5 m tumbling scene's on every seed (``docs/stereo-evaluation.md``).
        stereo: options of the epipolar search (:class:`~jaxpose.vision.stereo_match.
            StereoMatchOptions`); ranges of 128 disparities or more (a target within about 2 m
            on the 0.3 m, 1024-pixel rig) are searched coarse to fine, which takes 40-55% of the
            full search's CPU time there and returns the same match for 98% of the points
            (``d3``, ``c5``); on narrower ranges it costs more than it saves. Keypoints
            within 0.01 px of each other (``merge_px``: ORB's one corner at several pyramid
            levels, which the sub-pixel refinement moves to one point; about 40% of them up
            close with ``cornerSubPix``, the refinement until 2026-12-01) are
            searched once: the stereo stage's CPU 20-35% lower at 1.5-2 m, the development
            scenes' errors within 2% over noise seeds 0-2.
    """

    use_lines: bool = True
    depth_range_m: tuple[float, float] = (0.6, 8.0)
    depth_margin_m: float | None = 0.8
    robust: str | None = "huber"
    sigma_px: float = 1.0
    line_sigma_px: float = 1.0
    max_points: int = 2048
    max_lines: int = 96
    min_features: int = 12
    max_rms_px: float = 4.0
    max_jump_deg: float = 10.0
    max_jump_m: float = 0.25
    search_radius_px: float = 12.0
    adaptive_radius: bool = True
    line_angle_deg: float = 10.0
    keyframe_every: int = 1
    keyframe_min: int = 50
    inlier_px: float = 2.0
    passes: int = 3
    reject_px: float = 1.5
    max_view_deg: float = 60.0
    max_obs: int = 10
    cull_after: int = 8
    cull_ratio: float = 0.25
    descriptor_memory: int = 1
    keep_obs: int = 3
    refine_disparity_px: float = 1.0
    duplicate_px: float = 2.0
    frame_rays: bool = True
    stereo_residuals: bool = True
    features: FeatureOptions = field(
        default_factory=lambda: FeatureOptions(n_points=2000, orb_levels=3, subpixel="peak")
    )
    keypoint_spacing_px: float | None = 8.0
    keypoint_floor: int = 1000
    lsd_area_px: float | None = 120_000.0
    fine_corners_area_px: float | None = None
    line_planes: bool = True
    frame_planes: bool = False
    line_stereo_residuals: bool = True
    row_lines: bool = False
    measured_line_sigma: bool = True
    line_scale_memory: float = 0.9
    mature_obs: int = 3
    predicted_disparity: bool = True
    predicted_disparity_after: int = 3
    disparity_margin_px: float = 6.0
    neighbour_px: float = 40.0
    threads: bool = True
    stereo: StereoMatchOptions = field(
        default_factory=lambda: StereoMatchOptions(coarse_min_range=128, merge_px=0.01)
    )
    window_frames: int = 8
    window_frames_far: int = 12
    window_far_m: float | None = 3.3
    window_iterations: int = 2
    window_every: int = 4
    window_depth_m: float | None = 6.0
    window_points: int = 300
    window_motion_sigma: tuple[float, float] | None = (0.3, 5.0)
    window_free_lines: bool = True
    window_held_lines: bool = False
    window_gauge: str = "rays"
    window_anchors: int = 0
    window_anchor_every: int = 8
    window_anchor_points: int = 1000
    keep_history: bool = False
    # feature budget (jaxpose.pipelines.stereo.budget)
    feature_budget: int | None = None
    budget_rule: str = "dop"
    budget_noise: str = "pixel"
    budget_subsample: float = 1.0
    budget_window: bool = True
    budget_weight: str = "chaser"
    budget_repeat_discount: float = 2.0
    anchor_points: bool = True
    anchor_turn_deg: float | None = 10.0
    anchor_normals: str = "facing"
    anchor_half_px: int = 3
    anchor_cornerness: float = 0.1
    anchor_follow_px: int = 0
    anchor_affine_prior: float | None = 0.5
    measured_point_sigma: bool = False
    landmark_point_sigma: bool = False

    def __post_init__(self):
        for name in ("depth_range_m", "window_motion_sigma"):  # a NumPy pair as a tuple
            object.__setattr__(self, name, _as_pair(getattr(self, name)))
        check_fields(self, **_FIELD_KINDS)
        for name, kind in (("features", FeatureOptions), ("stereo", StereoMatchOptions)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"TrackerOptions.{name} must be a {kind.__name__}; got {getattr(self, name)!r}"
                )
        if self.robust not in ROBUST_KINDS:
            raise ValueError(
                f"TrackerOptions.robust must be one of {ROBUST_KINDS}; got {self.robust!r}"
            )
        lo_hi = self.depth_range_m
        if not (
            isinstance(lo_hi, tuple | list)
            and len(lo_hi) == 2
            and all(is_finite_number(v) and v > 0 for v in lo_hi)
            and lo_hi[0] < lo_hi[1]
        ):
            raise ValueError(
                "TrackerOptions.depth_range_m must be two finite depths 0 < near < far (metres); "
                f"got {lo_hi!r}"
            )
        if self.anchor_normals not in ANCHOR_NORMALS:
            raise ValueError(
                f"anchor_normals must be one of {ANCHOR_NORMALS}; got {self.anchor_normals!r}"
            )
        if self.window_gauge not in WINDOW_GAUGES:
            raise ValueError(
                f"window_gauge must be one of {WINDOW_GAUGES}; got {self.window_gauge!r}"
            )
        if self.budget_rule not in BUDGET_RULES:
            raise ValueError(f"budget_rule must be one of {BUDGET_RULES}; got {self.budget_rule!r}")
        if self.budget_noise not in BUDGET_NOISE:
            raise ValueError(
                f"budget_noise must be one of {BUDGET_NOISE}; got {self.budget_noise!r}"
            )
        if self.budget_weight not in BUDGET_WEIGHTS:
            raise ValueError(
                f"budget_weight must be one of {BUDGET_WEIGHTS}; got {self.budget_weight!r}"
            )
        if not self.budget_subsample <= 1.0:
            raise ValueError(f"budget_subsample must be in (0, 1]; got {self.budget_subsample}")
        if self.measured_point_sigma and self.landmark_point_sigma:
            raise ValueError(
                "measured_point_sigma and landmark_point_sigma are two weightings of the same "
                "point residuals: set one of them"
            )
        if self.window_frames == 1:  # a window of one frame adjusts nothing
            raise ValueError("TrackerOptions.window_frames must be 0 (off) or at least 2; got 1")
        if self.keep_history and not self.window_frames:
            raise ValueError(
                "keep_history needs the windowed adjustment (window_frames > 0): its ray records "
                "are the history"
            )
        ms = self.window_motion_sigma
        if ms is not None and not (
            isinstance(ms, tuple | list)
            and len(ms) == 2
            and all(is_finite_number(v) and v > 0 for v in ms)
        ):
            raise ValueError(
                f"window_motion_sigma must be None or two finite numbers > 0 (deg, mm); got {ms!r}"
            )
        if self.window_frames and self.window_every > self.window_frames:
            raise ValueError(
                f"window_every must be at most window_frames ({self.window_frames}); "
                f"got {self.window_every}"
            )
        if not self.line_scale_memory < 1.0:
            raise ValueError(f"line_scale_memory must be in [0, 1); got {self.line_scale_memory}")


def lost_pose() -> Pose:
    """The pose of a lost frame: NaN rotation and translation."""
    return Pose(np.full((3, 3), np.nan), np.full(3, np.nan))


@dataclass
class FrameResult:
    """Tracking output of one frame.

    Attributes:
        index: frame number (0 for the first pair).
        pose: :class:`~jaxpose.core.geometry.Pose` of the target in the left camera
            (``x_cam = R x_body + t``; NaN when lost).
        status: :class:`~jaxpose.core.status.Status` (``OK`` or ``LOST``).
        n_points, n_lines: features given to the solver.
        inliers: post-fit inliers; ``rms_px``: their post-fit RMS (pixels).
        keyframe: this frame updated the landmark map.
        timings: wall-clock seconds by stage (:data:`STAGES`); tracked by
            :func:`~jaxpose.pipelines.stereo.track_stream` with ``prefetch``, ``features`` is
            the wait for the features extracted ahead and ``features_ahead`` their extraction
            in the worker.
        cpu_timings: CPU seconds of the process by stage (all its threads; steadier than wall
            time on a shared machine); the feature budget's selection is timed in wall time
            only, its CPU time counts in ``pose``.
    """

    index: int
    pose: Pose
    status: int
    n_points: int = 0
    n_lines: int = 0
    inliers: int = 0
    rms_px: float = float("nan")
    keyframe: bool = False
    timings: dict = field(default_factory=dict)
    cpu_timings: dict = field(default_factory=dict)

    @property
    def R(self) -> np.ndarray:
        """``(3, 3)`` rotation of :attr:`pose` as a NumPy array."""
        return np.asarray(self.pose.R, float)

    @property
    def t(self) -> np.ndarray:
        """``(3,)`` translation of :attr:`pose` as a NumPy array, metres."""
        return np.asarray(self.pose.t, float)
