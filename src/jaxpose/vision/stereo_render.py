"""Stereo sequences of a tumbling target (extends :mod:`jaxpose.vision.render`, no second renderer).

The scene of Yang et al. 2024 (Sec. 1, 5): a defunct spacecraft spins about a principal axis at a
set rate while the chaser hovers at a set range and films it with a side-by-side stereo rig. Each
frame is drawn with :func:`jaxpose.vision.render.render_layers` (painter's algorithm, body-attached
textures) once per camera and turned into an 8-bit image by
:func:`~jaxpose.vision.render.apply_sensor`. This module adds, on top of those hooks:

* :func:`tumbler_model`: a 1 m target (box body, one solar wing, two antennas) and
  :func:`tumbler_textures`, a body-attached quilt of blanket patches (corners for ORB, texture for
  NCC) and solar cells on the wing;
* the motion: a spin at ``rate_deg_s`` about a body axis (``spin_axis_body``, the body z axis by
  default, or any axis off the principal axes), optionally with nutation: that axis tilted by
  ``nutation_deg`` from a fixed direction about which it precesses at ``precession_deg_s`` (the
  kinematics of a torque-free tumbling body); target origin on the boresight at ``range_m``;
* the Sun direction drifts in the camera frame (``sun_rate_deg_s``) and may sweep a further
  ``sun_sweep_deg`` over the sequence (both about the camera y axis);
* glints: a per-pixel Blinn-Phong lobe (the view direction changes across a flat face, so the
  highlight is a spot that moves as the target turns), added to the radiance;
* motion blur: the radiance averaged over sub-frame poses spread over the exposure
  (``blur`` = exposure / frame interval), as many as keep consecutive copies of the fastest
  model vertex within ``blur_step_px`` of each other (:func:`exposure_offsets`), so that the
  image holds a smear rather than separate copies;
* sensor noise and defocus (``apply_sensor``), and the ground truth of every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jaxpose.core._checks import is_finite_number
from jaxpose.core.camera import PinholeCamera, StereoCamera
from jaxpose.core.geometry import Pose
from jaxpose.vision.models import WireframeModel
from jaxpose.vision.render import (
    BACKGROUND,
    _face_depth_along_rays,
    apply_sensor,
    project_points,
    render_layers,
    solar_cell_texture,
)

__all__ = [
    "StereoFrame",
    "StereoScene",
    "default_rig",
    "exposure_offsets",
    "render_sequence",
    "render_stereo_frame",
    "scene_pose",
    "tumbler_model",
    "tumbler_textures",
]


def default_rig(
    width: int = 1024, height: int = 768, *, fov_deg: float = 50.0, baseline_m: float = 0.3
):
    """The default side-by-side rig: two identical ideal pinholes, ``fov_deg`` horizontal FOV."""
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    cam = PinholeCamera(f, f, (width - 1) / 2, (height - 1) / 2, width=width, height=height)
    return StereoCamera.from_baseline(cam, baseline_m)


def tumbler_model(size_m: float = 1.0) -> WireframeModel:
    """A target ``size_m`` across: body box ``0.5 x 0.45 x 0.55`` (scaled), a solar wing on +y, two
    antennas. Body origin at the body centre; the spin axis is body z."""
    s = size_m
    bx, by, bz = 0.25 * s, 0.225 * s, 0.275 * s
    body = np.array([[x, y, z] for z in (-bz, bz) for y in (-by, by) for x in (-bx, bx)])
    # wing: a thin plate from y = by to y = by + 0.5 s, spanning x in [-0.2 s, 0.2 s] at z = 0
    wy0, wy1, wx, wt = by, by + 0.5 * s, 0.2 * s, 0.01 * s
    wing = np.array([[x, y, z] for z in (-wt, wt) for y in (wy0, wy1) for x in (-wx, wx)])
    ant = np.array(
        [
            [bx * 0.5, -by, bz],
            [bx * 0.5, -by - 0.25 * s, bz + 0.15 * s],
            [-bx, -by * 0.3, -bz],
            [-bx - 0.2 * s, -by * 0.3, -bz - 0.2 * s],
        ]
    )
    V = np.concatenate([body, wing + 0.0, ant])

    def box_faces(o):  # vertices o + (x, y, z bits) with index x + 2 y + 4 z
        return [
            (o + 0, o + 2, o + 3, o + 1),  # z-
            (o + 4, o + 5, o + 7, o + 6),  # z+
            (o + 0, o + 1, o + 5, o + 4),  # y-
            (o + 2, o + 6, o + 7, o + 3),  # y+
            (o + 0, o + 4, o + 6, o + 2),  # x-
            (o + 1, o + 3, o + 7, o + 5),  # x+
        ]

    def box_edges(o):
        pairs = []
        for a in range(8):
            for bit in (1, 2, 4):
                if not a & bit:
                    pairs.append((o + a, o + a + bit))
        return pairs

    return WireframeModel(
        vertices=V,
        edges=np.array(box_edges(0) + box_edges(8)),
        faces=tuple(box_faces(0) + box_faces(8)),
        antennas=np.array([[16, 17], [18, 19]]),
        name="tumbler",
    )


def _hash01(ijk: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random values in [0, 1) of integer cells ``(M, 3)``."""
    h = (
        (ijk[:, 0] * 73856093)
        ^ (ijk[:, 1] * 19349663)
        ^ (ijk[:, 2] * 83492791)
        ^ (seed * 2654435761)
    )
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF) / 65536.0


#: Side of the blanket quilt's cells (m): its texture's patches and its glints' facets.
_QUILT_CELL_M = 0.05


def tumbler_textures(
    model: WireframeModel, *, cell_m: float = _QUILT_CELL_M, seed: int = 1
) -> dict:
    """Body-attached textures: a blanket quilt (patches of random albedo with fine crinkle) on
    every body face, solar cells on the wing's two large faces, plain thin wing edges."""

    def quilt(points_body):
        ijk = np.floor(points_body / cell_m).astype(np.int64)
        base = 0.35 + 0.55 * _hash01(ijk, seed)
        fine = np.floor(points_body / (cell_m / 2)).astype(np.int64)
        return base * (0.9 + 0.2 * _hash01(fine, seed + 7))

    tex = {k: quilt for k in range(6)}
    wing = model.vertices[8:16]
    o, u, v = wing[4], wing[5] - wing[4], wing[6] - wing[4]  # top face (z+) corners
    cells = solar_cell_texture(o, u, v, cells=(6, 8), base=0.2, line=0.7)
    tex[7] = cells
    tex[6] = solar_cell_texture(
        wing[0], wing[1] - wing[0], wing[2] - wing[0], cells=(6, 8), base=0.2, line=0.7
    )
    return tex


@dataclass(frozen=True)
class StereoScene:
    """Parameters of a rendered sequence (defaults: the paper's two turns at 10.2 deg/s).

    Attributes:
        rate_deg_s: spin rate about the body z axis.
        range_m: distance from the left camera to the target centre.
        frame_rate_hz: camera frame rate.
        frames: number of frames (``None``: two full turns).
        tilt_deg: angle between the spin axis and the image's up direction, towards the camera.
        size_m: target size.
        spin_axis_body: body-frame spin axis (normalised; default body z, a principal axis).
        nutation_deg: angle between the spin axis and the precession axis (0: a flat spin).
        precession_deg_s: precession rate of the spin axis about the precession axis (the
            spin axis' rest direction, tilted towards the camera by ``tilt_deg``).
        sun_dir_cam: initial direction to the Sun (camera frame).
        sun_rate_deg_s: drift of the Sun direction about the camera y axis.
        sun_sweep_deg: further rotation of the Sun direction about the camera y axis, spread
            linearly over the sequence (a light that sweeps across the target).
        blur: exposure / frame interval (0: no motion blur).
        blur_step_px: largest image motion of any model vertex between two consecutive
            sub-frame renderings of the blur (pixels of the left camera): the number of
            renderings follows the motion over the exposure (:func:`exposure_offsets`).
        blur_samples: most sub-frame renderings averaged for the blur (cost: one rendering of
            each camera each, about 15-80 ms of CPU at 1024 x 768 from 5 to 1.5 m, up to about
            150 ms with glints).
        glints: per-pixel specular strength (0: none); ``shininess`` its exponent.
        glint_facet_deg: the blanket's quilt cells are facets tilted by up to this from their
            face, so that its glints scatter over the faces as on crinkled insulation (0: flat
            faces, whose lobe is seen only where a whole face mirrors the Sun: in the default
            geometry never, over a whole turn).
        noise_sigma: sensor noise (fraction of full scale); ``defocus_px`` the optics blur.
        pixel_samples: each pixel's radiance is the mean of ``pixel_samples x pixel_samples``
            point samples spread over its area (a sensor integrates the light over the pixel;
            1: one sample at the pixel's centre, which puts every texture corner and face edge
            on the whole-pixel grid).
        exact_faces: a face covers the pixels (samples) whose centres it holds, not
            ``cv2.fillPoly``'s half-pixel-grown set (``render_layers``).
        seed: noise seed.
    """

    rate_deg_s: float = 10.2
    range_m: float = 2.0
    frame_rate_hz: float = 5.0
    frames: int | None = None
    tilt_deg: float = 20.0
    size_m: float = 1.0
    spin_axis_body: tuple[float, float, float] = (0.0, 0.0, 1.0)
    nutation_deg: float = 0.0
    precession_deg_s: float = 0.0
    sun_dir_cam: tuple[float, float, float] = (0.5, -0.6, -0.62)
    sun_rate_deg_s: float = 0.5
    sun_sweep_deg: float = 0.0
    blur: float = 0.0
    blur_step_px: float = 1.5
    blur_samples: int = 64
    glints: float = 0.0
    shininess: float = 1500.0
    glint_facet_deg: float = 45.0
    noise_sigma: float = 0.01
    defocus_px: float = 1.0
    ambient: float = 0.15
    pixel_samples: int = 1
    exact_faces: bool = False
    seed: int = 0

    def __post_init__(self):
        for name in ("range_m", "frame_rate_hz", "size_m", "shininess"):
            value = getattr(self, name)
            if not (is_finite_number(value) and value > 0):
                raise ValueError(f"{name} must be a positive number; got {value!r}")
        for name in ("glints", "noise_sigma", "defocus_px", "ambient", "glint_facet_deg"):
            value = getattr(self, name)
            if not (is_finite_number(value) and value >= 0):
                raise ValueError(f"{name} must be a number >= 0; got {value!r}")
        if self.glint_facet_deg > 90:
            raise ValueError(
                "glint_facet_deg must be at most 90 (a facet tilted further faces into the "
                f"blanket); got {self.glint_facet_deg!r}"
            )
        for name in (
            "rate_deg_s",
            "tilt_deg",
            "nutation_deg",
            "precession_deg_s",
            "sun_rate_deg_s",
            "sun_sweep_deg",
        ):
            value = getattr(self, name)
            if not is_finite_number(value):
                raise ValueError(f"{name} must be a finite number; got {value!r}")
        for name in ("spin_axis_body", "sun_dir_cam"):
            try:
                v = np.asarray(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                v = np.zeros(0)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or not np.any(v != 0):
                raise ValueError(f"{name} must be a non-zero 3-vector; got {getattr(self, name)!r}")
        if self.frames is not None and not (
            is_finite_number(self.frames) and int(self.frames) == self.frames and self.frames >= 2
        ):
            raise ValueError(
                f"frames must be an integer >= 2 (None: two turns); got {self.frames!r}"
            )
        if not self.blur >= 0:
            raise ValueError(f"blur must be >= 0 (exposure / frame interval); got {self.blur}")
        if not self.blur_step_px > 0:
            raise ValueError(f"blur_step_px must be positive; got {self.blur_step_px}")
        if int(self.blur_samples) != self.blur_samples or self.blur_samples < 1:
            raise ValueError(f"blur_samples must be a positive integer; got {self.blur_samples}")
        if int(self.pixel_samples) != self.pixel_samples or self.pixel_samples < 1:
            raise ValueError(f"pixel_samples must be a positive integer; got {self.pixel_samples}")

    def n_frames(self) -> int:
        if self.frames is not None:
            if self.frames < 2:
                raise ValueError(f"frames must be at least 2; got {self.frames}")
            return int(self.frames)
        if self.rate_deg_s <= 0:
            raise ValueError("with frames unset the rate must be positive (two turns are rendered)")
        return int(np.ceil(720.0 / self.rate_deg_s * self.frame_rate_hz)) + 1


@dataclass
class StereoFrame:
    """One rendered stereo pair and its ground truth (``pose``: target in the left camera, at the
    middle of the exposure; ``roi``: the target's box ``u0, v0, u1, v1`` in the left image, over
    the whole exposure when the frame is blurred)."""

    index: int
    time_s: float
    left: np.ndarray
    right: np.ndarray
    pose: Pose
    roi: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _align_to_z(axis) -> np.ndarray:
    """The smallest rotation taking the unit vector ``axis`` onto ``z`` (identity for ``z``)."""
    a = np.asarray(axis, float)
    n = np.linalg.norm(a)
    if not n > 0:
        raise ValueError(f"spin_axis_body must be a non-zero vector; got {axis}")
    a = a / n
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def scene_pose(scene: StereoScene, time_s: float) -> tuple[np.ndarray, np.ndarray]:
    """True ``(R, t)`` of the target in the left camera at ``time_s``.

    ``R(t) = R_view R_z(precession t) R_x(nutation) R_z(spin t) A``: ``A`` takes the body spin
    axis onto z, the body spins about it, the spin axis is tilted by the nutation angle and
    precesses about the rest direction, and ``R_view`` puts that direction along the image's up
    direction (camera -y), tilted by ``tilt_deg`` towards the camera so that the top face is
    visible. With the defaults (spin about body z, no nutation) ``R = R_view R_z(spin t)``.
    """
    base = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # body z -> camera -y
    R_view = _rot(0, np.radians(scene.tilt_deg)) @ base
    R = R_view @ _rot(2, np.radians(scene.rate_deg_s) * time_s)
    if scene.nutation_deg or scene.precession_deg_s:
        R = (
            R_view
            @ _rot(2, np.radians(scene.precession_deg_s) * time_s)
            @ _rot(0, np.radians(scene.nutation_deg))
            @ _rot(2, np.radians(scene.rate_deg_s) * time_s)
        )
    if tuple(scene.spin_axis_body) != (0.0, 0.0, 1.0):
        R = R @ _align_to_z(scene.spin_axis_body)
    return R, np.array([0.0, 0.0, scene.range_m])


def _pixel_rays(camera: PinholeCamera) -> np.ndarray:
    H, W = camera.height, camera.width
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    x = (uu - float(camera.cx)) / float(camera.fx)
    y = (vv - float(camera.cy)) / float(camera.fy)
    d = np.stack([x, y, np.ones_like(x)], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _glints(
    face_ids, rays, model, R, t, sun, strength, shininess, facet_deg=0.0, cell_m=_QUILT_CELL_M
):
    """Per-pixel Blinn-Phong lobe ``strength (n . h)^shininess`` on the faces (camera frame).

    ``facet_deg``: the body's faces (the blanket, faces 0-5) are quilted: each ``cell_m`` cell
    of the quilt (the texture's cells) is a flat facet tilted from its face by up to
    ``facet_deg`` in a random direction (``_hash01`` of the cell, the same in every frame), so
    the glints are the facets that mirror the Sun into the camera, scattered over the faces and
    moving with the view, as on crinkled multi-layer insulation. ``0``: flat faces (a lobe seen
    only where a whole face mirrors the Sun, within a few degrees)."""
    out = np.zeros(face_ids.shape, np.float32)
    sel = face_ids >= 0
    if not sel.any() or strength <= 0:
        return out
    n_cam = model.face_normals @ R.T
    ids = face_ids[sel]
    d = rays[sel]
    n = n_cam[ids]
    if facet_deg > 0:
        n = _faceted(n, ids, d, model, R, t, facet_deg, cell_m)
    h = sun[None, :] - d
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    out[sel] = strength * np.clip(np.einsum("ij,ij->i", n, h), 0, None) ** shininess
    return out


def _faceted(n, ids, rays, model, R, t, facet_deg, cell_m):
    """Normals ``(K, 3)`` (camera frame) of the quilt's facets hit by unit ``rays`` on faces
    ``ids`` (:func:`_glints`); the other faces keep their normals ``n``."""
    quilt = ids < 6
    if not quilt.any():
        return n
    n = n.copy()
    nq, dq, fq = n[quilt], rays[quilt], ids[quilt]
    x_cam = np.empty_like(dq)  # where each ray meets its face's plane
    for f in np.unique(fq):
        on = fq == f
        n_f = nq[on][0]  # the face's normal (camera frame)
        d_f = float(n_f @ (R @ model.vertices[model.faces[f][0]] + t))
        x_cam[on] = dq[on] * _face_depth_along_rays(n_f, d_f, dq[on])[:, None]
    cell = np.floor((x_cam - t) @ R / cell_m).astype(np.int64)
    # the coordinate across the face names the face instead: a face may lie on a cell boundary
    # (x = 0.25 m = 5 cells), where rounding would split its cells
    across = np.argmax(np.abs(model.face_normals[fq]), axis=1)
    cell[np.arange(len(cell)), across] = fq
    # two tangents of each face, then a tilt of up to facet_deg in a random direction
    helper = np.where(np.abs(nq[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(nq, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(nq, u)
    tilt = np.radians(facet_deg) * np.sqrt(_hash01(cell, 11))  # uniform over the tilt disc
    turn = 2.0 * np.pi * _hash01(cell, 23)
    m = np.cos(tilt)[:, None] * nq + np.sin(tilt)[:, None] * (
        np.cos(turn)[:, None] * u + np.sin(turn)[:, None] * v
    )
    n[quilt] = m
    return n


def _sampling_camera(camera: PinholeCamera, n: int) -> PinholeCamera:
    """The camera of ``n x n`` point samples per pixel of ``camera``: sample ``(n u + k, n v + l)``
    lies at ``(u - 1/2 + (k + 1/2) / n, v - 1/2 + (l + 1/2) / n)`` of ``camera``'s pixels, so
    the mean of each ``n x n`` block (:func:`_pixel_means`) is the pixel's area integral by the
    midpoint rule (``n = 1``: ``camera`` itself)."""
    if n == 1:
        return camera
    c = 0.5 * (n - 1)
    return PinholeCamera(
        n * camera.fx,
        n * camera.fy,
        n * camera.cx + c,
        n * camera.cy + c,
        camera.dist,
        width=n * camera.width,
        height=n * camera.height,
    )


def _pixel_means(samples: np.ndarray, n: int) -> np.ndarray:
    """``(n H, n W)`` samples to the ``(H, W)`` means of their ``n x n`` blocks."""
    if n == 1:
        return samples
    H, W = samples.shape[0] // n, samples.shape[1] // n
    return samples.reshape(H, n, W, n).mean(axis=(1, 3))


def _target_window(camera: PinholeCamera, model: WireframeModel, poses):
    """The image window ``(v0, v1, u0, u1)`` that holds the target at every pose ``(R, t)``
    (camera frame) and a camera that sees only it (the principal point moved by the window's
    corner): pixels outside it are background at every pose, so rendering the window alone
    gives the same pixels for less. The projected faces lie within their vertices' box for an
    ideal pinhole (a margin of 4 px plus 5 cm at the nearest vertex's depth covers the
    antennas' 1.5 cm width); with distortion, or a vertex behind the camera, the whole image."""
    H, W = camera.height, camera.width
    whole = (0, H, 0, W), camera
    if np.any(np.asarray(camera.dist) != 0):
        return whole
    pts = np.concatenate([model.vertices @ R.T + t for R, t in poses])
    if np.any(pts[:, 2] <= 1e-6):
        return whole
    pix = project_points(camera, pts)
    margin = 4 + int(np.ceil(float(camera.fx) * 0.05 / pts[:, 2].min()))
    u0, v0 = np.floor(pix.min(0)).astype(int) - margin
    u1, v1 = np.ceil(pix.max(0)).astype(int) + margin + 1
    u0, u1, v0, v1 = int(max(u0, 0)), int(min(u1, W)), int(max(v0, 0)), int(min(v1, H))
    if u1 - u0 < 2 or v1 - v0 < 2:
        return whole
    fx, fy, cx, cy = (float(v) for v in (camera.fx, camera.fy, camera.cx, camera.cy))
    view = PinholeCamera(fx, fy, cx - u0, cy - v0, width=u1 - u0, height=v1 - v0)
    return (v0, v1, u0, u1), view


def exposure_offsets(
    scene: StereoScene,
    rig: StereoCamera,
    time_s: float,
    *,
    model: WireframeModel | None = None,
    probes: int = 17,
) -> np.ndarray:
    """Time offsets (s, from ``time_s``) of the sub-frame renderings that make the motion blur.

    The exposure ``blur / frame_rate_hz`` is cut into ``n`` equal parts and each is rendered at
    its middle (the midpoint rule for the box-filter integral over the exposure), ``n`` the
    smallest count that keeps every model vertex within ``blur_step_px`` of its previous copy
    in the left image: ``n = ceil(L / blur_step_px)``, ``L`` the image path a vertex would
    cover over the exposure at its fastest (the largest displacement of any vertex between
    ``probes`` poses through the exposure, times ``probes - 1``), ``2 <= n <= blur_samples``.
    A face's points move no faster than the vertices that bound it (a rotation's speed grows
    with the distance from its axis; up to perspective in the image), so the copies of every
    edge and texture corner are at most about ``blur_step_px`` apart; after the defocus of 1 px
    (Gaussian sigma) a staircase of 1.5 px steps is a ramp (its slope ripples by 0.1%, 2 px
    steps by 3%), where 3 copies 5 px apart leave plateaus.

    Returns ``(n,)`` offsets; ``[0.0]`` without blur. Cost: one rendering of each camera per
    offset.
    """
    if scene.blur <= 0:
        return np.zeros(1)
    model = tumbler_model(scene.size_m) if model is None else model
    exposure = scene.blur / scene.frame_rate_hz
    pix = []
    for dt in np.linspace(-0.5, 0.5, max(int(probes), 2)) * exposure:
        R, t = scene_pose(scene, time_s + dt)
        pix.append(project_points(rig.left, model.vertices @ R.T + t))
    seg = np.linalg.norm(np.diff(np.stack(pix), axis=0), axis=-1)  # (probes - 1, V) pixels
    path = seg.max() * len(seg)
    n = int(np.clip(np.ceil(path / scene.blur_step_px), 2, scene.blur_samples))
    return ((np.arange(n) + 0.5) / n - 0.5) * exposure


def render_stereo_frame(
    scene: StereoScene,
    rig: StereoCamera,
    index: int,
    *,
    model: WireframeModel | None = None,
    textures: dict | None = None,
    rng: np.random.Generator | None = None,
    _rays: dict | None = None,
) -> StereoFrame:
    """Render frame ``index`` of ``scene`` with ``rig`` (both images) and its ground truth.

    The frame is drawn with the BLAS library (OpenBLAS) held to one thread: its worker threads
    otherwise keep spinning for about a tenth of a second after the ray cast's matrix product
    returns and take the cores of whatever runs next, a tracker fed frame by frame among them
    (on the 2-core machine they cost it about a fifth of its frame rate; the frame itself
    renders faster with one thread there, to the same bits).
    """
    with _one_blas_thread():
        return _render_stereo_frame(scene, rig, index, model, textures, rng, _rays)


_BLAS: list = []


def _one_blas_thread():
    """A context in which the BLAS library behind NumPy runs on one thread (threadpoolctl)."""
    if not _BLAS:
        from threadpoolctl import ThreadpoolController

        _BLAS.append(ThreadpoolController())
    return _BLAS[0].limit(limits=1, user_api="blas")


def _render_stereo_frame(scene, rig, index, model, textures, rng, _rays) -> StereoFrame:
    if rig.left.width <= 0 or rig.left.height <= 0:
        raise ValueError("the rig's cameras need an image size (width, height)")
    model = tumbler_model(scene.size_m) if model is None else model
    textures = tumbler_textures(model) if textures is None else textures
    rng = np.random.default_rng([scene.seed, index]) if rng is None else rng
    dt = 1.0 / scene.frame_rate_hz
    time_s = index * dt
    R_rl, t_rl = np.asarray(rig.R_rl), np.asarray(rig.t_rl)
    offsets = exposure_offsets(scene, rig, time_s, model=model)
    images, roi = [], np.full(4, np.nan)
    sun_axis_angle = np.radians(scene.sun_rate_deg_s) * time_s
    if scene.sun_sweep_deg:
        sun_axis_angle += np.radians(scene.sun_sweep_deg) * index / max(scene.n_frames() - 1, 1)
    sun = _rot(1, sun_axis_angle) @ np.asarray(scene.sun_dir_cam, float)
    sun /= np.linalg.norm(sun)
    rays_cache = {} if _rays is None else _rays
    sub_poses = [scene_pose(scene, time_s + off) for off in offsets]  # target in the left camera
    for cam_index, (camera, R_c, t_c) in enumerate(
        [(rig.left, np.eye(3), np.zeros(3)), (rig.right, R_rl, t_rl)]
    ):
        poses = [(R_c @ R, R_c @ t + t_c) for R, t in sub_poses]
        (v0, v1, u0, u1), view = _target_window(camera, model, poses)
        n_s = int(scene.pixel_samples)
        view = _sampling_camera(view, n_s)
        if scene.glints > 0 and n_s > 1:
            sample_rays = _pixel_rays(view)  # the window's samples, for every sub-frame
        sun_c = R_c @ sun
        acc = None
        for Rc, tc in poses:
            radiance, face_ids = render_layers(
                model,
                Pose(Rc, tc),
                view,
                sun_dir_cam=sun_c,
                ambient=scene.ambient,
                textures=textures,
                exact_faces=scene.exact_faces,
            )
            if scene.glints > 0:
                if n_s > 1:
                    rays = sample_rays
                else:
                    if cam_index not in rays_cache:
                        rays_cache[cam_index] = _pixel_rays(camera)
                    rays = rays_cache[cam_index][v0:v1, u0:u1]
                g = _glints(
                    face_ids,
                    rays,
                    model,
                    Rc,
                    tc,
                    sun_c,
                    scene.glints,
                    scene.shininess,
                    scene.glint_facet_deg,
                )
                radiance = np.where(np.isnan(radiance), radiance, radiance + g)
            radiance = _pixel_means(np.nan_to_num(radiance, nan=0.0), n_s)
            acc = radiance if acc is None else acc + radiance
            if cam_index == 0:
                vv, uu = np.nonzero(face_ids != BACKGROUND)
                vv, uu = vv // n_s, uu // n_s  # samples to pixels
                if len(uu):
                    box = np.array([uu.min(), vv.min(), uu.max(), vv.max()], float)
                    box += [u0, v0, u0, v0]  # the window's pixels to the image's
                    if not np.isnan(roi[0]):  # the union of the boxes over the exposure
                        box = np.r_[np.minimum(roi, box)[:2], np.maximum(roi, box)[2:]]
                    roi = box
        full = np.zeros((camera.height, camera.width), acc.dtype)
        full[v0:v1, u0:u1] = acc
        img = apply_sensor(
            full / len(offsets), rng, blur_sigma_px=scene.defocus_px, noise_sigma=scene.noise_sigma
        )
        images.append(img)
    R, t = scene_pose(scene, time_s)
    return StereoFrame(index, time_s, images[0], images[1], Pose(R, t), roi)


def render_sequence(scene: StereoScene, rig: StereoCamera | None = None, *, model=None):
    """Generator of the :class:`StereoFrame` of ``scene`` (``rig``: :func:`default_rig`)."""
    rig = default_rig() if rig is None else rig
    model = tumbler_model(scene.size_m) if model is None else model
    textures = tumbler_textures(model)
    rays: dict = {}
    for k in range(scene.n_frames()):
        yield render_stereo_frame(scene, rig, k, model=model, textures=textures, _rays=rays)
