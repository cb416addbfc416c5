"""Synthetic renderer: geometry against the camera model, visibility, sensor effects, hooks."""

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import PinholeCamera, Pose
from jaxpose.core.geometry import euler_to_dcm
from jaxpose.vision.models import tango
from jaxpose.vision.render import (
    BACKGROUND,
    blanket_texture,
    lightbox_scene,
    project_points,
    random_pose,
    render,
    render_layers,
)


@pytest.fixture
def camera():
    return PinholeCamera(
        800.0, 800.0, 319.5, 239.5, [-0.1, 0.02, 0.001, -0.001, 0.0], width=640, height=480
    )


def front_pose(z=5.0):
    # Camera looks at the panel top (body +z towards the camera): rotate body 180 deg about x.
    return Pose(np.asarray(euler_to_dcm(jnp.array([np.pi, 0.0, 0.0]))), np.array([0.0, 0.0, z]))


def test_project_points_matches_camera(camera, rng):
    P = rng.normal(size=(50, 3)) + [0, 0, 6]
    np.testing.assert_allclose(
        project_points(camera, P), np.asarray(camera.project(jnp.asarray(P))), atol=1e-9
    )


def test_top_view_shows_panel_edges_only(camera):
    r = render(tango(), front_pose(), camera, rng=0, noise_sigma=0.0)
    assert r.image.shape == (480, 640) and r.image.dtype == np.uint8
    # Seen from +z the panel top hides the body: its four edges are visible, the body bottom not.
    ids = set(r.visible.edge_ids.tolist())
    assert {0, 1, 2, 3} <= ids
    assert not ids & {16, 17, 18, 19}  # body bottom ring
    # Visible endpoints are the projected panel corners.
    m = tango()
    corners = project_points(camera, np.asarray(front_pose().apply(jnp.asarray(m.vertices[:4]))))
    ends = r.visible.segments[np.isin(r.visible.edge_ids, [0, 1, 2, 3])].reshape(-1, 2)
    d = np.linalg.norm(ends[:, None] - corners[None], axis=-1).min(1)
    assert d.max() < 1.0
    # ROI of the buffer contains all corners.
    assert np.all(corners[:, 0] >= r.roi[0] - 1) and np.all(corners[:, 0] <= r.roi[2] + 1)


def _first_hit_depth(point_cam, model, R, t, skip=(), grow_m=0.0):
    """Brute-force ray casting, independent of the renderer's painter buffer: the smallest
    distance along the camera ray through ``point_cam`` at which it crosses a front-facing model
    face (convex polygon; back faces are culled, as the model format specifies) other than
    ``skip``, each polygon grown (``grow_m > 0``) or shrunk (``< 0``) by ``|grow_m|`` metres at
    its borders; ``inf`` when the ray crosses none."""
    d = point_cam / np.linalg.norm(point_cam)
    best = np.inf
    for k, face in enumerate(model.faces):
        if k in skip:
            continue
        V = model.vertices[list(face)] @ R.T + t
        n = np.cross(V[1] - V[0], V[2] - V[0])
        n /= np.linalg.norm(n)
        if (model.face_normals[k] @ R.T) @ V.mean(0) >= 0:  # back-facing
            continue
        den = n @ d
        if abs(den) < 1e-12:
            continue
        s = (n @ V[0]) / den
        if s <= 0:
            continue
        q = s * d
        edges = np.roll(V, -1, axis=0) - V
        # Signed distance (m, in the face's plane) of q from each border line, inside positive
        # for one orientation of the polygon.
        dist = np.einsum("ij,j->i", np.cross(edges, q - V), n) / np.linalg.norm(edges, axis=1)
        if min(dist) >= -grow_m or max(dist) <= grow_m:
            best = min(best, s)
    return best


def _two_plates(front_half: float):
    """A 0.4 m square plate at body z = 0 and a square plate of half-side ``front_half`` at
    z = 0.3, both facing +z (the camera looks down -z of the body, see ``front_pose``)."""
    from jaxpose.vision.models import WireframeModel

    def square(h, z):
        return [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]]

    V = np.array(square(0.2, 0.0) + square(front_half, 0.3))
    E = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4]]
    return WireframeModel(V, np.array(E), ((0, 1, 2, 3), (4, 5, 6, 7)), name="two plates")


def test_occlusion_hides_far_edges(camera, rng):
    # A large front plate hides every edge of the back plate; a small one hides none of them.
    for front_half, back_visible in ((0.5, set()), (0.05, {0, 1, 2, 3})):
        r = render(_two_plates(front_half), front_pose(4.0), camera, rng=0)
        assert set(r.visible.edge_ids.tolist()) == back_visible | {4, 5, 6, 7}
    # Tango at random poses against a ray caster, up to the renderer's pixel grid (polygons grown
    # by 1.5 px at the edge's depth): every edge that is front-facing and in view but reported
    # hidden is covered at its midpoint by a face nearer than the edge.
    m = tango()
    px = 1.5 / float(camera.fx)
    hidden_seen = 0
    for _ in range(8):
        pose = random_pose(rng, camera, range_m=(4, 8))
        r = render(m, pose, camera, rng=rng)
        R, t = np.asarray(pose.R), np.asarray(pose.t)
        front = np.einsum("fi,fi->f", m.face_normals @ R.T, m.face_centres @ R.T + t) < 0
        shown = set(r.visible.edge_ids.tolist())
        for e, (a, b) in enumerate(m.edges):
            mid = R @ (m.vertices[a] + m.vertices[b]) / 2 + t
            uv = np.asarray(camera.project(jnp.asarray(mid)))
            in_view = 5 < uv[0] < camera.width - 5 and 5 < uv[1] < camera.height - 5
            if e in shown or not in_view or not any(front[f] for f in m.edge_faces[e]):
                continue
            hit = _first_hit_depth(mid, m, R, t, m.edge_faces[e], px * mid[2])
            assert hit < np.linalg.norm(mid) - 1e-2, f"edge {e} hidden though nothing covers it"
            hidden_seen += 1
    assert hidden_seen > 0  # the random poses did exercise occlusion


@pytest.mark.xfail(
    strict=True,
    reason="painter's-algorithm ordering: where the solar panel overhangs the body, the body's "
    "top side edges are drawn over the panel and reported visible though the panel covers them "
    "(33 of 1923 visible samples in 10 of 40 random poses behind a nearer front face)",
)
def test_visible_edges_are_not_behind_a_face(camera, rng):
    """No point of a reported visible edge lies behind a front-facing face (ray casting, polygons
    shrunk by 1.5 px at the point's depth so that pixel rounding at borders does not count)."""
    m = tango()
    px = 1.5 / float(camera.fx)
    for _ in range(8):
        pose = random_pose(rng, camera, range_m=(4, 8))
        r = render(m, pose, camera, rng=rng)
        R, t = np.asarray(pose.R), np.asarray(pose.t)
        for e, body in zip(r.visible.edge_ids, r.visible.points_body, strict=True):
            if e >= len(m.edges):  # antennas have no faces of their own
                continue
            for s in (0.25, 0.5, 0.75):
                p_cam = R @ ((1 - s) * body[0] + s * body[1]) + t
                hit = _first_hit_depth(p_cam, m, R, t, m.edge_faces[e], -px * p_cam[2])
                assert hit >= np.linalg.norm(p_cam) - 5e-3, f"edge {e} visible behind a face"


def _occluded(points_cam, model, R, t):
    """Independent ray casting: is each camera-frame point behind a face of the model? A face
    (convex, planar) hides a point when the ray from the camera centre to it crosses the face's
    plane nearer than 0.999 of its depth and inside the face's polygon."""
    hidden = np.zeros(len(points_cam), bool)
    for face in model.faces:
        V = model.vertices[list(face)] @ R.T + t  # (k, 3)
        n = np.cross(V[1] - V[0], V[2] - V[0])
        denom = points_cam @ n
        s = (V[0] @ n) / np.where(np.abs(denom) > 1e-12, denom, np.nan)  # ray x = s * p
        X = s[:, None] * points_cam
        sides = np.stack(
            [np.cross(b - a, X - a) @ n for a, b in zip(V, np.roll(V, -1, axis=0), strict=True)]
        )
        inside = np.all(sides >= -1e-9, axis=0) | np.all(sides <= 1e-9, axis=0)
        hidden |= inside & (s > 0) & (s < 0.999)
    return hidden


def test_occlusion_hides_antennas_behind_the_body(camera):
    """Antennas behind the body are hidden, and only they: for poses where the body covers part
    of an antenna (found by an independent ray cast against the model's faces), the renderer's
    visible fraction of each antenna matches the ray-cast share of unoccluded samples."""
    m = tango()
    n_edges = len(m.edges)
    rng = np.random.default_rng(5)
    checked = occluded_seen = 0
    for _ in range(60):
        pose = random_pose(rng, camera, range_m=(4, 8))
        R, t = np.asarray(pose.R), np.asarray(pose.t)
        s = np.linspace(0.0, 1.0, 49)
        fractions = {}
        for a, (base, tip) in enumerate(m.antenna_points):
            pts = (base + s[:, None] * (tip - base)) @ R.T + t
            pix = project_points(camera, pts)
            on_image = np.all((pix >= 0) & (pix <= [639, 479]), axis=1)
            if not on_image.all():
                break
            fractions[n_edges + a] = 1.0 - _occluded(pts, m, R, t).mean()
        else:
            if min(fractions.values()) > 0.9:
                continue  # nothing occluded: not a test of occlusion
            r = render(m, pose, camera, rng=rng)
            got = dict(zip(r.visible.edge_ids.tolist(), r.visible.fraction.tolist(), strict=True))
            for e, expected in fractions.items():
                seen = got.get(e, 0.0)
                if expected < 0.05:
                    assert seen == 0.0  # wholly hidden: not reported
                elif expected > 0.95:
                    assert seen > 0.9
                else:  # partly hidden: the longest visible run is at most the visible share
                    assert seen <= expected + 0.05
                occluded_seen += expected < 0.5
            checked += 1
        if checked >= 4 and occluded_seen >= 2:
            break
    assert checked >= 4 and occluded_seen >= 2


def test_background_noise_blur_and_hooks(camera):
    m = tango()
    base = render(m, front_pose(), camera, rng=1, noise_sigma=0.0, blur_sigma_px=0.0)
    assert base.image[base.face_ids == BACKGROUND].max() == 0
    earth = render(m, front_pose(), camera, rng=1, earth=True)
    assert earth.image[earth.face_ids == BACKGROUND].mean() > 5
    # Per-face albedo hook: a brighter panel top.
    bright = render(
        m,
        front_pose(),
        camera,
        rng=1,
        noise_sigma=0.0,
        blur_sigma_px=0.0,
        textures=None,
        albedo=1.0,
    )
    dark = render(
        m,
        front_pose(),
        camera,
        rng=1,
        noise_sigma=0.0,
        blur_sigma_px=0.0,
        textures=None,
        albedo=0.2,
    )
    sel = bright.face_ids == 0
    assert bright.image[sel].mean() > 2 * dark.image[sel].mean()
    # Texture hook gets body-frame points on the face.
    seen = []

    def tex(points_body):
        seen.append(points_body)
        return np.full(len(points_body), 0.5)

    render_layers(m, front_pose(), camera, textures={0: tex})
    np.testing.assert_allclose(seen[0][:, 2], 0.3215, atol=1e-6)


def test_bad_pose_raises(camera):
    with pytest.raises(ValueError, match="in front"):
        render(tango(), Pose(np.eye(3), np.array([0.0, 0.0, -3.0])), camera)


def test_lightbox_scene_background_noise_and_blanket(camera):
    m = tango()
    rng = np.random.default_rng(3)
    opts = lightbox_scene(m, rng)
    r = render(m, front_pose(4.0), camera, rng=rng, **opts)
    bg = r.image[r.face_ids == BACKGROUND].astype(float)
    # grey background of 25-40 grey levels with sensor noise of 6-8 grey levels (sigma)
    assert 22 < bg.mean() < 43 and 4.5 < bg.std() < 9.5
    # a flat-faced render of the same pose has no texture: the blanket only adds variance
    V = m.vertices
    tex = blanket_texture(V[list(m.faces[7])], np.random.default_rng(0), albedo=0.5)
    pts = V[list(m.faces[7])].mean(0) + np.linspace(-0.1, 0.1, 400)[:, None] * (V[15] - V[4])
    vals = tex(pts)
    assert vals.min() < 0.45 < 0.55 < vals.max()  # dark folds and bright glints on the face
    with pytest.raises(ValueError, match="face_vertices"):
        blanket_texture(np.zeros((2, 3)), rng)
    with pytest.raises(ValueError, match="exclusive"):
        render(m, front_pose(), camera, rng=0, earth=True, background_level=0.1)


def test_lightbox_scene_earth_option(camera):
    m = tango()
    plain = lightbox_scene(m, np.random.default_rng(5))
    shape = (camera.height, camera.width)
    for cover in ("partial", "full"):
        opts = lightbox_scene(m, np.random.default_rng(5), earth=cover, shape=shape)
        # the options without the Earth are drawn first: the same for the same generator state
        for key in ("exposure", "ambient", "noise_sigma", "blur_sigma_px"):
            assert opts[key] == plain[key]
        np.testing.assert_array_equal(opts["sun_dir_cam"], plain["sun_dir_cam"])
        assert "background_level" not in opts
        bg = opts["background"]
        assert bg.shape == shape
        sky = np.isclose(bg, plain["background_level"], rtol=1e-5)
        if cover == "partial":  # grey lab background beyond the limb, the Earth on the rest
            assert 0.2 < sky.mean() < 0.95
        # bright clouds: well above the lab background somewhere
        assert bg.max() * opts["exposure"] > 0.3
        r = render(m, front_pose(4.0), camera, rng=np.random.default_rng(1), **opts)
        assert r.image.shape == shape and np.isfinite(r.roi).all()
    with pytest.raises(ValueError, match="earth"):
        lightbox_scene(m, np.random.default_rng(5), earth="half", shape=shape)
    with pytest.raises(ValueError, match="shape"):
        lightbox_scene(m, np.random.default_rng(5), earth="full")
    with pytest.raises(ValueError, match="exclusive"):
        render(m, front_pose(), camera, rng=0, background=np.zeros(shape), background_level=0.1)
    with pytest.raises(ValueError, match="shape"):
        render(m, front_pose(), camera, rng=0, background=np.zeros((3, 3)))


def test_lightbox_scene_cell_grid_option(camera):
    m = tango()
    pose = front_pose(4.0)

    def image(grid):
        rng = np.random.default_rng(11)
        opts = lightbox_scene(m, rng) if grid == "off" else lightbox_scene(m, rng, cell_grid=grid)
        return render(m, pose, camera, rng=rng, **opts)

    off = image("off")
    # the documented default grid (8 x 10 cells, gaps 0.2) is what renders without the option
    np.testing.assert_array_equal(off.image, image((8, 10, 0.2)).image)
    # bright gaps on the panel's top (face 0) raise its radiance; nothing else changes
    bright = image((12, 14, 0.6))
    panel = off.face_ids == 0
    assert panel.sum() > 1000
    assert bright.image[panel].mean() > off.image[panel].mean() + 5
    # away from the panel (beyond the sensor blur's reach) the images are the same
    near = cv2.dilate(panel.astype(np.uint8), np.ones((21, 21), np.uint8)) > 0
    np.testing.assert_array_equal(bright.image[~near], off.image[~near])
    with pytest.raises(ValueError, match="cell_grid"):
        lightbox_scene(m, np.random.default_rng(0), cell_grid=(0, 4, 0.5))


def test_textured_faces_outside_the_image_render(camera):
    # a lightbox scene (blanket-textured faces) whose target lies beside the image: the faces
    # in front of the camera cover no pixel; the image is all background, no error
    m = tango()
    rng = np.random.default_rng(5)
    opts = lightbox_scene(m, rng)
    pose = Pose(front_pose(4.0).R, np.array([12.0, 0.0, 4.0]))
    r = render(m, pose, camera, rng=rng, **opts)
    assert r.image.shape == (480, 640)
    assert np.all(r.face_ids == BACKGROUND)


def test_exact_face_fill_holds_the_pixel_centres_inside_the_polygon():
    """``_centres_inside`` against OpenCV's ``pointPolygonTest`` at every pixel centre, for a
    convex and a concave polygon; ``cv2.fillPoly`` (the default fill) holds more."""
    import cv2

    from jaxpose.vision.render import _centres_inside

    rng = np.random.default_rng(3)
    convex = np.array([[10.3, 12.6], [40.7, 9.2], [47.4, 30.5], [15.1, 38.8]])
    concave = np.array([[5.5, 5.2], [44.6, 6.3], [25.3, 20.7], [42.2, 41.4], [6.8, 39.9]])
    for poly in (convex, concave, convex + rng.uniform(-0.5, 0.5, convex.shape)):
        mask = _centres_inside(poly, (48, 52))
        vv, uu = np.mgrid[0:48, 0:52]
        ref = np.array(
            [
                cv2.pointPolygonTest(poly.astype(np.float32), (float(u), float(v)), False) > 0
                for u, v in zip(uu.ravel(), vv.ravel(), strict=True)
            ]
        ).reshape(48, 52)
        assert np.array_equal(mask, ref)
        grown = np.zeros((48, 52), np.uint8)
        cv2.fillPoly(grown, [np.rint(poly * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
        assert grown.sum() > mask.sum() and not (mask & ~grown.astype(bool)).any()
