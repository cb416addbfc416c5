"""What a selection study may plan, checked before any work (:mod:`jaxpose.studies.selection`):
a group's subsets per case, the whole study's subsets and case data, and a scenario's feature
square in front of the camera and inside its image."""

from __future__ import annotations

import math
import warnings

import jax.numpy as jnp
import numpy as np

from jaxpose.core.geometry import Pose

__all__ = [
    "MAX_OUTSIDE_FRACTION",
    "MAX_STUDY_BYTES",
    "MAX_STUDY_SUBSETS",
    "MAX_SUBSETS_PER_CASE",
    "OutsideImageWarning",
    "check_group",
    "check_plan",
]

MAX_SUBSETS_PER_CASE = 10_000_000
"""The largest ``C(n, m)`` the study searches exhaustively per case (``C(25, 12)`` is below it,
``C(26, 13)`` above). The exhaustive kernel scores 1-2 x 10^7 subsets per CPU-second (measured at
``n = 18, m = 9`` over 250 cases and ``n = 22, m = 11`` over 8), so a case at the limit costs
about half a CPU-second and 1000 such cases some ten CPU-minutes; beyond it,
:func:`jaxpose.core.select.branch_and_bound` finds the same optimum of one problem without
visiting every subset."""

MAX_STUDY_SUBSETS = 10**11
"""The most subsets a whole study may score: ``cases`` times the sum of ``C(n, m)`` over its
groups. At the measured 1-2 x 10^7 subsets per CPU-second (:data:`MAX_SUBSETS_PER_CASE`) that is
1.5-3 CPU-hours; it is ten times the largest group the study allows at the paper's 1000 cases, and
the paper's own study (Table 4 and Tables 5-6, 1000 cases per group) plans 2.8 x 10^8."""

MAX_STUDY_BYTES = 10**9
"""The most case data a study may plan, in bytes (:func:`check_plan`): every case is kept in memory
until the statistics are taken and written to the chunk files under ``out_dir``, about
``8 (3 n + 3 m + 10)`` bytes per case and group (the points, the three index sets, six DOPs, the
status and the attitude). The paper's study plans 12.5 MB at 1000 cases per group, so the limit is
some 80 times that; a single ``n = 8, m = 5`` group reaches it at about 2.5 x 10^6 cases, some
minutes of work (small cases are drawn, solved and saved at about 8000 per second), where
``--cases 10^9`` would have run for a day and a half and written hundreds of GB."""

MAX_OUTSIDE_FRACTION = 0.05
"""The largest share of the feature square that may fall outside the ``image_size`` sensor. The
study projects every feature and counts it as observed (the sensor size sets only the principal
point; the DOP does not depend on it), so a feature outside the image is counted although the
camera cannot see it. A share above this limit is refused (:func:`run_study` raises, the command
exits 2 naming ``--image-size`` and ``--offset-m``); a smaller, nonzero one runs with an
:class:`OutsideImageWarning`. The documented scenarios of ``docs/selection.md`` reach at most 2.4 %
(5 m range, 20 degrees; 2.0 % with the body origin at a corner of the square) and run with the
warning, their numbers unchanged; the default scenario (Table 4) has none outside."""


class OutsideImageWarning(UserWarning):
    """Part of the feature square falls outside the image; those features are counted as seen."""


def _translation(scenario) -> np.ndarray:
    return np.array([scenario.offset_x_m, scenario.offset_y_m, scenario.range_m])


def _behind_camera(z_min: float) -> ValueError:
    return ValueError(
        f"the scenario puts feature points behind the camera (z = {z_min:.3g} m): increase "
        "range_m (--range-m) or decrease plane_size_m (--plane-size-m), "
        "plane_centre_m (--plane-centre-m) or attitude_deg (--attitude-deg)"
    )


def _fixed_pose(scenario) -> Pose:
    """The target's pose of a scenario with a fixed attitude (``attitude_deg``)."""
    return Pose.from_euler(
        jnp.deg2rad(jnp.asarray(scenario.attitude_deg, dtype=float)),
        jnp.asarray(_translation(scenario)),
        scenario.sequence,
    )


def _check_in_front(scenario) -> None:
    """Refuse before any work a fixed attitude that puts a corner of the feature square (the
    square's deepest and shallowest points are corners) at or behind the camera's z = 0."""
    if scenario.random_attitude:  # checked per chunk on the drawn attitudes
        return
    half = scenario.plane_size_m / 2.0
    cx, cy = scenario.plane_centre_m
    corners = np.array([[cx + a, cy + b, 0.0] for a in (-half, half) for b in (-half, half)])
    pose = _fixed_pose(scenario)
    z_min = float(np.min(np.asarray(pose.apply(jnp.asarray(corners)))[:, 2]))
    if not z_min > 0:
        raise _behind_camera(z_min)


_IMAGE_OPTIONS = (
    "--image-size, --offset-m, --range-m, --attitude-deg, --plane-size-m, --plane-centre-m, "
    "--focal-length-mm or --pixel-size-um"
)


def _outside_image(scenario, points_cam) -> int:
    """How many camera-frame points ``(..., 3)`` (in front of the camera) project outside the
    ``image_size`` sensor (pixel centres ``0 .. W - 1``: the image spans ``[-0.5, W - 0.5]``).
    Computed where the points are (a sharded chunk stays on its devices)."""
    u = scenario.camera().project(points_cam)
    w, h = scenario.image_size
    inside = (u[..., 0] >= -0.5) & (u[..., 0] <= w - 0.5)
    inside &= (u[..., 1] >= -0.5) & (u[..., 1] <= h - 0.5)
    return int(jnp.sum(~inside))


def _outside_error(scenario, share: float, what: str) -> ValueError:
    w, h = scenario.image_size
    return ValueError(
        f"features fall outside the image: {100 * share:.3g} % of {what} lie outside the "
        f"{w} x {h} sensor (--image-size), at most {100 * MAX_OUTSIDE_FRACTION:g} % may "
        "(MAX_OUTSIDE_FRACTION); the study would count them as observed. Change "
        f"{_IMAGE_OPTIONS} so that the features are in the image"
    )


def _outside_warning(scenario, share: float, what: str) -> None:
    w, h = scenario.image_size
    warnings.warn(
        f"{100 * share:.2g} % of {what} lie outside the {w} x {h} sensor (--image-size); "
        "the study counts them as observed",
        OutsideImageWarning,
        stacklevel=3,
    )


def _check_in_image(scenario) -> None:
    """Refuse before any work a fixed attitude that puts more than :data:`MAX_OUTSIDE_FRACTION`
    of the feature square outside the image, and warn when a smaller share is; the share is
    taken over a 64 x 64 grid of cell centres of the square (features are uniform in it). Random
    attitudes are checked per chunk on the drawn features."""
    if scenario.random_attitude:
        return
    k = 64
    half = scenario.plane_size_m / 2.0
    g = (np.arange(k) + 0.5) / k * 2 * half - half
    x, y = np.meshgrid(g + scenario.plane_centre_m[0], g + scenario.plane_centre_m[1])
    grid = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    pose = _fixed_pose(scenario)
    share = _outside_image(scenario, pose.apply(jnp.asarray(grid))) / len(grid)
    what = "the features (a grid over the feature square)"
    if share > MAX_OUTSIDE_FRACTION:
        raise _outside_error(scenario, share, what)
    if share > 0:
        _outside_warning(scenario, share, what)


def _case_bytes(n: int, m: int) -> int:
    """Bytes of one case of group ``(n, m)`` in memory and in a chunk file (an estimate, 8 bytes
    a number): the points, three index sets, six DOPs, the status and the attitude."""
    return 8 * (3 * n + 3 * m + 10)


def check_plan(groups: list[tuple[int, int]], cases: int) -> None:
    """Refuse (``ValueError`` naming ``--cases``) a study that plans an unreasonable amount of
    work: more than :data:`MAX_STUDY_SUBSETS` subsets scored or :data:`MAX_STUDY_BYTES` bytes of
    case data over all groups. Pure Python: the command checks it before anything starts."""
    if not (isinstance(cases, int | np.integer) and not isinstance(cases, bool) and cases >= 1):
        raise ValueError(f"cases (--cases) must be an integer >= 1; got {cases!r}")
    cases = int(cases)
    groups = list(groups)
    per_case_subsets = sum(math.comb(n, m) for n, m in groups)
    per_case_bytes = sum(_case_bytes(n, m) for n, m in groups)
    label = f"{len(groups)} group(s)"
    if cases * per_case_bytes > MAX_STUDY_BYTES:
        most = MAX_STUDY_BYTES // per_case_bytes
        raise ValueError(
            f"cases (--cases) = {cases} over {label} plans {cases * per_case_bytes:.3g} bytes of "
            f"case data (kept in memory and written to the chunk files), above the study's limit "
            f"of {MAX_STUDY_BYTES:.0e} (MAX_STUDY_BYTES); lower --cases (at most {most} with "
            "these groups) or run fewer groups (--n, --m)"
        )
    if cases * per_case_subsets > MAX_STUDY_SUBSETS:
        most = MAX_STUDY_SUBSETS // per_case_subsets
        raise ValueError(
            f"cases (--cases) = {cases} over {label} plans {cases * per_case_subsets:.3g} "
            f"exhaustive subset evaluations, above the study's limit of {MAX_STUDY_SUBSETS:.0e} "
            "(MAX_STUDY_SUBSETS, 1.5-3 CPU-hours); lower --cases (at most "
            f"{most} with these groups) or run smaller groups (--n, --m)"
        )


def check_group(n: int, m: int) -> None:
    """Refuse a group the study cannot run: ``4 <= m <= n`` and at most
    :data:`MAX_SUBSETS_PER_CASE` subsets per case."""
    if not (isinstance(n, int | np.integer) and isinstance(m, int | np.integer) and 4 <= m <= n):
        raise ValueError(f"each group needs 4 <= m <= n (--n, --m); got (n, m) = ({n}, {m})")
    count = math.comb(n, m)
    if count > MAX_SUBSETS_PER_CASE:
        raise ValueError(
            f"(n, m) = ({n}, {m}) has C({n}, {m}) = {count:.3g} subsets per case, above the "
            f"study's exhaustive limit of {MAX_SUBSETS_PER_CASE:.0e}; lower --n or move --m "
            "away from n / 2 (jaxpose.core.select.branch_and_bound finds the optimum of one "
            "large problem without visiting every subset)"
        )
