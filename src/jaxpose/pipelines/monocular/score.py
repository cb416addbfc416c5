"""Pure-JAX scores of a pose against one image
(:class:`~jaxpose.pipelines.monocular.scene._EdgeScene`), each for one pose and batched over
hypotheses with ``jax.vmap``: the quick score of thousands of hypotheses, the symmetric truncated
chamfer distance, the region, silhouette and antenna terms, and the ranking key that sums them."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.pipelines.monocular.scene import _EdgeScene, _pool_cells
from jaxpose.vision.image_maps import SILHOUETTE_GRID


def _project(points_cam, cam4):
    """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)`` in the undistorted image,
    ``cam4 = [fx, fy, cx, cy]``: the core's :meth:`~jaxpose.core.camera.PinholeCamera.project`
    with ``min_depth=1e-6``, so points at or behind the camera land far off the image and drop
    out of every in-image test of the scores."""
    camera = PinholeCamera(cam4[0], cam4[1], cam4[2], cam4[3], jnp.zeros(5, cam4.dtype))
    return camera.project(points_cam, min_depth=1e-6)


def _point_segment_distance(p, a, b):
    """Distances ``(M, E)`` from points ``(M, 2)`` to segments ``a, b (E, 2)``."""
    ab = b - a
    ap = p[:, None, :] - a[None]
    s = jnp.clip(
        jnp.sum(ap * ab[None], -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-12)[None], 0.0, 1.0
    )
    d = ap - s[..., None] * ab[None]
    return jnp.sqrt(jnp.sum(d * d, -1) + 1e-12)


def _visible_edges(R, t, geom):
    """Edges on at least one front-facing face at ``(R, t)`` (edges of no face always count)."""
    _, _, edge_faces, normals, centres = geom
    n_cam = normals @ R.T
    c_cam = centres @ R.T + t
    front = jnp.sum(n_cam * c_cam, -1) < 0
    has_face = jnp.any(edge_faces, axis=1)
    return jnp.where(has_face, jnp.any(edge_faces & front[None], axis=1), True)


def _face_cover(R, t, P, poly, geom, cam4, band=0.0):
    """Which front-facing projected faces contain each pixel: ``(F, P)`` bool for pixels
    ``P (P, 2)`` of the undistorted image (with ``band > 0``: at least ``band`` pixels inside
    every projected side), and each face centre's depth ``(F,)`` (metres).

    A face is front-facing when its outward normal points at the camera and every vertex is in
    front of it; its projection is convex (a planar convex polygon under a pinhole camera), so a
    pixel is inside when it lies on one side of every projected side."""
    _, _, _, normals, centres = geom
    n_cam = normals @ R.T
    c_cam = centres @ R.T + t
    front = (jnp.sum(n_cam * c_cam, -1) < 0) & (c_cam[:, 2] > 1e-3)
    pv = poly @ R.T + t  # (F, K, 3)
    q = _project(pv, cam4)  # (F, K, 2)
    e = jnp.roll(q, -1, axis=1) - q  # (F, K, 2)
    rel = P[None, None] - q[:, :, None]  # (F, K, P, 2)
    cross = e[:, :, None, 0] * rel[..., 1] - e[:, :, None, 1] * rel[..., 0]
    if not (isinstance(band, float | int) and band == 0):
        # signed distances to the sides (pixels); padded repeated vertices give zero-length sides
        ln = jnp.sqrt(jnp.sum(e * e, -1))[:, :, None]
        real = ln > 1e-9
        dist = cross / jnp.maximum(ln, 1e-9)
        pos = jnp.all(jnp.where(real, dist >= band, True), axis=1)
        neg = jnp.all(jnp.where(real, dist <= -band, True), axis=1)
        inside = pos | neg
    else:
        inside = jnp.all(cross >= 0, axis=1) | jnp.all(cross <= 0, axis=1)  # (F, P)
    inside &= front[:, None] & jnp.all(pv[..., 2] > 1e-3, axis=1)[:, None]
    return inside, c_cam[:, 2]


def _region_energy(R, t, sc: _EdgeScene):
    """Piecewise-constant region energy of the pose (Chan-Vese-like, in ``[0, 1]``).

    Each grid cell over the ROI (:func:`jaxpose.vision.image_maps.region_grid`) is labelled by
    the nearest front-facing projected face containing it (painter's order by face-centre depth),
    or background; the energy is the within-label sum of squared deviations from the label means
    over the total sum of squares. At the true pose each label is one face, lit alike all over (a
    saturated face, a face in shadow a few grey levels off the background, both uniform up to
    thin creases and noise that the cell means average); a wrong pose mixes lit, dark and
    background pixels in its labels. It does not depend on detected segments, so texture and
    faint edges leave it alone where the chamfer distance fails."""
    val, poly = sc.grid_val, sc.face_poly
    F = poly.shape[0]
    inside, depth_f = _face_cover(R, t, sc.grid_pts, poly, sc.geom, sc.cam4)
    depth = jnp.where(inside, depth_f[:, None], jnp.inf)
    label = jnp.where(jnp.any(inside, 0), jnp.argmin(depth, axis=0), F)  # (P,)
    onehot = jax.nn.one_hot(label, F + 1, dtype=val.dtype)  # (P, F + 1)
    cnt = jnp.sum(onehot, 0)
    mean = (onehot.T @ val) / jnp.maximum(cnt, 1.0)
    sse = jnp.sum((val - onehot @ mean) ** 2)
    sst = jnp.sum((val - jnp.mean(val)) ** 2)
    return sse / jnp.maximum(sst, 1e-9)


#: Share of ``tau`` by which each projected face is shrunk before the face-shading term reads it
#: (the border of a face straddles the neighbouring face or the background even at the true pose,
#: a fitted pose is a few pixels off). Chosen, not tuned.
SPREAD_BAND = 0.4


def _shading_cells(sc: _EdgeScene, coarse: bool):
    """The shading grid's cells ``(pts, val, sq)``, or with ``coarse`` their 2x2 pooling
    (``sc.shade_coarse``, a quarter of the cost, for the quick score)."""
    if not coarse:
        return sc.shade_pts, sc.shade_val, sc.shade_sq
    return sc.shade_coarse


def _face_spread(R, t, sc: _EdgeScene, coarse: bool = False, background: bool = False):
    """Face-shading spread of the pose (about ``[0, 1.5]``; lower is better): the root mean
    square deviation of the grey levels inside the projected front faces from their own face's
    mean, over the root mean square deviation of the whole grid from its mean.

    Each cell of :func:`jaxpose.vision.image_maps.shading_grid` is labelled by the nearest
    front-facing face that contains it (painter's order), and counts only when it lies at least
    ``SPREAD_BAND x tau`` inside that face; a cell contributes its mean squared deviation from
    the face's mean, the texture inside the cell included (both moments of the cell are known).
    A box face under one light is near-uniform, so at the true pose every label is one face
    (lit, saturated or in shadow); a wrong pose's faces straddle faces, background and the
    target's outline. On the 23 SPEED+ development images with a pose, the spread at the
    returned pose separated right from wrong answers better than the chamfer distance (docs:
    monocular evaluation). ``1`` when fewer than 8 cells lie inside the faces. ``coarse``: on the
    pooled grid (:func:`_shading_cells`). ``background``: the cells farther than the band from
    every projected face count too, as one more label (a pose whose faces lie on a uniform
    background then pays for the target it leaves in the background)."""
    pts, val, sq = _shading_cells(sc, coarse)
    poly = sc.face_poly
    F = poly.shape[0]
    inside, depth_f = _face_cover(R, t, pts, poly, sc.geom, sc.cam4)
    deep, _ = _face_cover(R, t, pts, poly, sc.geom, sc.cam4, band=SPREAD_BAND * sc.tau)
    depth = jnp.where(inside, depth_f[:, None], jnp.inf)
    label = jnp.argmin(depth, axis=0)  # (P,)
    use = jnp.any(inside, 0) & jnp.take_along_axis(deep, label[None], axis=0)[0]
    n_faces = jnp.sum(use)
    if background:
        grown, _ = _face_cover(R, t, pts, poly, sc.geom, sc.cam4, band=-SPREAD_BAND * sc.tau)
        away = ~jnp.any(grown, 0)
        label = jnp.where(away, F, label)
        use = use | away
    onehot = jax.nn.one_hot(label, F + 1, dtype=val.dtype) * use[:, None].astype(val.dtype)
    cnt = jnp.sum(onehot, 0)
    mean = (onehot.T @ val) / jnp.maximum(cnt, 1.0)
    m = onehot @ mean
    dev = jnp.sum(jnp.where(use, sq - 2.0 * m * val + m * m, 0.0))
    n = jnp.sum(cnt)
    total = jnp.maximum(jnp.mean(sq) - jnp.mean(val) ** 2, 1e-12)
    spread = jnp.sqrt(jnp.maximum(dev / jnp.maximum(n, 1.0), 0.0) / total)
    return jnp.where(n_faces >= 8, spread, 1.0)


@functools.lru_cache(maxsize=4)
def _jit_face_spread():
    return jax.jit(_face_spread, static_argnames=("coarse", "background"))


def _silhouette_cells(sc: _EdgeScene, coarse: bool):
    """The silhouette grid's cell centres and values, or with ``coarse`` their 2x2 pooling
    (``SILHOUETTE_GRID / 2`` squared cells: a quarter of the cost, for the thousands of poses of the
    quick score; the shortlist's ranking key uses the full grid)."""
    if not coarse:
        return sc.sil_pts, sc.sil_val
    return _pool_cells(SILHOUETTE_GRID, sc.sil_pts, sc.sil_val)


def _silhouette_term(R, t, sc: _EdgeScene, coarse: bool = False):
    """``1 - IoU`` (in ``[0, 1]``) of the model's projected silhouette at the pose and the image's
    silhouette (:func:`jaxpose.vision.roi.silhouette_mask`) on the cells of
    :func:`jaxpose.vision.image_maps.silhouette_grid`: a cell is the model's when a front-facing
    face covers its centre, and counts the share of it that is silhouette (soft IoU: ``sum min / sum
    max``).

    Against a dark sky the faces in shadow are part of the silhouette though they give no edges,
    and blanket texture inside a face does not change it: on the SPEED+ lightbox photographs the
    poses chosen by the edge score alone covered 0.19-0.62 of it (IoU), the labelled poses
    0.71-0.85 (four of five photographs against the dark lightbox)."""
    pts, val = _silhouette_cells(sc, coarse)
    inside, _ = _face_cover(R, t, pts, sc.face_poly, sc.geom, sc.cam4)
    model = jnp.any(inside, axis=0).astype(val.dtype)
    inter = jnp.sum(jnp.minimum(model, val))
    union = jnp.sum(jnp.maximum(model, val))
    return 1.0 - inter / jnp.maximum(union, 1e-9)


@functools.lru_cache(maxsize=4)
def _jit_silhouette_term():
    return jax.jit(_silhouette_term)


def _antenna_term(R, t, sc: _EdgeScene):
    """``tau x (1 - mean rod response)`` (pixels) over samples of the projected antennas' outer
    80% (the base sits on the body's edge); ``tau`` when the model has no antenna in front of
    the camera. At the true pose every visible antenna lies on a rod of the image; a pose that
    puts the box's outline on the same edges with the antennas elsewhere (a 180-degree flip) pays
    up to ``tau``. Antennas hidden behind the body are not modelled (they pay too)."""
    _, samples, edge_faces, _, _ = sc.geom
    antenna = ~jnp.any(edge_faces, axis=1)  # edges of no face: the antennas
    s = jnp.linspace(0.0, 1.0, samples.shape[1])
    pc = samples @ R.T + t
    uv = (_project(pc, sc.cam4) - sc.rod_frame[:2]) * sc.rod_frame[2]
    S = sc.rods.shape[0]
    inside = jnp.all((uv >= 0) & (uv <= S - 1), axis=-1)
    ij = jnp.clip(jnp.round(uv).astype(jnp.int32), 0, S - 1)
    val = jnp.where(inside, sc.rods[ij[..., 1], ij[..., 0]], 0.0)
    m = (antenna[:, None] & (s > 0.2)[None] & (pc[..., 2] > 1e-3)).astype(val.dtype)
    return sc.tau * (1.0 - jnp.sum(val * m) / jnp.maximum(jnp.sum(m), 1.0))


def _edge_normal_bins(pix, bins: int):
    """The orientation bin ``(E,)`` (of ``bins`` over 180 degrees, as in
    :func:`jaxpose.vision.image_maps.orientation_maps`) of each projected edge's normal, from its
    samples' pixels ``pix (E, K, 2)`` (first to last sample)."""
    d = pix[:, -1] - pix[:, 0]
    phi = jnp.mod(jnp.arctan2(d[:, 1], d[:, 0]) + 0.5 * jnp.pi, jnp.pi)
    return jnp.mod(jnp.round(phi / (jnp.pi / bins)).astype(jnp.int32), bins)


def _orientation_term(R, t, sc: _EdgeScene):
    """``1 -`` the mean LINE-2D similarity (Hinterstoisser et al. 2012) at the projected visible
    model edges, in ``[0, 1]``: each edge sample reads the spread orientation map
    (:func:`jaxpose.vision.image_maps.orientation_maps`) of its edge's projected normal, 1 where a
    strong image gradient nearby points the same way (modulo 180 deg), 0 where none does. Only the
    model's edges are read, so background texture away from them does not vote; ``1`` when no
    sample falls on the map."""
    _, samples, _, _, _ = sc.geom
    B = sc.ori.shape[0]
    S = sc.ori.shape[1]
    vis = _visible_edges(R, t, sc.geom)
    pc = samples @ R.T + t
    pix = _project(pc, sc.cam4)  # (E, K, 2)
    o = _edge_normal_bins(pix, B)  # (E,)
    uv = (pix - sc.ori_frame[:2]) * sc.ori_frame[2]
    inside = jnp.all((uv >= 0) & (uv <= S - 1), axis=-1)
    ij = jnp.clip(jnp.round(uv).astype(jnp.int32), 0, S - 1)
    val = sc.ori[o[:, None], ij[..., 1], ij[..., 0]]
    m = (vis[:, None] & inside & (pc[..., 2] > 1e-3)).astype(val.dtype)
    n = jnp.sum(m)
    return jnp.where(n > 0, 1.0 - jnp.sum(val * m) / jnp.maximum(n, 1.0), 1.0)


@functools.lru_cache(maxsize=4)
def _jit_orientation_term():
    return jax.jit(_orientation_term)


#: Share of ``(1 - cos)`` of the panel's viewing angle under which it counts fully (a panel seen
#: edge-on shows no cells): its weight is ``min(1, cos / PANEL_COS)``. Chosen, not tuned.
PANEL_COS = 0.3
#: Mean excess (:func:`_panel_term`) that counts as full evidence of the cell lines: the
#: photographed panels of SPEED+ show the lines of one direction, about 0.35-0.45 of the window's
#: gradient above the uniform share. Chosen, not tuned.
PANEL_FULL = 0.4


def _panel_term(R, t, sc: _EdgeScene):
    """Solar-cell evidence against the pose, in ``[0, 1]``: ``1 -`` the mean excess, at samples
    inside the projected solar panel, of the local gradient-orientation histogram
    (:func:`jaxpose.vision.image_maps.texture_maps`) in the two bins around the normal of one
    of the panel's projected sides over their uniform share (the cells' lines run along the
    sides; the larger of the two sides' excesses, as photographs often show the lines of one
    direction only), scaled so that a mean excess of ``PANEL_FULL`` gives 1.

    The panel is the one face of Tango that the near-symmetric flips (180 deg about an axis in
    its plane) move to the other side of the body: at the true pose the cell lines lie where the
    term looks for them; a flip puts a smooth or blanket-covered face there, or a face with
    lines in other directions. A panel turned away (or seen edge-on) is neither evidence for
    nor against: it pays ``0.5``, weighted by the panel's visibility."""
    pts, o, u, v = sc.panel[:-3], sc.panel[-3], sc.panel[-2], sc.panel[-1]
    B = sc.tex.shape[0]
    S = sc.tex.shape[1]
    n_cam = R @ jnp.cross(u, v)  # outward (face 0's winding, right-hand rule)
    c_cam = R @ (o + 0.5 * (u + v)) + t
    cosv = -jnp.sum(n_cam * c_cam) / jnp.maximum(
        jnp.linalg.norm(n_cam) * jnp.linalg.norm(c_cam), 1e-12
    )
    corners = _project(jnp.stack([o, o + u, o + v]) @ R.T + t, sc.cam4)
    du, dv = corners[1] - corners[0], corners[2] - corners[0]

    def normal_bins(d):  # the two bins around the normal's orientation
        x = jnp.mod(jnp.arctan2(d[1], d[0]) + 0.5 * jnp.pi, jnp.pi) / (jnp.pi / B)
        lo = jnp.floor(x).astype(jnp.int32)
        return jnp.mod(lo, B), jnp.mod(lo + 1, B)

    pc = pts @ R.T + t
    uv = (_project(pc, sc.cam4) - sc.tex_frame[:2]) * sc.tex_frame[2]
    inside = jnp.all((uv >= 0) & (uv <= S - 1), axis=-1) & (pc[:, 2] > 1e-3)
    ij = jnp.clip(jnp.round(uv).astype(jnp.int32), 0, S - 1)
    h = sc.tex[:, ij[:, 1], ij[:, 0]].astype(pc.dtype)  # (B, N)
    total = jnp.sum(h, 0)

    def excess(d):
        a, b = normal_bins(d)
        return (h[a] + h[b] - 2.0 / B * total) / (1.0 - 2.0 / B)

    ex = jnp.maximum(excess(du), excess(dv))
    m = inside.astype(h.dtype)
    ev = jnp.clip(jnp.sum(ex * m) / jnp.maximum(jnp.sum(m), 1.0) / PANEL_FULL, 0.0, 1.0)
    w = jnp.where(jnp.sum(m) > 0, jnp.clip(cosv / PANEL_COS, 0.0, 1.0), 0.0)
    return w * (1.0 - ev) + (1.0 - w) * 0.5


def _quick_score(R, t, sc: _EdgeScene, roi):
    """Cheap ranking score of many hypotheses: the model side of :func:`_chamfer` plus a penalty
    when the projected model's box does not match the ROI in size (a small, far-away projection
    otherwise fits any dense patch of edges), plus the antenna term (:func:`_antenna_term`) and
    the silhouette term (:func:`_silhouette_term`, on the pooled grid) when the scene has
    them, and the face-shading spread (:func:`_face_spread`, pooled grid) when its quick weight
    is above 0."""
    geom, dt, tau, cam4 = sc.geom, sc.dt, sc.tau, sc.cam4
    edges, samples, edge_faces, normals, centres = geom
    vis = _visible_edges(R, t, geom)
    pc = samples @ R.T + t
    pix = _project(pc, cam4)
    H, W = dt.shape
    inside = (
        (pix[..., 0] >= 0) & (pix[..., 0] <= W - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= H - 1)
    )
    m = (vis[:, None] & (pc[..., 2] > 1e-3)).astype(dt.dtype)
    ij = jnp.clip(jnp.round(pix).astype(jnp.int32), 0, jnp.array([W - 1, H - 1], dtype=jnp.int32))
    dm = jnp.where(inside, jnp.minimum(dt[ij[..., 1], ij[..., 0]], tau), tau)
    model_term = jnp.sum(dm * m) / jnp.maximum(jnp.sum(m), 1.0)
    lo, hi = jnp.min(pix.reshape(-1, 2), axis=0), jnp.max(pix.reshape(-1, 2), axis=0)
    diag = jnp.linalg.norm(hi - lo)
    roi_diag = jnp.linalg.norm(roi[2:] - roi[:2])
    size = jnp.minimum(jnp.abs(jnp.log(jnp.maximum(diag, 1.0) / roi_diag)), 1.0)
    out = model_term + tau * size
    if sc.rods is not None:
        out = out + sc.antenna_weight * _antenna_term(R, t, sc)
    if sc.sil_pts is not None:
        out = out + sc.silhouette_weight * tau * _silhouette_term(R, t, sc, coarse=True)
    if sc.ori is not None:
        out = out + sc.orientation_weight * tau * _orientation_term(R, t, sc)
    if sc.panel is not None:
        out = out + sc.panel_weight * tau * _panel_term(R, t, sc)
    if sc.shade_coarse is not None:
        out = out + sc.spread_quick_weight * tau * _face_spread(R, t, sc, coarse=True)
    return out


def _chamfer(R, t, sc: _EdgeScene):
    """Symmetric truncated chamfer distance (pixels) of the model at ``(R, t)``.

    Model side: samples of front-facing edges looked up in the distance transform of the detected
    segments. Image side: samples of the detected segments to the nearest projected edge.
    Returns ``(score, share of model samples within tau / 4 of a detected segment)``.
    """
    geom, img_pts, img_mask, dt, tau, cam4 = sc.chamfer_inputs()
    edges, samples, edge_faces, normals, centres = geom
    vis = _visible_edges(R, t, geom)
    pc = samples @ R.T + t  # (E, S, 3)
    pix = _project(pc, cam4)
    H, W = dt.shape
    inside = (
        (pix[..., 0] >= 0) & (pix[..., 0] <= W - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= H - 1)
    )
    m = vis[:, None] & inside & (pc[..., 2] > 1e-3)
    ij = jnp.clip(jnp.round(pix).astype(jnp.int32), 0, jnp.array([W - 1, H - 1], dtype=jnp.int32))
    dm = jnp.minimum(dt[ij[..., 1], ij[..., 0]], tau)
    dm = jnp.where(inside, dm, tau)
    mf = m.astype(dm.dtype)
    nm = jnp.sum(mf)
    model_term = jnp.where(nm > 0, jnp.sum(dm * mf) / jnp.maximum(nm, 1.0), tau)
    near = jnp.where(
        nm > 0, jnp.sum((dm < 0.25 * tau).astype(dm.dtype) * mf) / jnp.maximum(nm, 1.0), 0.0
    )
    ends = _project(edges @ R.T + t, cam4)  # (E, 2, 2)
    d = _point_segment_distance(img_pts, ends[:, 0], ends[:, 1])
    d = jnp.where(vis[None], d, jnp.inf)
    di = jnp.minimum(jnp.min(d, axis=1), tau)
    wi = img_mask.astype(di.dtype)
    img_term = jnp.sum(di * wi) / jnp.maximum(jnp.sum(wi), 1.0)
    return model_term + img_term, near


def _rank_key(R, t, sc: _EdgeScene):
    """Ranking key (pixels): the chamfer distance plus ``region_weight x tau x`` the region
    energy (:func:`_region_energy`; the scene has no grid when the weight is 0) plus
    ``antenna_weight x`` the antenna term (:func:`_antenna_term`; no rod map when 0) plus
    ``silhouette_weight x tau x`` the silhouette term (:func:`_silhouette_term`; only with a
    silhouette) plus ``spread_weight x tau x`` the face-shading spread (:func:`_face_spread`).
    Returns ``(key, chamfer, near)``."""
    ch, near = _chamfer(R, t, sc)
    key = ch
    if sc.grid_pts is not None:
        key = key + sc.region_weight * sc.tau * _region_energy(R, t, sc)
    if sc.rods is not None:
        key = key + sc.antenna_weight * _antenna_term(R, t, sc)
    if sc.sil_pts is not None:
        key = key + sc.silhouette_weight * sc.tau * _silhouette_term(R, t, sc)
    if sc.ori is not None:
        key = key + sc.orientation_weight * sc.tau * _orientation_term(R, t, sc)
    if sc.panel is not None:
        key = key + sc.panel_weight * sc.tau * _panel_term(R, t, sc)
    if sc.shade_pts is not None:
        key = key + sc.spread_weight * sc.tau * _face_spread(R, t, sc)
    return key, ch, near


@functools.lru_cache(maxsize=4)
def _batched_quick():
    return jax.jit(jax.vmap(_quick_score, in_axes=(0, 0, None, None)))


@functools.lru_cache(maxsize=4)
def _batched_rank():
    return jax.jit(jax.vmap(_rank_key, in_axes=(0, 0, None)))


_MAX_CANDIDATES = 10  # top five and their planar mirrors


def _pad_to(x, n):
    """Pad (repeating the first row) or cut the leading axis to ``n`` (fixed compiled shapes)."""
    x = np.asarray(x)
    if len(x) >= n:
        return jnp.asarray(x[:n])
    return jnp.asarray(np.concatenate([x, np.repeat(x[:1], n - len(x), 0)]))


def _score_poses(poses, sc: _EdgeScene) -> tuple[np.ndarray, np.ndarray]:
    """Ranking key (:func:`_rank_key`) and symmetric chamfer distance of each pose (batches of
    ``_MAX_CANDIDATES``); ``inf`` when not finite or behind the camera."""
    keys, out = [], []
    for a in range(0, len(poses), _MAX_CANDIDATES):
        chunk = poses[a : a + _MAX_CANDIDATES]
        R = _pad_to(jnp.stack([p.R for p in chunk]), _MAX_CANDIDATES)
        t = _pad_to(jnp.stack([p.t for p in chunk]), _MAX_CANDIDATES)
        key, score, _ = _batched_rank()(R, t, sc)
        keys.append(np.asarray(key)[: len(chunk)])
        out.append(np.asarray(score)[: len(chunk)])
    key, score = np.concatenate(keys), np.concatenate(out)
    z = np.array([float(p.t[2]) for p in poses])
    ok = np.isfinite(score) & np.isfinite(key) & (z > 0)
    return np.where(ok, key, np.inf), np.where(ok, score, np.inf)
