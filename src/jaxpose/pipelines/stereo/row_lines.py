"""Segments along the image rows: their depth from the stereo points beside them.

On a rectified rig a segment along the rows has no stereo match of its own: its left and right
images lie on the same rows, so the ZNCC search along a row (Yang et al. 2024, eqs. 4-5) cannot
tell where on the segment a sample falls, and the two observation planes through the camera
centres coincide (the baseline lies in both). :func:`~jaxpose.vision.stereo_match.match_stereo`
skips such segments (``min_epipolar_angle_deg``). Yet they are what measures the target's motion
across the rows: a segment constrains the image motion along its normal only, so the steep
segments that do get a stereo match measure the motion along the rows (the rotation about the
camera's vertical, the lateral shift) and say nothing of the rotation about the camera's
horizontal axis or of the motion along the columns.

Such a segment still lies on the target, among keypoints whose disparity *is* measured. On a
rectified rig the disparity of the points of a plane is an affine function of their pixel,
``d = c0 + c1 u + c2 v``, so a plane fitted to the disparities of the keypoints on one side of
the segment gives the disparity of the segment where that side's surface meets it. The segment
is given a depth when the two sides agree (a crease of the box, a line on a face) or when only
one side has keypoints (an edge against the sky); where both sides have planes that disagree
(one part in front of another) it gets none.
"""

from __future__ import annotations

import numpy as np

__all__ = ["row_segment_disparities"]


def _side_planes(s, h, d, mask, length, min_points: int, trim_px: float):
    """Least-squares disparity planes ``d = c0 + c1 s + c2 h`` of the masked points of each
    segment (``(M, N)`` arrays; ``s``, ``h`` in pixels along and across the segment), refitted
    once on the points within ``trim_px`` of the first fit. Returns the coefficients ``(M, 3)``
    and whether each fit holds at least ``min_points`` points that span half the segment's
    ``length`` (``(M,)``)."""
    A = np.stack([np.ones_like(s), s, h], -1)  # (M, N, 3)
    for _ in range(2):
        w = mask.astype(float)
        G = np.einsum("mn,mni,mnj->mij", w, A, A) + 1e-9 * np.eye(3)
        r = np.einsum("mn,mni,n->mi", w, A, d)
        c = np.linalg.solve(G, r[..., None])[..., 0]
        res = np.abs(np.einsum("mni,mi->mn", A, c) - d[None])
        mask = mask & (res < trim_px)
    count = mask.sum(1)
    big = 1e9
    span = np.where(mask, s, -big).max(1) - np.where(mask, s, big).min(1)
    return c, (count >= min_points) & (span >= 0.5 * length)


def row_segment_disparities(
    segments: np.ndarray,
    pixels: np.ndarray,
    disparities: np.ndarray,
    *,
    band_px: float = 24.0,
    min_points: int = 5,
    trim_px: float = 0.5,
    agree_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Disparities of segments' endpoints from the keypoints beside them (module docstring).

    Args:
        segments: ``(M, 2, 2)`` left-image segments (pixels).
        pixels: ``(N, 2)`` left-image keypoints with a stereo match; ``disparities``: ``(N,)``
            their disparities ``u_left - u_right`` (pixels).
        band_px: keypoints within this distance of a segment (across it, and beyond its ends
            along it) are its neighbours.
        min_points: keypoints a side's plane needs, left after the trim, spanning at least half
            the segment's length.
        trim_px: the plane is refitted to the keypoints within this disparity of its first fit.
        agree_px: two sides' planes agree when their disparities at both endpoints are within
            this.

    Returns:
        ``(M, 2)`` endpoint disparities (pixels) and ``(M,)`` whether each segment got them.
    """
    segments, pixels = np.asarray(segments, float), np.asarray(pixels, float)
    d = np.asarray(disparities, float)
    if segments.ndim != 3 or segments.shape[1:] != (2, 2):
        raise ValueError(f"segments must be (M, 2, 2) pixels; got shape {segments.shape}")
    if pixels.ndim != 2 or pixels.shape[1] != 2 or d.shape != (len(pixels),):
        raise ValueError(
            f"pixels must be (N, 2) and disparities (N,); got {pixels.shape} and {d.shape}"
        )
    M = len(segments)
    out, ok = np.zeros((M, 2)), np.zeros(M, bool)
    if M == 0 or len(pixels) < min_points:
        return out, ok
    a = segments[:, 0]
    v = segments[:, 1] - a
    length = np.linalg.norm(v, axis=1)
    e = v / np.maximum(length, 1e-12)[:, None]
    n = np.stack([-e[:, 1], e[:, 0]], 1)
    rel = pixels[None] - a[:, None]  # (M, N, 2)
    s = np.einsum("mnk,mk->mn", rel, e)
    h = np.einsum("mnk,mk->mn", rel, n)
    near = (s > -band_px) & (s < length[:, None] + band_px) & (np.abs(h) <= band_px)
    ends = np.stack([np.zeros(M), length], 1)  # s of the two endpoints, h = 0
    fits = []
    for side in (h > 0, h < 0):
        c, good = _side_planes(s, h, d, near & side, length, min_points, trim_px)
        fits.append((c[:, :1] + c[:, 1:2] * ends, good))
    (dA, okA), (dB, okB) = fits
    agree = (np.abs(dA - dB) < agree_px).all(1)
    both = okA & okB & agree
    out = np.where(both[:, None], 0.5 * (dA + dB), np.where(okA[:, None], dA, dB))
    ok = both | (okA ^ okB)  # both sides agreeing, or the one side there is
    ok &= (out > 0).all(1) & (length > 0)
    return out, ok
