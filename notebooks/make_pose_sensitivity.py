"""Builds notebooks/pose_sensitivity.ipynb (a script: the notebook's source stays reviewable)."""

import nbformat as nbf

cells = []
md = lambda s: cells.append(nbf.v4.new_markdown_cell(s))  # noqa: E731
code = lambda s: cells.append(nbf.v4.new_code_cell(s))  # noqa: E731

md("""# How sensitive is a refined pose? Implicit differentiation through the solve

`jaxpose.refine_pose` minimises the reprojection error over the pose. Its optimum `xi*(theta)`
depends on everything the problem is made of, `theta`: the measured pixels, the 3-D model points
and the camera intrinsics. At the optimum the gradient of the cost vanishes, so by the implicit
function theorem

    d xi* / d theta = -(d^2 C / d xi^2)^-1  d^2 C / (d xi d theta),

with no differentiation through the iterations. `jaxpose.sensitivity(...)` returns these
Jacobians (pose in the tangent coordinates of `pose_covariance`: `dt` in metres, `dw` a small
camera-frame rotation in radians), and the same rule makes `jax.grad` / `jax.jacfwd` work through
`refine_pose` itself.

Questions answered below:
1. how much does the pose move for a focal-length error (a calibration error)?
2. which feature's position matters most?

Set `JAXPOSE_NB_SMALL=1` to run at a small size (the test suite does).""")

code("""import os
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import matplotlib.pyplot as plt

import jaxpose as jp
from jaxpose.core.geometry import so3_log

SMALL = os.environ.get("JAXPOSE_NB_SMALL") == "1"
rng = np.random.default_rng(3)""")

md("""## A scene
Twenty features in a 1 m cube, 5 m away, a 1000 px focal length, 0.5 px pixel noise.""")

code("""camera = jp.PinholeCamera(1000.0, 1000.0, 511.5, 511.5)
truth = jp.Pose.from_euler(np.deg2rad([20.0, -15.0, 30.0]), np.array([0.2, -0.1, 5.0]))
n = 20
points = rng.uniform(-0.5, 0.5, (n, 3))
pixels = np.asarray(camera.project(truth.apply(points))) + 0.5 * rng.normal(size=(n, 2))

tight = jp.RefineOptions(rtol=1e-13, atol=1e-15)
res = jp.refine_pose(points, pixels, truth, camera, sigma=0.5, options=tight)
print("status", jp.Status(int(res.status)).name, " rms %.3f px" % res.rms_px,
      " steps", int(res.num_steps))
sens = jp.sensitivity(points, pixels, res, camera, sigma=0.5)
print("d pose / d(fx, fy, cx, cy)  [rows tx ty tz (m/px), wx wy wz (rad/px)]")
print(np.array2string(np.asarray(sens.d_intrinsics), precision=6, suppress_small=True))""")

md("""## 1. A focal-length error

Solve again with a camera whose `fx` and `fy` are off by `df` and compare the change of the
refined pose with the first-order prediction `(d xi/d fx + d xi/d fy) df`. The range `tz` scales
with the focal length (`dz/df ~ z/f`), the attitude hardly moves.""")

code("""def tangent(a, b):
    return np.concatenate([np.asarray(a.t - b.t), np.asarray(so3_log(a.R @ b.R.T))])

errors = np.linspace(-0.02, 0.02, 5 if SMALL else 9) * 1000.0   # focal errors in px (+-2 %)
solve = jax.jit(lambda cam: jp.refine_pose(points, pixels, res.pose, cam, sigma=0.5,
                                           options=tight).pose)
actual = []
for df in errors:
    cam = jp.PinholeCamera(camera.fx + df, camera.fy + df, camera.cx, camera.cy)
    actual.append(tangent(solve(cam), res.pose))
actual = np.array(actual)
slope = np.asarray(sens.d_intrinsics[:, 0] + sens.d_intrinsics[:, 1])

fig, ax = plt.subplots(1, 2, figsize=(10, 3.4))
ax[0].plot(errors, actual[:, 2] * 1e3, "o", label="re-solved")
ax[0].plot(errors, slope[2] * errors * 1e3, "-", label="implicit derivative")
ax[0].set_xlabel("focal-length error (px)"); ax[0].set_ylabel("tz change (mm)"); ax[0].legend()
for i, name in zip(range(3, 6), ("wx", "wy", "wz")):
    ax[1].plot(errors, np.rad2deg(actual[:, i]) * 1e3, "o", label=f"{name} re-solved")
    ax[1].plot(errors, np.rad2deg(slope[i] * errors) * 1e3, "-")
ax[1].set_xlabel("focal-length error (px)"); ax[1].set_ylabel("attitude change (mdeg)")
ax[1].legend()
fig.tight_layout()
print("tz per 1 px of focal error: %.3f mm (z/f = %.3f mm)"
      % (slope[2] * 1e3, 5.0 / 1000 * 1e3))""")

md("""## 2. Which feature matters most?

`sens.d_pixels[:, i, :]` is how the pose moves per pixel of feature `i`. Its norm, split into
position (mm/px) and attitude (mdeg/px), ranks the features: the ones at the edge of the
object's image and at extreme depths pull hardest. A detection error of `e` pixels on feature `i`
moves the pose by about `d_pixels[:, i, :] @ e`.""")

code("""dpos = np.linalg.norm(np.asarray(sens.d_pixels[:3]), axis=(0, 2)) * 1e3        # mm / px
datt = np.rad2deg(np.linalg.norm(np.asarray(sens.d_pixels[3:]), axis=(0, 2))) * 1e3  # mdeg / px
order = np.argsort(-dpos)
print("most influential features (position):", order[:5].tolist())

fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
sc = ax[0].scatter(pixels[:, 0], pixels[:, 1], c=dpos, s=30 + 300 * datt / datt.max(),
                   cmap="viridis")
ax[0].invert_yaxis(); ax[0].set_aspect("equal")
ax[0].set_title("feature influence (colour: mm/px, size: mdeg/px)")
fig.colorbar(sc, ax=ax[0])
ax[1].bar(np.arange(n), dpos[order])
ax[1].set_xticks(np.arange(n), order, fontsize=7)
ax[1].set_xlabel("feature"); ax[1].set_ylabel("|d position / d pixel| (mm/px)")
fig.tight_layout()""")

md("""Check one entry against finite differences: move the most influential feature by 0.05 px
along `u` and re-solve.""")

code("""i = int(order[0])
h = 0.05
moved = pixels.copy(); moved[i, 0] += h
p_new = jp.refine_pose(points, moved, res.pose, camera, sigma=0.5, options=tight).pose
fd = tangent(p_new, res.pose) / h
print("finite difference :", np.array2string(fd, precision=7))
print("implicit derivative:", np.array2string(np.asarray(sens.d_pixels[:, i, 0]), precision=7))""")

md("""## `jax.grad` through `refine_pose`

The same implicit rule is attached to `refine_pose`, so any scalar of the refined pose can be
differentiated with respect to any input, here the range with respect to the focal length and
to all model points at once.""")

code("""def range_of(cam, pts):
    return jp.refine_pose(pts, pixels, res.pose, cam, sigma=0.5, options=tight).pose.t[2]

g_cam, g_pts = jax.grad(range_of, argnums=(0, 1))(camera, jnp.asarray(points))
print("d tz / d fx = %.4e m/px (sensitivity: %.4e)" % (g_cam.fx, sens.d_intrinsics[2, 0]))
print("max |d tz / d points - sensitivity| =",
      float(jnp.max(jnp.abs(g_pts - sens.d_points_body[2]))))""")

kernel = {"kernelspec": {"name": "python3", "display_name": "Python 3"}}
for i, cell in enumerate(cells):  # fixed ids: regenerating gives no diff
    cell["id"] = f"cell-{i:02d}"
nb = nbf.v4.new_notebook(cells=cells, metadata=kernel)
nbf.write(nb, "notebooks/pose_sensitivity.ipynb")
