"""Which landmarks the budget's ``"dop"`` rule chose in the window's earlier frames.

With the feature budget over the windowed adjustment (``TrackerOptions.budget_window``) each
reported pose is fitted to the last ``window_frames`` frames' ``N`` features each. The DOP of one
frame takes every observation as independent, and so picks much the same high-leverage landmarks
frame after frame; but the observations of one landmark in several frames of a window share its
position error, which more frames do not average out. :class:`SelectionHistory` keeps, per
landmark map, the stable ids of the point and line landmarks the rule chose in its last ``frames``
selections, and :meth:`SelectionHistory.scale` turns them into the factor on a candidate's
information rows: a landmark chosen in ``k`` of them counts with its information divided by
``(1 + k) ** power`` (``TrackerOptions.budget_repeat_discount``), so that the window's features
spread over more landmarks where others fix the pose nearly as well.
"""

from __future__ import annotations

import weakref
from collections import Counter, deque

import numpy as np

__all__ = ["SelectionHistory", "selection_history"]


class SelectionHistory:
    """The point and line landmark ids chosen in each of the last ``frames`` selections."""

    def __init__(self, frames: int):
        if frames < 0:
            raise ValueError(f"frames must be >= 0; got {frames}")
        self.frames = int(frames)
        self._chosen: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max(self.frames, 1))

    def counts(self, point_ids, line_ids) -> tuple[np.ndarray, np.ndarray]:
        """How many of the kept selections chose each landmark: ``(n_p,)`` and ``(n_l,)``."""
        if not self.frames:
            return np.zeros(len(point_ids), int), np.zeros(len(line_ids), int)
        cp = Counter(i for p, _ in self._chosen for i in p.tolist())
        cl = Counter(i for _, q in self._chosen for i in q.tolist())
        return (
            np.array([cp.get(int(i), 0) for i in np.asarray(point_ids).tolist()], int),
            np.array([cl.get(int(i), 0) for i in np.asarray(line_ids).tolist()], int),
        )

    def scale(self, point_ids, line_ids, power: float) -> tuple[np.ndarray, np.ndarray]:
        """Factors ``(1 + k) ** (-power / 2)`` on the information rows of the candidates (their
        information divided by ``(1 + k) ** power``), ``k`` from :meth:`counts`."""
        kp, kl = self.counts(point_ids, line_ids)
        return (1.0 + kp) ** (-0.5 * power), (1.0 + kl) ** (-0.5 * power)

    def push(self, point_ids, line_ids) -> None:
        """Record one selection (the chosen landmarks' stable ids)."""
        if self.frames:
            self._chosen.append(
                (np.asarray(point_ids, np.int64).copy(), np.asarray(line_ids, np.int64).copy())
            )


_HISTORIES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def selection_history(landmarks, frames: int) -> SelectionHistory:
    """The :class:`SelectionHistory` of a landmark map (one per map, created on first use with
    ``frames`` selections kept)."""
    if landmarks not in _HISTORIES or _HISTORIES[landmarks].frames != frames:
        _HISTORIES[landmarks] = SelectionHistory(frames)
    return _HISTORIES[landmarks]
