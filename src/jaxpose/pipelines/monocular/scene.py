"""What every pose score of one image shares: the model's padded geometry and the image maps
(:mod:`jaxpose.vision.image_maps`) as one pytree (:class:`_EdgeScene`)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.pipelines.monocular.options import InitOptions
from jaxpose.vision import image_maps
from jaxpose.vision.features import Detection
from jaxpose.vision.models import WireframeModel
from jaxpose.vision.roi import roi_diagonal


class _EdgeScene(NamedTuple):
    """What every pose score of one image shares (a pytree: ``vmap`` with ``in_axes=None``).

    ``geom``: :func:`_model_geometry` of the model; ``img_pts (N, 2)``, ``img_mask (N,)``: samples
    of the detected segments (:func:`jaxpose.vision.image_maps.segment_samples`); ``dt (H, W)``:
    distance map of the detected segments (pixels); ``tau``: truncation of the chamfer distances
    (pixels, ``0.05 l_ROI``); ``cam4``: ``[fx, fy, cx, cy]`` of the undistorted image; ``grid_pts
    (P, 2)``, ``grid_val (P,)``: a grid of pixels over the ROI and their smoothed grey levels, and
    ``face_poly (F, K, 3)``: the model's faces (vertices, padded by repeating the last), for the
    region term (:func:`_region_energy`); ``rods (S, S)``, ``rod_frame (3,)``: the rod response map
    of :func:`jaxpose.vision.image_maps.rod_map` and its ``[u_origin, v_origin, scale]``, for the
    antenna term; ``sil_pts (P, 2)``, ``sil_val (P,)``:
    :func:`jaxpose.vision.image_maps.silhouette_grid`, for the silhouette term (``None`` without a
    silhouette: an Earth behind the target, or the weight 0); ``ori (B, S, S)``, ``ori_frame (3,)``:
    :func:`jaxpose.vision.image_maps.orientation_maps` and its frame, for the orientation term
    (``None`` when its weight is 0); ``tex (B, S, S)``, ``tex_frame (3,)``:
    :func:`jaxpose.vision.image_maps.texture_maps`, and ``panel (N + 3, 3)``: samples inside the
    model's solar panel followed by its corner and two sides (:func:`_panel_geometry`), for the
    panel term (``None`` when its weight is 0 or the model has no panel); ``shade_pts (P, 2)``,
    ``shade_val (P,)``, ``shade_sq (P,)``: :func:`jaxpose.vision.image_maps.shading_grid`, for
    the face-shading term (``None`` when the model has no faces or both its weights are 0), and
    ``shade_coarse``: their 2x2 pooling (:func:`_pool_shading`) for the quick score (``None``
    when its weight is 0); ``fit_sample_w (S,)``: the weight of each model segment's samples in
    the model side of the shortlist's fit (:func:`_fit_sample_weights`; ``None``: all alike) and
    ``fit_model_weight``: the model side's weight in that fit."""

    geom: tuple
    img_pts: jax.Array
    img_mask: jax.Array
    dt: jax.Array
    tau: float
    cam4: jax.Array
    grid_pts: jax.Array | None = None
    grid_val: jax.Array | None = None
    face_poly: jax.Array | None = None
    region_weight: float = 0.0
    rods: jax.Array | None = None
    rod_frame: jax.Array | None = None
    antenna_weight: float = 0.0
    sil_pts: jax.Array | None = None
    sil_val: jax.Array | None = None
    silhouette_weight: float = 0.0
    ori: jax.Array | None = None
    ori_frame: jax.Array | None = None
    orientation_weight: float = 0.0
    tex: jax.Array | None = None
    tex_frame: jax.Array | None = None
    panel: jax.Array | None = None
    panel_weight: float = 0.0
    shade_pts: jax.Array | None = None
    shade_val: jax.Array | None = None
    shade_sq: jax.Array | None = None
    spread_weight: float = 0.0
    shade_coarse: tuple | None = None
    spread_quick_weight: float = 0.0
    fit_sample_w: jax.Array | None = None
    fit_model_weight: float = 1.0

    def chamfer_inputs(self):
        """``(geom, img_pts, img_mask, dt, tau, cam4)``: the fields the chamfer terms use."""
        return self.geom, self.img_pts, self.img_mask, self.dt, self.tau, self.cam4


def _edge_scene(det: Detection, model: WireframeModel, options: InitOptions) -> _EdgeScene:
    """The score inputs of one image (needs ``det.roi`` and ``det.segments``)."""
    l_roi = roi_diagonal(det.roi)
    img_pts, img_mask = _as_jax(image_maps.segment_samples(det.segments))
    dt = jnp.asarray(image_maps.distance_map(det.segments, det.image.shape))
    region = options.region_weight > 0
    antennas = options.antenna_weight > 0 and len(model.antennas) > 0
    sil = options.silhouette_weight > 0 and det.silhouette is not None and len(model.faces) > 0
    ori = options.orientation_weight > 0
    panel = _panel_geometry(model) if options.panel_weight > 0 else None
    # the shading grid only where a ranking reads it (the pipeline makes it for the final pose)
    shade = len(model.faces) > 0 and (options.spread_weight > 0 or options.spread_quick_weight > 0)
    cells = _as_jax(image_maps.shading_grid(det.image, det.roi)) if shade else (None, None, None)
    coarse = _pool_shading(*cells) if shade and options.spread_quick_weight > 0 else None
    return _EdgeScene(
        _model_geometry(model),
        img_pts,
        img_mask,
        dt,
        0.05 * l_roi,
        _ideal_params(det.camera),
        *(_as_jax(image_maps.region_grid(det.image, det.roi)) if region else (None, None)),
        _face_polygons(model) if len(model.faces) else None,
        float(options.region_weight),
        *(_as_jax(image_maps.rod_map(det.image, det.roi)) if antennas else (None, None)),
        float(options.antenna_weight),
        *(
            _as_jax(image_maps.silhouette_grid(det.silhouette, det.silhouette_factor, det.roi))
            if sil
            else (None, None)
        ),
        float(options.silhouette_weight),
        *(_as_jax(image_maps.orientation_maps(det.image, det.roi)) if ori else (None, None)),
        float(options.orientation_weight),
        *(
            _as_jax(image_maps.texture_maps(det.image, det.roi))
            if panel is not None
            else (None, None)
        ),
        panel,
        float(options.panel_weight),
        *cells,
        float(options.spread_weight),
        coarse,
        float(options.spread_quick_weight),
        _fit_sample_weights(model, bool(options.fit_by_length)),
        float(options.fit_model_weight),
    )


@functools.lru_cache(maxsize=16)
def _fit_sample_weights(model: WireframeModel, by_length: bool) -> jax.Array | None:
    """``(S,)`` weights of the model segments (edges, then antennas: :func:`_model_geometry`)
    in the model side of the shortlist's edge fit (its weighted mean square), an edge 1 on
    average; ``None`` (all alike) without ``by_length``.

    With ``by_length`` each edge's samples count in proportion to its length and the antennas
    not at all: every segment has the same number of samples, so counted alike the panel's 2 cm
    sides weigh as much as its 77 cm edges, and the antennas, whose directions on the mock-up
    differ from the model's by 13-16 degrees (:func:`jaxpose.vision.models.build_tango`), pull
    the fit as much as the body's edges. Without it (the default), every segment counts
    alike."""
    if not by_length:
        return None
    segs = np.asarray(_model_geometry(model)[0])
    n_edges = len(model.edges)
    w = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=-1)
    w[n_edges:] = 0.0
    return jnp.asarray(w / w[:n_edges].mean())


def _pool_cells(grid: int, pts, *values):
    """2x2 pooling of the cells of a ``grid x grid`` cell grid (row-major): the centres ``(G^2,
    2)`` and each per-cell array ``(G^2,)`` averaged over blocks of four, ``G = grid // 2``."""
    G = grid // 2
    pooled = [pts.reshape(G, 2, G, 2, 2).mean(axis=(1, 3)).reshape(-1, 2)]
    pooled += [v.reshape(G, 2, G, 2).mean(axis=(1, 3)).reshape(-1) for v in values]
    return tuple(pooled)


def _pool_shading(pts, val, sq):
    """2x2 pooling of the shading grid's cells (exact: a pooled cell's two moments are the means
    of its four cells')."""
    return _pool_cells(image_maps.SHADING_GRID, pts, val, sq)


def _with_shading(sc: _EdgeScene, det: Detection) -> _EdgeScene:
    """The scene with the shading grid of the detection's image (:func:`_edge_scene` holds it
    only where a ranking weight reads it; the face-shading spread of the final pose is evidence
    for the confidence class whatever the weights)."""
    if sc.shade_pts is not None:
        return sc
    pts, val, sq = _as_jax(image_maps.shading_grid(det.image, det.roi))
    return sc._replace(shade_pts=pts, shade_val=val, shade_sq=sq)


def _as_jax(arrays):
    return tuple(jnp.asarray(a) for a in arrays)


@functools.lru_cache(maxsize=8)
def _model_geometry(model: WireframeModel, samples: int = 8):
    segs = model.edge_points
    faces = list(model.edge_faces)
    if len(model.antennas):
        segs = np.concatenate([segs, model.antenna_points])
        faces += [()] * len(model.antennas)
    F = len(model.faces)
    ef = np.zeros((len(segs), max(F, 1)), bool)
    for e, fs in enumerate(faces):
        ef[e, list(fs)] = True
    s = np.linspace(0.0, 1.0, samples)
    pts = segs[:, :1] + s[None, :, None] * (segs[:, 1:] - segs[:, :1])
    normals = model.face_normals if F else np.zeros((1, 3))
    centres = model.face_centres if F else np.zeros((1, 3))
    return tuple(jnp.asarray(x) for x in (segs, pts, ef, normals, centres))


#: Samples per side of the grid inside the solar panel (:func:`_panel_geometry`), and the share of
#: each side left out along the panel's border (its outline is an edge, not a cell line).
PANEL_SAMPLES = 6
PANEL_BORDER = 0.15


@functools.lru_cache(maxsize=8)
def _panel_geometry(model: WireframeModel) -> jax.Array | None:
    """The solar panel of the built-in Tango (face 0: the top of the panel, a grid of cells, as
    :func:`jaxpose.vision.render.default_textures` renders it): ``PANEL_SAMPLES`` squared points
    inside it, then its corner and its two sides (body frame, metres), ``(N + 3, 3)``; ``None``
    for other models (no known panel)."""
    if model.name != "tango" or not len(model.faces):
        return None
    V = np.asarray(model.vertices, float)
    o, u, v = V[0], V[3] - V[0], V[1] - V[0]
    a = np.linspace(PANEL_BORDER, 1.0 - PANEL_BORDER, PANEL_SAMPLES)
    A, Bm = np.meshgrid(a, a, indexing="ij")
    pts = o + A.reshape(-1, 1) * u + Bm.reshape(-1, 1) * v
    return jnp.asarray(np.concatenate([pts, [o, u, v]]))


@functools.lru_cache(maxsize=8)
def _face_polygons(model: WireframeModel) -> jax.Array:
    if not len(model.faces):
        return jnp.zeros((1, 3, 3))
    k = max(len(f) for f in model.faces)
    idx = [list(f) + [f[-1]] * (k - len(f)) for f in model.faces]
    return jnp.asarray(model.vertices[np.asarray(idx)])


def _ideal_params(camera: PinholeCamera):
    return jnp.asarray([float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)])
