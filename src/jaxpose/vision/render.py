"""Synthetic renderer (NumPy + OpenCV, no GPU) of a wireframe model seen by a pinhole camera.

Faces are shaded (Lambert + ambient, optional specular) and drawn far to near (painter's
algorithm) as polygons whose sides are subdivided before projection, so lens distortion bends
straight edges exactly as the camera does. Antennas are thick lines drawn in the same depth order.
An Earth-like textured background, Gaussian blur and sensor noise are optional.

Written to be extended (stereo pairs, textures, glints, motion blur) through these hooks:

* ``albedo``: per-face reflectance, ``(F,)``;
* ``textures``: ``{face_index: f(points_body (M, 3)) -> (M,) albedo}``, evaluated at the body-frame
  point seen through each pixel of that face (ray/plane intersection), so a texture is attached to
  the body and looks the same from any camera (what stereo matching needs);
* ``specular``: ``(strength, shininess)`` Blinn-Phong glints;
* :func:`render_layers` returns the noise-free radiance and the face-index buffer before the
  sensor model (:func:`apply_sensor`), so motion blur or a second camera can reuse them.

The returned :class:`Rendering` holds the image, the true pose and the visible edge endpoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose, quat_to_dcm

__all__ = [
    "Rendering",
    "VisibleEdges",
    "apply_sensor",
    "blanket_texture",
    "earth_background",
    "lightbox_scene",
    "photographic_earth",
    "project_points",
    "random_pose",
    "render",
    "render_layers",
    "solar_cell_texture",
    "visible_edges",
]

BACKGROUND = -1  # face-index buffer value of background pixels
_ANTENNA = -2  # face-index buffer value of antenna pixels


@dataclass
class VisibleEdges:
    """Visible parts of model edges at a pose.

    Attributes:
        edge_ids: ``(K,)`` indices into ``model.edges`` (antennas: ``len(model.edges) + a``).
        segments: ``(K, 2, 2)`` pixel endpoints of the visible part (distorted image).
        fraction: ``(K,)`` visible share of each edge's length.
        points_body: ``(K, 2, 3)`` body-frame points at those endpoints.
    """

    edge_ids: np.ndarray
    segments: np.ndarray
    fraction: np.ndarray
    points_body: np.ndarray


@dataclass
class Rendering:
    """A rendered image with its ground truth."""

    image: np.ndarray  # (H, W) uint8
    pose: Pose
    camera: PinholeCamera
    visible: VisibleEdges
    face_ids: np.ndarray  # (H, W) int: front face index, -1 background, -2 antenna
    roi: np.ndarray  # (4,) true bounding box u0, v0, u1, v1 of the target (pixels)


# ----------------------------------------------------------------------------- geometry helpers
def _pose_np(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(pose.R, dtype=float), np.asarray(pose.t, dtype=float)


def project_points(camera: PinholeCamera, points_cam: np.ndarray) -> np.ndarray:
    """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)`` with distortion (NumPy twin of
    :meth:`PinholeCamera.project` for the eager image side; tested against it)."""
    P = np.asarray(points_cam, dtype=float)
    z = np.where(P[..., 2] > 1e-9, P[..., 2], 1e-9)
    x, y = P[..., 0] / z, P[..., 1] / z
    k1, k2, p1, p2, k3 = np.asarray(camera.dist, dtype=float)
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    return np.stack([fx * xd + cx, fy * yd + cy], -1)


def _pixel_rays(camera: PinholeCamera, pixels: np.ndarray) -> np.ndarray:
    """Undistorted normalised rays ``(M, 3)`` (z = 1) of pixels ``(M, 2)`` (OpenCV's iteration)."""
    if len(pixels) == 0:  # OpenCV returns None for no points
        return np.zeros((0, 3))
    K = np.asarray(camera.K, dtype=float)
    xy = cv2.undistortPoints(
        pixels.reshape(-1, 1, 2).astype(np.float64), K, np.asarray(camera.dist)
    )
    xy = xy.reshape(-1, 2)
    return np.concatenate([xy, np.ones((len(xy), 1))], 1)


def _image_size(camera: PinholeCamera, shape) -> tuple[int, int]:
    if shape is not None:
        return int(shape[0]), int(shape[1])
    if camera.width <= 0 or camera.height <= 0:
        raise ValueError("the camera has no image size: pass shape=(height, width)")
    return camera.height, camera.width


def _subdivide(poly: np.ndarray, n: int) -> np.ndarray:
    """Polygon ``(k, 3)`` with every side split into ``n`` pieces: ``(k n, 3)``."""
    nxt = np.roll(poly, -1, axis=0)
    s = np.arange(n)[None, :, None] / n
    return (poly[:, None] + s * (nxt - poly)[:, None]).reshape(-1, poly.shape[1])


def _centres_inside(pix: np.ndarray, shape) -> np.ndarray:
    """Mask ``shape`` of the pixels whose centres (integer coordinates) lie inside the polygon
    ``pix (k, 2)`` (even-odd rule over its edges, within its bounding box). Exact where
    ``cv2.fillPoly`` rounds the vertices to whole pixels and fills inclusively, which grows a
    polygon by about half a pixel on every side."""
    H, W = shape
    mask = np.zeros((H, W), bool)
    u0, v0 = np.maximum(np.ceil(pix.min(0)).astype(int), 0)
    u1, v1 = np.minimum(np.floor(pix.max(0)).astype(int), [W - 1, H - 1])
    if u1 < u0 or v1 < v0:
        return mask
    vv, uu = np.mgrid[v0 : v1 + 1, u0 : u1 + 1].astype(float)
    inside = np.zeros(uu.shape, bool)
    a, b = pix, np.roll(pix, -1, axis=0)
    for (xa, ya), (xb, yb) in zip(a, b, strict=True):
        if ya == yb:
            continue
        crosses = (ya > vv) != (yb > vv)
        x_at = xa + (vv - ya) * (xb - xa) / (yb - ya)
        inside ^= crosses & (uu < x_at)
    mask[v0 : v1 + 1, u0 : u1 + 1] = inside
    return mask


# ----------------------------------------------------------------------------- visibility
def _face_depth_along_rays(n_cam, d_cam, rays):
    """Depth z where rays (M, 3) with z = 1 meet the plane n . x = d."""
    den = rays @ n_cam
    with np.errstate(divide="ignore", invalid="ignore"):
        z = d_cam / den
    return np.where(np.abs(den) > 1e-12, z, np.inf)


def visible_edges(
    model,
    pose: Pose,
    camera: PinholeCamera,
    *,
    face_ids: np.ndarray | None = None,
    shape=None,
    samples: int = 48,
    min_fraction: float = 0.05,
    include_antennas: bool = True,
    buffer_scale: float = 1.0,
) -> VisibleEdges:
    """Visible parts of the model's edges (and antennas) at ``pose``.

    An edge sample is visible when it is in front of the camera, inside the image, at least one of
    the edge's faces is front-facing (free edges and antennas: always), and the front face of the
    painter's buffer at its pixel is the edge's own face or lies behind it (ray/plane depth test,
    1 mm tolerance). The longest visible run of samples gives the endpoints.

    Without ``face_ids`` the painter's buffer is rendered here, at ``buffer_scale`` times the
    image resolution (0.25 is four times faster per side and plenty for visibility).
    """
    R, t = _pose_np(pose)
    H, W = _image_size(camera, shape)
    scale = 1.0
    if face_ids is None:
        scale = float(buffer_scale)
        small = PinholeCamera(
            float(camera.fx) * scale,
            float(camera.fy) * scale,
            (float(camera.cx) + 0.5) * scale - 0.5,
            (float(camera.cy) + 0.5) * scale - 0.5,
            camera.dist,
        )
        hs, ws = max(int(round(H * scale)), 1), max(int(round(W * scale)), 1)
        face_ids = render_layers(model, pose, small, shape=(hs, ws), textures=None)[1]
    segs3 = model.edge_points
    owners = list(model.edge_faces)
    if include_antennas and len(model.antennas):
        segs3 = np.concatenate([segs3, model.antenna_points])
        owners += [()] * len(model.antennas)
    front = _front_facing(model, R, t)
    s = np.linspace(0.0, 1.0, samples)
    pts_body = segs3[:, :1] + s[None, :, None] * (segs3[:, 1:] - segs3[:, :1])  # (E, S, 3)
    pts_cam = pts_body @ R.T + t
    pix = project_points(camera, pts_cam)
    ok = pts_cam[..., 2] > 1e-6
    ok &= (pix[..., 0] >= 0) & (pix[..., 0] <= W - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= H - 1)
    hb, wb = face_ids.shape
    pi = np.clip(np.rint((pix + 0.5) * scale - 0.5).astype(int), 0, [wb - 1, hb - 1])
    fid = face_ids[pi[..., 1], pi[..., 0]]
    n_cam = model.face_normals @ R.T
    d_cam = np.einsum("fi,fi->f", n_cam, model.face_centres @ R.T + t)
    rays = pts_cam / np.where(np.abs(pts_cam[..., 2:]) > 1e-12, pts_cam[..., 2:], 1e-12)
    for e, faces in enumerate(owners):
        if faces and not any(front[f] for f in faces):
            ok[e] = False
            continue
        occ = (fid[e] >= 0) & ~np.isin(fid[e], faces)
        if occ.any():
            idx = np.nonzero(occ)[0]
            f = fid[e, idx]
            zf = np.einsum("mi,mi->m", rays[e, idx], n_cam[f])
            with np.errstate(divide="ignore", invalid="ignore"):
                zf = np.where(np.abs(zf) > 1e-12, d_cam[f] / zf, np.inf)
            behind = zf < pts_cam[e, idx, 2] - 1e-3
            ok[e, idx[behind]] = False
    ids, out, frac, body = [], [], [], []
    for e in range(len(segs3)):
        run = _longest_run(ok[e])
        if run is None:
            continue
        a, b = run
        f = (b - a) / (samples - 1)
        if f < min_fraction:
            continue
        ids.append(e)
        out.append([pix[e, a], pix[e, b]])
        frac.append(f)
        body.append([pts_body[e, a], pts_body[e, b]])
    return VisibleEdges(
        np.array(ids, dtype=int),
        np.array(out, dtype=float).reshape(-1, 2, 2),
        np.array(frac, dtype=float),
        np.array(body, dtype=float).reshape(-1, 2, 3),
    )


def _longest_run(mask: np.ndarray):
    best, start, best_run = 0, None, None
    for i, m in enumerate(np.append(mask, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best:
                best, best_run = i - start, (start, i - 1)
            start = None
    return best_run if best >= 2 else None


def _front_facing(model, R, t) -> np.ndarray:
    n_cam = model.face_normals @ R.T
    c_cam = model.face_centres @ R.T + t
    return np.einsum("fi,fi->f", n_cam, c_cam) < 0


# ----------------------------------------------------------------------------- textures
def solar_cell_texture(origin, axis_u, axis_v, cells=(8, 10), *, base=0.22, line=0.32, frame=0.02):
    """A solar-panel-like texture: dark cells separated by bright lines (a body-attached hook).

    ``origin`` is a panel corner and ``axis_u``, ``axis_v`` its two sides (body frame, metres).
    """
    o, au, av = (np.asarray(v, dtype=float) for v in (origin, axis_u, axis_v))
    lu, lv = np.linalg.norm(au), np.linalg.norm(av)

    def texture(points_body):
        rel = points_body - o
        a = rel @ au / lu**2
        b = rel @ av / lv**2
        fa, fb = (a * cells[0]) % 1.0, (b * cells[1]) % 1.0
        w = 0.04
        grid = (fa < w) | (fa > 1 - w) | (fb < w) | (fb > 1 - w)
        edge = (a < frame) | (a > 1 - frame) | (b < frame) | (b > 1 - frame)
        return np.where(grid | edge, line, base)

    return texture


def blanket_texture(
    face_vertices,
    rng: np.random.Generator,
    *,
    albedo: float = 0.8,
    creases_per_m2: float = 400.0,
    length_m: tuple[float, float] = (0.03, 0.2),
    texel_m: float = 0.002,
):
    """A crumpled multi-layer-insulation (MLI) blanket on one planar face (a body-attached hook).

    The face is covered by short straight creases at random places and angles (lengths
    ``length_m``), each a one-texel line brighter (a glint on the fold) or darker (its shadow) than
    the blanket, over a slow +-15 % undulation: the many short spurious edge segments inside the
    faces that the SPEED+ lightbox photographs show. ``face_vertices (k, 3)``: the face polygon
    (body frame, metres). Rasterised once into a texture map of ``texel_m`` metres per texel.
    """
    V = np.asarray(face_vertices, dtype=float)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise ValueError(f"face_vertices must be (k >= 3, 3); got shape {V.shape}")
    o = V[0]
    eu = V[1] - V[0]
    eu /= np.linalg.norm(eu)
    n = np.cross(V[1] - V[0], V[2] - V[0])
    n /= np.linalg.norm(n)
    ev = np.cross(n, eu)
    uv = np.stack([(V - o) @ eu, (V - o) @ ev], 1)
    lo, hi = uv.min(0) - 0.01, uv.max(0) + 0.01
    nu, nv = (np.ceil((hi - lo) / texel_m).astype(int) + 1).tolist()
    smooth = cv2.resize(rng.random((4, 4)).astype(np.float32), (nu, nv), cv2.INTER_CUBIC)
    tex = (1.0 + 0.3 * (smooth - 0.5)).astype(np.float32)
    area = float(np.prod(hi - lo))
    for _ in range(int(creases_per_m2 * area)):
        c = rng.uniform(lo, hi)
        ang = rng.uniform(0, np.pi)
        half = 0.5 * rng.uniform(*length_m) * np.array([np.cos(ang), np.sin(ang)])
        a = np.rint((c - half - lo) / texel_m * 16).astype(int)  # 4 fractional bits (shift=4)
        b = np.rint((c + half - lo) / texel_m * 16).astype(int)
        value = rng.uniform(1.5, 2.2) if rng.random() < 0.6 else rng.uniform(0.3, 0.6)
        cv2.line(tex, tuple(a.tolist()), tuple(b.tolist()), value, 1, cv2.LINE_AA, 4)

    def texture(points_body):
        rel = np.asarray(points_body, dtype=float) - o
        i = np.clip(np.rint((rel @ ev - lo[1]) / texel_m).astype(int), 0, nv - 1)
        j = np.clip(np.rint((rel @ eu - lo[0]) / texel_m).astype(int), 0, nu - 1)
        return albedo * tex[i, j]

    return texture


def lightbox_scene(
    model,
    rng: np.random.Generator,
    *,
    earth: str | None = None,
    shape=None,
    cell_grid: tuple[int, int, float] | None = None,
) -> dict:
    """Render options of a laboratory image like the SPEED+ lightbox photographs (a development
    domain for :func:`render`, not fitted to those photographs).

    What the photographs show and these options imitate: a flat grey background (about 30 of 255)
    with strong sensor noise (sigma about 7 grey levels, measured on a background patch); an
    exposure that saturates the lit faces; faces in shadow only a few grey levels from the
    background (weak ambient); crumpled MLI blankets on the body (:func:`blanket_texture`) and a
    dark solar panel; Sun direction random over the hemisphere facing the camera. The background
    level, noise, ambient and exposure are drawn per image from the ranges below.

    ``earth``: ``None`` (the laboratory's grey background), ``"partial"`` (an Earth whose limb
    crosses the image, clouds in a corner or along a side, grey background beyond the limb) or
    ``"full"`` (the Earth fills the image): a :func:`photographic_earth` of image ``shape``
    ``(H, W)`` as the ``background`` option, drawn after everything else, so that the options
    without it are the same for the same generator state.

    ``cell_grid``: ``(cells_u, cells_v, line)``, a solar-cell grid of that many cells along the
    panel's two sides with gaps of radiance ``line`` (the default: 8 x 10 cells, ``line`` 0.2,
    faint); the SPEED+ panel shows many cells with bright gaps, whose lines the Hough streams
    pick up (a development stress test; it draws nothing from ``rng``).
    """
    if cell_grid is not None and (
        len(cell_grid) != 3 or min(cell_grid[:2]) < 1 or not 0 <= cell_grid[2] <= 1
    ):
        raise ValueError(
            f"cell_grid must be (cells_u >= 1, cells_v >= 1, line in [0, 1]); got {cell_grid}"
        )
    if earth not in (None, "partial", "full"):
        raise ValueError(f"earth must be None, 'partial' or 'full'; got {earth!r}")
    if earth is not None and shape is None:
        raise ValueError("an Earth background needs the image shape=(H, W)")
    sun = rng.normal(size=3)
    sun[2] = -abs(sun[2]) - 0.3  # towards the camera's side: some lit face is seen
    F = len(model.faces)
    albedo = np.full(F, 0.7)
    textures = {}
    if model.name == "tango":
        V = model.vertices
        albedo[:6] = 0.25  # the panel slab: dark cells and edges
        cells, line = ((8, 10), 0.2) if cell_grid is None else (tuple(cell_grid[:2]), cell_grid[2])
        textures[0] = solar_cell_texture(V[0], V[3] - V[0], V[1] - V[0], cells, base=0.1, line=line)
        body = range(6, F)
    else:
        body = range(F)
    for f in body:
        textures[f] = blanket_texture(model.vertices[list(model.faces[f])], rng, albedo=0.8)
    exposure = rng.uniform(2.5, 5.0)
    bg = rng.uniform(25, 40) / 255.0
    options = dict(
        sun_dir_cam=sun,
        ambient=bg / exposure * rng.uniform(0.75, 1.35) / 0.8,  # shadow: 0.75-1.35 x background
        albedo=albedo,
        textures=textures,
        exposure=exposure,
        noise_sigma=rng.uniform(6.0, 8.0) / 255.0,
        blur_sigma_px=rng.uniform(0.8, 1.5),
        background_level=bg / exposure,
    )
    if earth is not None:
        ground, inside = photographic_earth(shape, rng, coverage=earth)
        options.pop("background_level")
        options["background"] = (np.where(inside, np.maximum(ground, bg), bg) / exposure).astype(
            np.float32
        )
    return options


def photographic_earth(
    shape, rng: np.random.Generator, *, coverage: str = "partial"
) -> tuple[np.ndarray, np.ndarray]:
    """An Earth of photographic contrast: ``(radiance (H, W) in [0, 1], inside (H, W) bool)``.

    Unlike :func:`earth_background` (soft clouds at half brightness), the clouds here are bright
    (their top level drawn in 0.35-1.0, so the brightest may saturate after exposure) with sharp
    edges and fine structure, over a dark ocean (0.1-0.3 of that level) and brighter land with
    sharp coasts: the SPEED+
    lightbox photographs with the Earth show such clouds, dimmer than the lit target in some and
    far brighter than its shadowed faces in others. ``coverage``: ``"full"`` (the Earth fills the
    image) or ``"partial"`` (a limb, a circle 1-3 image sizes in radius, crosses the image so that
    the Earth covers a corner or a side; ``inside`` is False beyond it).
    """
    if coverage not in ("partial", "full"):
        raise ValueError(f"coverage must be 'partial' or 'full'; got {coverage!r}")
    H, W = (int(v) for v in shape)
    if H < 2 or W < 2:
        raise ValueError(f"shape must be at least 2x2; got {shape}")

    def fractal(octaves, base, decay):
        out = np.zeros((H, W), dtype=np.float32)
        amp = 1.0
        for octave in range(octaves):
            n = base * 2**octave
            small = rng.random((n, max(2, int(n * W / H)))).astype(np.float32)
            out += amp * cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
            amp *= decay
        return (out - out.min()) / max(float(out.max() - out.min()), 1e-6)

    cloud_field = fractal(7, 3, 0.65)
    land = fractal(5, 2, 0.5)
    level = rng.uniform(0.35, 1.0)
    cover = rng.uniform(0.35, 0.6)  # the higher, the fewer clouds
    gain = rng.uniform(3.0, 6.0)
    clouds = np.clip((cloud_field - cover) * gain, 0.0, 1.0)
    ocean = rng.uniform(0.1, 0.3)
    coast = land > rng.uniform(0.4, 0.6)  # land masses with sharp coasts
    ground = np.where(coast, ocean + rng.uniform(0.1, 0.25), ocean) + 0.1 * (land - 0.5)
    img = level * np.maximum(clouds, ground)
    if coverage == "full":
        return img.astype(np.float32), np.ones((H, W), bool)
    size = max(H, W)
    r = rng.uniform(1.0, 3.0) * size
    ang = rng.uniform(0, 2 * np.pi)
    dist = r + rng.uniform(0.1, 0.4) * size  # the image centre lies beyond the limb
    cx, cy = W / 2 + np.cos(ang) * dist, H / 2 + np.sin(ang) * dist
    yy, xx = np.mgrid[0:H, 0:W]
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 < r**2
    return img.astype(np.float32), inside


def earth_background(shape, rng: np.random.Generator, *, brightness: float = 0.55) -> np.ndarray:
    """An Earth-like background ``(H, W)`` in ``[0, 1]``: a limb at a random place, fractal clouds
    over a darker ocean/land pattern, black space beyond the limb."""
    H, W = shape
    noise = np.zeros((H, W), dtype=np.float32)
    amp = 1.0
    for octave in range(6):
        n = 4 * 2**octave
        small = rng.random((n, max(2, int(n * W / H)))).astype(np.float32)
        noise += amp * cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
        amp *= 0.55
    noise = (noise - noise.min()) / max(float(noise.max() - noise.min()), 1e-6)
    clouds = np.clip((noise - 0.5) * 3.0, 0, 1)
    ground = 0.25 + 0.2 * noise
    img = brightness * np.maximum(clouds, ground)
    # Limb: a big circle whose edge crosses the image.
    r = rng.uniform(1.5, 4.0) * max(H, W)
    ang = rng.uniform(0, 2 * np.pi)
    cx = W / 2 + np.cos(ang) * (r - rng.uniform(-0.3, 0.6) * max(H, W))
    cy = H / 2 + np.sin(ang) * (r - rng.uniform(-0.3, 0.6) * max(H, W))
    yy, xx = np.mgrid[0:H, 0:W]
    inside = (xx - cx) ** 2 + (yy - cy) ** 2 < r**2
    return np.where(inside, img, 0.0).astype(np.float32)


# ----------------------------------------------------------------------------- rendering
def render_layers(
    model,
    pose: Pose,
    camera: PinholeCamera,
    *,
    shape=None,
    sun_dir_cam=(0.4, -0.5, -0.75),
    ambient: float = 0.08,
    albedo=None,
    textures=None,
    specular: tuple[float, float] | None = None,
    antenna_diameter_m: float = 0.015,
    subdivisions: int = 16,
    exact_faces: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free radiance ``(H, W)`` float in ``[0, 1]`` (NaN on background) and the face-index
    buffer (``-1`` background, ``-2`` antenna), by the painter's algorithm.

    ``sun_dir_cam`` points from the target towards the Sun, in the camera frame.
    ``exact_faces``: a face covers exactly the pixels whose centres it holds
    (:func:`_centres_inside`); else ``cv2.fillPoly``'s, about half a pixel more on every side,
    so that a nearer face drawn later takes a half-pixel band of the face behind it.
    """
    R, t = _pose_np(pose)
    H, W = _image_size(camera, shape)
    if t[2] <= 0:
        raise ValueError(f"the target origin must be in front of the camera (t_z > 0); got t = {t}")
    F = len(model.faces)
    albedo = np.full(F, 0.7) if albedo is None else np.broadcast_to(np.asarray(albedo, float), (F,))
    sun = np.asarray(sun_dir_cam, dtype=float)
    sun = sun / np.linalg.norm(sun)
    n_cam = model.face_normals @ R.T
    c_cam = model.face_centres @ R.T + t
    front = np.einsum("fi,fi->f", n_cam, c_cam) < 0
    lambert = np.clip(n_cam @ sun, 0.0, None)
    shade = ambient + (1 - ambient) * lambert
    if specular is not None:
        strength, shininess = specular
        view = -c_cam / np.linalg.norm(c_cam, axis=1, keepdims=True)
        half = view + sun
        half /= np.linalg.norm(half, axis=1, keepdims=True)
        spec = strength * np.clip(np.einsum("fi,fi->f", n_cam, half), 0, None) ** shininess
    else:
        spec = np.zeros(F)

    radiance = np.full((H, W), np.nan, dtype=np.float32)
    face_ids = np.full((H, W), BACKGROUND, dtype=np.int32)
    items = []  # (depth, kind, index)
    for f in np.nonzero(front)[0]:
        items.append((float(c_cam[f, 2]), "face", int(f)))
    ant = model.antenna_points
    for a in range(len(ant)):
        items.append((float((ant[a] @ R.T + t)[:, 2].mean()), "antenna", a))
    scale = 16  # fixed-point sub-pixel precision for cv2.fillPoly / cv2.line
    for _, kind, k in sorted(items, key=lambda x: -x[0]):
        if kind == "face":
            poly = model.vertices[list(model.faces[k])] @ R.T + t
            if np.any(poly[:, 2] <= 1e-6):
                continue
            pix = project_points(camera, _subdivide(poly, subdivisions))
            if not np.all(np.isfinite(pix)) or np.abs(pix).max() > 1e6:
                continue
            if exact_faces:
                sel = _centres_inside(pix, (H, W))
            else:
                mask = np.zeros((H, W), np.uint8)
                cv2.fillPoly(
                    mask, [np.rint(pix * scale).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4
                )
                sel = mask.astype(bool)
            face_ids[sel] = k
            value = albedo[k] * shade[k] + spec[k]
            if textures and k in textures:
                vv, uu = np.nonzero(sel)
                rays = _pixel_rays(camera, np.stack([uu, vv], 1).astype(float))
                n, d = n_cam[k], float(n_cam[k] @ c_cam[k])
                z = _face_depth_along_rays(n, d, rays)
                pts_body = (rays * z[:, None] - t) @ R  # back to the body frame
                tex = np.asarray(textures[k](pts_body), dtype=float)
                radiance[vv, uu] = tex * shade[k] + spec[k]
            else:
                radiance[sel] = value
        else:
            seg = ant[k] @ R.T + t
            if np.any(seg[:, 2] <= 1e-6):
                continue
            pix = project_points(camera, seg)
            width = max(
                1,
                int(
                    round(
                        0.5 * float(camera.fx + camera.fy) * antenna_diameter_m / seg[:, 2].mean()
                    )
                ),
            )
            mask = np.zeros((H, W), np.uint8)
            p = np.rint(pix * scale).astype(np.int64)
            if np.abs(p).max() > 2**30:
                continue
            cv2.line(
                mask, tuple(map(int, p[0])), tuple(map(int, p[1])), 1, width, cv2.LINE_8, shift=4
            )
            sel = mask.astype(bool)
            face_ids[sel] = _ANTENNA
            radiance[sel] = 0.75 * (ambient + (1 - ambient) * 0.8)
    return radiance, face_ids


def apply_sensor(
    radiance: np.ndarray,
    rng: np.random.Generator,
    *,
    background: np.ndarray | None = None,
    blur_sigma_px: float = 0.8,
    noise_sigma: float = 0.01,
    exposure: float = 1.0,
) -> np.ndarray:
    """Radiance (NaN = background) to an 8-bit image: background, Gaussian blur, noise, clipping."""
    img = np.where(np.isnan(radiance), 0.0 if background is None else background, radiance)
    img = img.astype(np.float32) * exposure
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    if noise_sigma > 0:
        img = img + rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def render(
    model,
    pose: Pose,
    camera: PinholeCamera,
    *,
    rng: np.random.Generator | int | None = None,
    shape=None,
    earth: bool = False,
    blur_sigma_px: float = 0.8,
    noise_sigma: float = 0.01,
    exposure: float = 1.0,
    background_level: float | None = None,
    background: np.ndarray | None = None,
    **layer_options,
) -> Rendering:
    """Render ``model`` at ``pose``: image, true pose, visible edges, face buffer and true ROI.

    ``layer_options`` go to :func:`render_layers` (light, albedo, textures, specular, ...). With
    ``textures`` left out and the Tango model, the top of the solar panel gets solar cells.
    ``background_level``: a uniform background radiance (before ``exposure``) instead of black
    space or ``earth``; ``background``: an ``(H, W)`` background radiance (before ``exposure``);
    :func:`lightbox_scene` gives all the options of a lightbox photograph.
    """
    rng = np.random.default_rng(rng)
    H, W = _image_size(camera, shape)
    if layer_options.get("textures", "default") == "default":
        layer_options["textures"] = default_textures(model)
    radiance, face_ids = render_layers(model, pose, camera, shape=(H, W), **layer_options)
    bg = earth_background((H, W), rng) if earth else None
    if background_level is not None:
        if earth:
            raise ValueError("earth and background_level are exclusive")
        bg = np.full((H, W), float(background_level), np.float32)
    if background is not None:
        if earth or background_level is not None:
            raise ValueError("background, earth and background_level are exclusive")
        bg = np.asarray(background, dtype=np.float32)
        if bg.shape != (H, W):
            raise ValueError(f"background must have shape {(H, W)}; got {bg.shape}")
    image = apply_sensor(
        radiance,
        rng,
        background=bg,
        blur_sigma_px=blur_sigma_px,
        noise_sigma=noise_sigma,
        exposure=exposure,
    )
    vis = visible_edges(model, pose, camera, face_ids=face_ids, shape=(H, W))
    vv, uu = np.nonzero(face_ids != BACKGROUND)
    roi = (
        np.array([uu.min(), vv.min(), uu.max(), vv.max()], dtype=float)
        if len(uu)
        else np.full(4, np.nan)
    )
    return Rendering(image, pose, camera, vis, face_ids, roi)


def default_textures(model) -> dict | None:
    """Solar cells on the Tango panel top (face 0 of the built-in model); none for other models."""
    if model.name != "tango":
        return None
    V = model.vertices
    return {0: solar_cell_texture(V[0], V[3] - V[0], V[1] - V[0])}


def random_pose(
    rng: np.random.Generator,
    camera: PinholeCamera,
    *,
    range_m: tuple[float, float] = (3.0, 12.0),
    margin: float = 0.25,
) -> Pose:
    """A uniformly random attitude at a random range whose target origin projects inside the
    central ``1 - 2 margin`` of the image."""
    q = rng.normal(size=4)  # a normalised Gaussian 4-vector is a uniform random rotation
    R = np.asarray(quat_to_dcm(q / np.linalg.norm(q)))
    z = rng.uniform(*range_m)
    W, H = camera.width or 2 * float(camera.cx), camera.height or 2 * float(camera.cy)
    u = rng.uniform(margin * W, (1 - margin) * W)
    v = rng.uniform(margin * H, (1 - margin) * H)
    x = (u - float(camera.cx)) / float(camera.fx) * z
    y = (v - float(camera.cy)) / float(camera.fy) * z
    return Pose(np.asarray(R), np.array([x, y, z]))
