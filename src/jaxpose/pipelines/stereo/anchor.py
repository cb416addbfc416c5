"""Point observations anchored at each landmark's first view (feature alignment).

ORB finds a corner anew in every frame, and where it settles (its pyramid level, the sub-pixel
refinement's window over several corners) moves with the view: the same landmark is observed at a
slightly different physical point as the target turns, frame after frame with one sign
(``docs/stereo-evaluation.md``, *The kept observations are biased frame by frame*). Semi-direct
odometry (SVO, Forster et al. 2014, sec. IV-B) avoids that by aligning, in each new frame, the
landmark's image patch from the frame that created it, warped by the affine map that the two
poses and the landmark's depth predict: every observation is then of the same physical point.

:class:`PatchAnchors` keeps, for each point landmark (by its stable id), a patch of the left
image of the frame that created it, the keypoint's pixel there and that frame's pose.
:meth:`PatchAnchors.align` warps the patch into the current frame (the plane through the landmark
facing the reference camera, as SVO does), and from the detected keypoint (or, with ``search_px``,
from the integer shift of best zero-normalised cross-correlation, ZNCC, around it) runs a few
Gauss-Newton steps of Lucas-Kanade on the translation with a gain and a bias. It returns the
aligned pixel where that converges near the detection, the template correlates (ZNCC) and the
window is not an edge (its gradients' aperture, the Shi-Tomasi ratio); the detected one elsewhere.
With ``affine_prior`` the steps also correct the predicted warp by a 2 x 2 linear map (the affine
alignment of Shi and Tomasi 1994, held to the prediction by a prior): where the facing plane
mispredicts a turned face's foreshortening, the translation then settles on the landmark.

Pure NumPy (application side), vectorised over the landmarks of a frame: about 13 ms of CPU a
frame at 1.5 m, two thirds of it the Lucas-Kanade steps (the 2-core machine), which take about
twice as long with the warp's correction (2.7 against 5.4 ms for 300 landmarks).
"""

from __future__ import annotations

import numpy as np

from jaxpose.core._checks import is_finite_number
from jaxpose.core.camera import PinholeCamera
from jaxpose.pipelines.stereo._arrays import find
from jaxpose.vision.stereo_match import parabolic_offset
from jaxpose.vision.stereo_slant import plane_normals, slanted_disparity

__all__ = ["PatchAnchors", "affine_to_reference", "stereo_normals"]

#: The least ZNCC of a slanted-window fit whose normal is used (:func:`stereo_normals`).
SLANT_MIN_ZNCC = 0.9


def affine_to_reference(
    camera: PinholeCamera,
    X_body: np.ndarray,
    ref_uv: np.ndarray,
    R_ref: np.ndarray,
    t_ref: np.ndarray,
    R_cur: np.ndarray,
    t_cur: np.ndarray,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """``(n, 2, 2)`` affine maps from pixel offsets in the current image to pixel offsets in the
    reference image, about each landmark's pixel.

    The landmark lies on the plane through it that faces the reference camera (depth ``z_ref``
    constant): a reference offset ``d`` is the point ``z_ref K^-1 (uv_ref + d, 1)``, carried to the
    current camera by ``R_cur R_ref^T (. - t_ref) + t_cur`` and projected; the map returned is the
    inverse of that projection's Jacobian in ``d``. With ``normals`` (``(n, 3)`` unit, body
    frame; a NaN row: the plane facing the camera) the plane through the landmark is the
    surface's: the offset's ray ``r = K^-1 (uv_ref + d, 1)`` meets it at ``r (n . X_ref) /
    (n . r)``. On a face turned from the reference view the facing plane mispredicts the
    foreshortening, and the alignment then settles off the landmark by a part of a pixel, the
    same way frame after frame as the target turns.

    Args:
        camera: pinhole camera without distortion (the rectified left camera).
        X_body: ``(n, 3)`` landmarks, body frame (metres).
        ref_uv: ``(n, 2)`` their pixels in the reference image.
        R_ref, t_ref: ``(n, 3, 3)``, ``(n, 3)`` body-to-camera poses of the reference frames.
        R_cur, t_cur: ``(3, 3)``, ``(3,)`` body-to-camera pose of the current frame.
    """
    fx, fy = float(camera.fx), float(camera.fy)
    X_ref = np.einsum("nij,nj->ni", R_ref, X_body) + t_ref  # the landmarks, reference camera
    z_ref = X_ref[:, 2]
    M = np.einsum("ij,nkj->nik", R_cur, R_ref)  # R_cur R_ref^T
    P_cur = np.einsum("ij,nj->ni", R_cur, X_body) + t_cur
    dP = M[:, :, :2] * (z_ref[:, None, None] / np.array([fx, fy])[None, None, :])  # (n, 3, 2)
    if normals is not None:
        normals = np.asarray(normals, float)
        if normals.shape != (len(X_body), 3):
            raise ValueError(f"normals must be ({len(X_body)}, 3); got shape {normals.shape}")
        E = np.zeros((3, 2))
        E[0, 0], E[1, 1] = 1.0 / fx, 1.0 / fy  # d r / d d
        n_ref = np.einsum("nij,nj->ni", R_ref, normals)
        uv = np.asarray(ref_uv, float)
        u, v = (uv[:, 0] - float(camera.cx)) / fx, (uv[:, 1] - float(camera.cy)) / fy
        r = np.stack([u, v, np.ones(len(uv))], 1)  # the reference pixel's ray
        nX, nr = np.einsum("ni,ni->n", n_ref, X_ref), np.einsum("ni,ni->n", n_ref, r)
        ok = np.isfinite(nX) & np.isfinite(nr) & (np.abs(nr) > 1e-3 * np.linalg.norm(r, axis=1))
        sc = np.where(ok, nX / np.where(ok, nr, 1.0), z_ref)  # the ray's scale to the plane
        ds = -(nX / np.where(ok, nr, 1.0) ** 2)[:, None] * (n_ref @ E)  # (n, 2)
        dP_plane = E[None] * sc[:, None, None] + r[:, :, None] * ds[:, None, :]
        dP[ok] = np.einsum("nij,njk->nik", M[ok], dP_plane[ok])
    x, y, z = P_cur[:, 0], P_cur[:, 1], P_cur[:, 2]
    J = np.empty((len(X_body), 2, 2))
    J[:, 0] = fx * (dP[:, 0] / z[:, None] - x[:, None] * dP[:, 2] / z[:, None] ** 2)
    J[:, 1] = fy * (dP[:, 1] / z[:, None] - y[:, None] * dP[:, 2] / z[:, None] ** 2)
    return np.linalg.inv(J)


def stereo_normals(
    left: np.ndarray,
    right: np.ndarray,
    camera: PinholeCamera,
    pixels: np.ndarray,
    disparity: np.ndarray,
    R: np.ndarray,
) -> np.ndarray:
    """Surface normals ``(n, 3)`` (body frame) at the features ``pixels (n, 2)`` of the rectified
    pair ``left, right`` (disparities ``(n,)``, the pose's rotation ``R``, body to left camera)
    from the slant of the disparity across a window about each
    (:func:`~jaxpose.vision.stereo_slant.slanted_disparity`): NaN rows where the fit fails or
    its ZNCC is below ``SLANT_MIN_ZNCC``. ``camera``: the rectified left camera."""
    fit = slanted_disparity(left, right, pixels, disparity)
    n_cam = plane_normals(camera, pixels, fit.disparity, fit.slope)
    good = fit.ok & (fit.zncc >= SLANT_MIN_ZNCC)
    return np.where(good[:, None], n_cam @ np.asarray(R, float), np.nan)


def _bilinear(images: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``images (n, h, w)`` at ``(x, y)`` of shape ``(n, k)`` (inside the images)."""
    n, h, w = images.shape
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    ax, ay = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    flat = images.reshape(-1)
    i = np.arange(n)[:, None] * (h * w) + y0 * w + x0
    f00, f01, f10, f11 = flat[i], flat[i + 1], flat[i + w], flat[i + w + 1]
    return (f00 * (1 - ax) + f01 * ax) * (1 - ay) + (f10 * (1 - ax) + f11 * ax) * ay


def _standardise(v: np.ndarray) -> np.ndarray:
    v = v - v.mean(axis=-1, keepdims=True)
    s = np.sqrt((v**2).sum(axis=-1, keepdims=True))
    return v / np.where(s > 1e-9, s, np.inf)


class PatchAnchors:
    """Reference patches of point landmarks, by stable landmark id (module docstring).

    Args:
        half: half-size of the aligned template (``2 half + 1`` pixels square).
        search_px: integer shifts searched around the detected keypoint (each axis) before the
            Lucas-Kanade steps (0: start at the detection; the aligned pixel stays within
            ``search_px + 1.5`` of it).
        min_zncc: the aligned pixel is used only where its ZNCC with the template reaches this.
        max_scale: warps that stretch or shrink by more than this factor (the view has turned too
            far from the reference) are not aligned.
        background: a patch whose central window (the template and its reach) holds a grey
            level at or below this is not kept (it lies over the sky, which does not move with
            the body); ``None``: keep every patch.
        min_cornerness: the smaller over the larger eigenvalue of the aligned window's gradient
            moments must reach this (0: any; along an edge the shift is not fixed).
        lk_iterations: Gauss-Newton steps of the alignment (the last below 0.1 px to count).
        affine_prior: ``None`` (the default here; the tracker passes
            ``TrackerOptions.anchor_affine_prior``, 0.5): the steps align the translation only.
            A weight ``lambda >= 0``: they also correct the predicted warp by a 2 x 2 map ``D``
            (offsets ``d`` sampled at ``(I + D) d``), with the prior ``lambda ||J_D D||^2``
            (the data's own weight of the correction, ``J_D`` its columns; 0: free, 1: half of
            what the data alone would give where the correction is uncorrelated with the rest);
            :func:`_lucas_kanade_affine`.
    """

    def __init__(
        self,
        *,
        half: int = 5,
        search_px: int = 0,
        min_zncc: float = 0.8,
        max_scale: float = 1.6,
        background: float | None = 10.0,
        min_cornerness: float = 0.0,
        lk_iterations: int = 4,
        affine_prior: float | None = None,
    ):
        if affine_prior is not None and not (is_finite_number(affine_prior) and affine_prior >= 0):
            raise ValueError(
                f"affine_prior must be None or a finite number >= 0; got {affine_prior!r}"
            )
        self.affine_prior = None if affine_prior is None else float(affine_prior)
        self.half, self.search = int(half), int(search_px)
        self.min_zncc, self.max_scale = float(min_zncc), float(max_scale)
        self.lk_iterations = int(lk_iterations)
        self.background = background
        self.min_cornerness = min_cornerness
        self.margin = int(np.ceil(self.half * self.max_scale * np.sqrt(2))) + 2
        p = 2 * self.margin + 1
        self.ids = np.zeros(0, np.int64)
        self.patches = np.zeros((0, p, p), np.float32)
        self.uv = np.zeros((0, 2))
        self.R = np.zeros((0, 3, 3))
        self.t = np.zeros((0, 3))
        self.normals = np.zeros((0, 3))  # body frame; NaN: the plane facing the reference

    def __len__(self) -> int:
        return len(self.ids)

    def _cut(self, image: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The patches around ``uv (n, 2)`` that can be kept (inside the image, not over the
        sky) and which those are ``(n,)``."""
        h, w = image.shape[:2]
        m = self.margin
        c = np.round(uv).astype(int)
        ok = (c[:, 0] >= m) & (c[:, 0] < w - m) & (c[:, 1] >= m) & (c[:, 1] < h - m)
        c = c[ok]
        r = np.arange(-m, m + 1)
        patches = image[c[:, 1, None, None] + r[None, :, None], c[:, 0, None, None] + r[None, None]]
        if self.background is not None and len(c):  # the sky does not move with the body
            q = self.half + self.search + 1
            core = patches[:, m - q : m + q + 1, m - q : m + q + 1]
            fg = core.reshape(len(core), -1).min(axis=1) > self.background
            patches = patches[fg]
            ok[np.nonzero(ok)[0][~fg]] = False
        return patches, ok

    def capture(
        self, image: np.ndarray, ids, uv, R: np.ndarray, t: np.ndarray, normals=None
    ) -> None:
        """Store the patches around ``uv (n, 2)`` of the landmarks ``ids`` (new, increasing)
        created in ``image`` at the pose ``R, t``; landmarks too near the border or over the
        sky get none. ``normals``: the surface normals at the landmarks ``(n, 3)`` (body
        frame; a NaN row or ``None``: the plane facing the reference camera), kept for the
        warp of :meth:`align`."""
        ids, uv = np.asarray(ids, np.int64), np.asarray(uv, float).reshape(-1, 2)
        if normals is None:
            normals = np.full((len(ids), 3), np.nan)
        normals = np.asarray(normals, float)
        if normals.shape != (len(ids), 3):
            raise ValueError(f"normals must be ({len(ids)}, 3); got shape {normals.shape}")
        patches, ok = self._cut(image, uv)
        ids, uv, normals = ids[ok], uv[ok], normals[ok]
        if not len(ids):
            return
        if not len(self.ids):  # 8-bit images keep 8-bit patches (a quarter of the memory)
            self.patches = self.patches.astype(np.uint8 if image.dtype == np.uint8 else np.float32)
        self.ids = np.concatenate([self.ids, ids])
        self.patches = np.concatenate([self.patches, patches.astype(self.patches.dtype)])
        self.uv = np.concatenate([self.uv, uv])
        self.R = np.concatenate([self.R, np.broadcast_to(R, (len(ids), 3, 3))])
        self.t = np.concatenate([self.t, np.broadcast_to(t, (len(ids), 3))])
        self.normals = np.concatenate([self.normals, normals])

    def reanchor(self, image, ids, uv, X_body, R: np.ndarray, t: np.ndarray, min_deg: float):
        """Take the patches of the landmarks ``ids`` anew from ``image`` (pose ``R, t``) at their
        aligned pixels ``uv`` where the view has turned more than ``min_deg`` from their
        reference's (the plane warp's error grows with the turn); returns how many."""
        ids, uv = np.asarray(ids, np.int64), np.asarray(uv, float).reshape(-1, 2)
        pos, has = self._lookup(ids)
        if not has.any():
            return 0
        X = np.asarray(X_body, float)[has]
        p = pos[has]
        c_ref = -np.einsum("nji,nj->ni", self.R[p], self.t[p])  # reference camera, body frame
        c_cur = -R.T @ t
        v_ref = c_ref - X
        v_cur = c_cur[None] - X
        cos = np.einsum("ni,ni->n", v_ref, v_cur) / (
            np.linalg.norm(v_ref, axis=1) * np.linalg.norm(v_cur, axis=1)
        )
        turn = cos < np.cos(np.radians(min_deg))
        if not turn.any():
            return 0
        sel = np.nonzero(has)[0][turn]
        patches, ok = self._cut(image, uv[sel])
        sel, p = sel[ok], p[turn][ok]
        self.patches[p] = patches
        self.uv[p] = uv[sel]
        self.R[p], self.t[p] = R, t
        return len(p)

    def keep(self, ids_alive: np.ndarray) -> None:
        """Forget the patches of landmarks no longer in the map."""
        keep = np.isin(self.ids, ids_alive)
        if not keep.all():
            for name in ("ids", "patches", "uv", "R", "t", "normals"):
                setattr(self, name, getattr(self, name)[keep])

    def align(
        self,
        image: np.ndarray,
        camera: PinholeCamera,
        ids: np.ndarray,
        X_body: np.ndarray,
        pixels: np.ndarray,
        R_cur: np.ndarray,
        t_cur: np.ndarray,
        normals: np.ndarray | None = None,
        *,
        search: int | None = None,
        min_zncc: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Aligned pixels of the landmarks ``ids`` (body points ``X_body (n, 3)``) detected at
        ``pixels (n, 2)`` in ``image``, the current frame at the pose ``R_cur, t_cur``;
        ``normals``: their surface normals ``(n, 3)`` for the warp (:func:`affine_to_reference`;
        ``None``: those kept by :meth:`capture`); ``search``, ``min_zncc``: for this call, the
        integer shifts searched and the least ZNCC (``None``: ``search_px``, ``min_zncc``).

        Returns ``(pixels (n, 2), aligned (n,) bool)``: the aligned pixel where the alignment
        holds (a patch, a warp within ``max_scale``, Lucas-Kanade converged within
        ``search_px + 1.5`` px of the detection, ZNCC at least ``min_zncc``, cornerness at least
        ``min_cornerness``), the detected pixel elsewhere."""
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        ids = np.asarray(ids, np.int64)
        A = np.full((len(ids), 2, 2), np.nan)
        pos, has = self._lookup(ids)
        if has.any():
            p = pos[has]
            A[has] = affine_to_reference(
                camera,
                np.asarray(X_body, float)[has],
                self.uv[p],
                self.R[p],
                self.t[p],
                R_cur,
                t_cur,
                _any_finite(self.normals[p])
                if normals is None
                else np.asarray(normals, float)[has],
            )
        return self.match(image, ids, A, pixels, search=search, min_zncc=min_zncc)

    def _lookup(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each of ``ids``, its row here (0 where absent) and whether it has one."""
        pos, has = np.zeros(len(ids), int), np.zeros(len(ids), bool)
        if len(self.ids):
            q, rows = find(self.ids, ids, increasing=True)  # (the ids are kept increasing)
            pos[q], has[q] = rows, True
        return pos, has

    def match(
        self,
        image: np.ndarray,
        ids: np.ndarray,
        A: np.ndarray,
        pixels: np.ndarray,
        *,
        search: int | None = None,
        min_zncc: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`align` with the warps given: ``A (n, 2, 2)`` maps pixel offsets in ``image``
        to offsets in each landmark's reference patch (NaN: no warp)."""
        search = self.search if search is None else int(search)
        min_zncc = self.min_zncc if min_zncc is None else float(min_zncc)
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        out, aligned = pixels.copy(), np.zeros(len(pixels), bool)
        pos, has = self._lookup(np.asarray(ids, np.int64))
        h, w = image.shape[:2]
        reach = self.half + search + 1
        c = np.round(pixels).astype(int)
        has &= (c[:, 0] >= reach) & (c[:, 0] < w - reach)
        has &= (c[:, 1] >= reach) & (c[:, 1] < h - reach)
        has &= np.isfinite(A).all(axis=(1, 2))
        sel = np.nonzero(has)[0]
        if not len(sel):
            return out, aligned
        p, A = pos[sel], A[sel]
        sv = np.linalg.svd(A, compute_uv=False)
        good = (sv[:, 0] <= self.max_scale) & (sv[:, 1] >= 1.0 / self.max_scale)
        sel, p, A = sel[good], p[good], A[good]
        if not len(sel):
            return out, aligned
        # the template: the reference patch warped into the current image's geometry
        g = np.arange(-self.half, self.half + 1)
        dx, dy = np.meshgrid(g, g)  # (k, k): x along columns
        d = np.stack([dx.ravel(), dy.ravel()], axis=0).astype(float)  # (2, k*k)
        m = self.margin
        frac = self.uv[p] - np.round(self.uv[p])  # the keypoint within its patch's centre pixel
        ref = np.einsum("nij,jk->nik", A, d) + (frac + m)[:, :, None]
        T = _standardise(
            _bilinear(self.patches[p].astype(np.float32), ref[:, 0], ref[:, 1])
        )  # (n, k*k)
        cc = c[sel]
        if search:  # the integer shift of best ZNCC around the detected keypoint first
            start = _integer_search(image, T, d, search, cc)
        else:
            start = pixels[sel]
        if self.affine_prior is None:
            new, conv, zncc, corner = _lucas_kanade(image, T, self.half, start, self.lk_iterations)
        else:
            new, conv, zncc, corner = _lucas_kanade_affine(
                image, T, d, start, self.lk_iterations, self.affine_prior
            )
        inside = conv & (zncc >= min_zncc) & (corner >= self.min_cornerness)
        inside &= np.abs(new - pixels[sel]).max(axis=1) <= search + 1.5
        out[sel[inside]] = new[inside]
        aligned[sel[inside]] = True
        return out, aligned


def _any_finite(normals: np.ndarray) -> np.ndarray | None:
    """``normals``, or ``None`` where none is finite (the warp then skips the plane terms)."""
    return normals if np.isfinite(normals).any() else None


def _integer_search(image, T, d: np.ndarray, search: int, cc: np.ndarray) -> np.ndarray:
    """The integer shift within ``search`` of ``cc (n, 2)`` where the templates ``T`` (sampled
    at the integer offsets ``d (2, k)``) correlate best (ZNCC), moved to the sub-pixel peak of a
    parabola per axis (at most half a pixel)."""
    dx, dy = d.astype(int)
    s = np.arange(-search, search + 1)
    sx, sy = np.meshgrid(s, s)
    sh = np.stack([sx.ravel(), sy.ravel()], axis=1)  # (S, 2)
    cols = cc[:, None, None, 0] + sh[None, :, None, 0] + dx[None, None]
    rows = cc[:, None, None, 1] + sh[None, :, None, 1] + dy[None, None]
    C = _standardise(image[rows, cols].astype(np.float32))  # (n, S, k*k)
    score = (C @ T[..., None])[..., 0]
    best = np.argmax(score, axis=1)
    n_s = len(s)
    bx, by = best % n_s, best // n_s
    grid = score.reshape(-1, n_s, n_s)  # [row = y shift, col = x shift]
    i = np.arange(len(cc))
    bxc, byc = np.clip(bx, 1, n_s - 2), np.clip(by, 1, n_s - 2)

    ox = parabolic_offset(grid[i, byc, bxc - 1], grid[i, byc, bxc], grid[i, byc, bxc + 1])
    oy = parabolic_offset(grid[i, byc - 1, bxc], grid[i, byc, bxc], grid[i, byc + 1, bxc])
    return cc + sh[best] + np.stack([ox, oy], axis=1)


def _lucas_kanade(image, T, half: int, centre, iterations: int):
    """Gauss-Newton on the translation (with a gain and a bias) that best fits the templates
    ``T (n, k * k)`` (``k = 2 half + 1``, rows of ``y`` offsets) to ``image`` about
    ``centre (n, 2)``; returns the centres, whether each converged (last step below 0.1 px) and
    the ZNCC of the template with the image at the last window sampled.
    One bilinear sampling of a window a pixel wider per iteration gives the image and its central
    differences. The windows are gathered in the image's own type and converted after (not the
    whole image), and the 4 x 4 normal equations are one batched product in float32 (8-bit
    windows over ``k * k`` terms keep about six significant digits), solved in float64."""
    img = np.asarray(image)
    h, w = img.shape[:2]
    flat = img.reshape(h * w, *img.shape[2:])
    g = np.arange(-half - 1, half + 3)  # a window a pixel wider, one more for the interpolation
    n, k2 = len(centre), (2 * half + 1) ** 2
    p = centre.astype(float).copy()
    step = np.zeros_like(p)
    T32 = np.asarray(T, np.float32)[:, :, None]
    J = np.empty((n, 4, k2), np.float32)  # rows: d/dx, d/dy, the window, one
    J[:, 3] = 1.0
    ridge = 1e-9 * np.eye(4)
    for _ in range(iterations):
        # the window's samples share their sub-pixel offset: one gather, four weights
        base = np.floor(p).astype(int)
        ax, ay = (p - base).T.astype(np.float32)
        cols = np.clip(base[:, 0, None] + g[None], 0, w - 1)
        rows = np.clip(base[:, 1, None] + g[None], 0, h - 1)
        # (one gather from the flattened image: a third of the 2-D fancy index's time)
        G = flat[rows[:, :, None] * w + cols[:, None, :]].astype(np.float32)  # (n, k+3, k+3)
        ax, ay = ax[:, None, None], ay[:, None, None]
        top = G[:, :-1, :-1] + ax * (G[:, :-1, 1:] - G[:, :-1, :-1])
        bottom = G[:, 1:, :-1] + ax * (G[:, 1:, 1:] - G[:, 1:, :-1])
        Wd = top + ay * (bottom - top)  # (n, k + 2, k + 2): rows y, columns x
        J[:, 0] = (0.5 * (Wd[:, 1:-1, 2:] - Wd[:, 1:-1, :-2])).reshape(n, -1)
        J[:, 1] = (0.5 * (Wd[:, 2:, 1:-1] - Wd[:, :-2, 1:-1])).reshape(n, -1)
        J[:, 2] = Wd[:, 1:-1, 1:-1].reshape(n, -1)
        # T = a C(p + dp + d) + b, linearised in dp: linear in (a dp, a, b)
        JtJ = (J @ J.transpose(0, 2, 1)).astype(float)
        Jtr = (J @ T32).astype(float)
        sol = np.linalg.solve(JtJ + ridge, Jtr)[..., 0]
        a = np.where(np.abs(sol[:, 2]) > 1e-9, sol[:, 2], 1.0)
        step = np.clip(sol[:, :2] / a[:, None], -1.0, 1.0)
        p = p + step
    return (p, np.abs(step).max(axis=1) < 0.1, *_fit_scores(J[:, 2], T32[..., 0], JtJ))


def _fit_scores(window, T, JtJ) -> tuple[np.ndarray, np.ndarray]:
    """The ZNCC of each last sampled ``window (n, k)`` with its template ``T (n, k)``, and the
    window's aperture from the normal equations ``JtJ`` (rows 0 and 1 the image's gradients):
    the smaller over the larger eigenvalue of the gradient moments (an edge fixes the shift
    across it only; 1 for a corner with no preferred direction)."""
    zncc = np.einsum("nk,nk->n", _standardise(window), _standardise(T))
    a, b, c = JtJ[:, 0, 0], JtJ[:, 1, 1], JtJ[:, 0, 1]
    root = np.sqrt((a - b) ** 2 + 4 * c**2)
    return zncc, (a + b - root) / np.maximum(a + b + root, 1e-12)


def _sample_with_gradients(image: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Bilinear samples of ``image (h, w)`` and its central differences along ``x`` and ``y``
    at the points ``(x, y)`` of shape ``(n, k)`` (kept a pixel inside the image): three
    ``(n, k)`` float32 arrays. The differences are those of samples a pixel apart, which is
    sampling the image's central differences; five samplings of the points cost less than
    differencing the whole image for the few thousand points of a frame."""
    h, w = image.shape[:2]
    flat = image.reshape(-1)
    x = np.clip(x, 1.0, w - 2.0)
    y = np.clip(y, 1.0, h - 2.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 3)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 3)
    ax, ay = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    i = y0 * w + x0

    def at(shift: int) -> np.ndarray:
        f = flat[i + shift].astype(np.float32)
        f1 = flat[i + shift + 1].astype(np.float32)
        g = flat[i + shift + w].astype(np.float32)
        g1 = flat[i + shift + w + 1].astype(np.float32)
        top = f + ax * (f1 - f)
        return top + ay * (g + ax * (g1 - g) - top)

    return at(0), 0.5 * (at(1) - at(-1)), 0.5 * (at(w) - at(-w))


def _lucas_kanade_affine(image, T, d: np.ndarray, centre, iterations: int, prior: float):
    """:func:`_lucas_kanade` with a 2 x 2 correction ``D`` of the predicted warp: the templates
    ``T (n, k)``, sampled at the integer offsets ``d (2, k)``, are fitted to ``image`` at
    ``centre + (I + D) d`` with a gain and a bias (Gauss-Newton on 8 unknowns a landmark, the
    columns ``g_x, g_y, g_x d_x, g_x d_y, g_y d_x, g_y d_y, I, 1``). ``prior``: the weight
    ``lambda`` of ``lambda sum_q ||J_q||^2 D_q^2`` on the total correction (the same units as
    the fit's residual). ``D`` moves by at most 0.2 per entry a step and stays within 0.4
    (beyond it ``max_scale`` refuses the warp anyway); the translation moves by at most a pixel
    a step, as in the translation-only steps. Returns the centres, convergence (last step below
    0.1 px), the ZNCC at the last window sampled and the window's cornerness."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., 0]
    n, k = len(centre), d.shape[1]
    p = centre.astype(float).copy()
    D = np.zeros((n, 4))  # D00, D01, D10, D11
    step = np.zeros_like(p)
    dx, dy = d.astype(np.float32)
    T32 = np.asarray(T, np.float32)[:, :, None]
    J = np.empty((n, 8, k), np.float32)
    J[:, 7] = 1.0
    gain = np.ones(n)  # the last gain solved (the prior acts on the correction's total)
    q = np.arange(2, 6)
    for _ in range(iterations):
        x = p[:, 0, None] + (1.0 + D[:, 0, None]) * dx + D[:, 1, None] * dy
        y = p[:, 1, None] + D[:, 2, None] * dx + (1.0 + D[:, 3, None]) * dy
        window, gx, gy = _sample_with_gradients(img, x, y)
        J[:, 0], J[:, 1] = gx, gy
        J[:, 2], J[:, 3], J[:, 4], J[:, 5] = gx * dx, gx * dy, gy * dx, gy * dy
        J[:, 6] = window
        JtJ = (J @ J.transpose(0, 2, 1)).astype(float)
        Jtr = (J @ T32).astype(float)[..., 0]
        # unknowns (a dp, a dD, a, b): the prior lambda ||J_q||^2 (D_q + dD_q)^2, times a^2
        w = prior * JtJ[:, q, q]
        A = JtJ + 1e-9 * np.eye(8)
        A[:, q, q] += w
        Jtr[:, q] -= w * gain[:, None] * D
        sol = np.linalg.solve(A, Jtr[..., None])[..., 0]
        a = np.where(np.abs(sol[:, 6]) > 1e-9, sol[:, 6], 1.0)
        step = np.clip(sol[:, :2] / a[:, None], -1.0, 1.0)
        p = p + step
        D = np.clip(D + np.clip(sol[:, 2:6] / a[:, None], -0.2, 0.2), -0.4, 0.4)
        gain = a
    return (p, np.abs(step).max(axis=1) < 0.1, *_fit_scores(J[:, 6], T32[..., 0], JtJ))
