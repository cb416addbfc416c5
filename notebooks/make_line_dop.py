"""Builds notebooks/line_dop.ipynb (a script, so that the notebook's source is reviewable).

Run from the repository root: ``python notebooks/make_line_dop.py``.
"""

import nbformat as nbf

cells = []
md = lambda s: cells.append(nbf.v4.new_markdown_cell(s))  # noqa: E731
code = lambda s: cells.append(nbf.v4.new_code_cell(s))  # noqa: E731

md("""# DOP of points and lines together

Ning, Zhang and Wang (2018) measure the precision a set of feature *points* gives the pose by the
DOP: `Q = (H^T H)^-1`, `PDOP = sqrt(tr Q_pp)`, `ADOP = sqrt(tr Q_aa)` (eqs. 7, 14-15). The stereo
tracker of Yang et al. (2024) also observes straight edges: a 3-D segment with endpoints `P_1, P_2`
seen as the image line `l` contributes the two signed distances of its projected endpoints to that
line (eq. 9),

    d_k = (l_1 u_k + l_2 v_k + l_3) / sqrt(l_1^2 + l_2^2),   k = 1, 2.

`jaxpose.line_information_blocks` differentiates them (`jax.jacfwd`) in the same state
`(T, eps)` as the point blocks, so `A = sum_points A_i + sum_lines A_j` and every DOP-based
selection method takes a stack of both. Row `k` of a line's Jacobian is `n^T H_k`: the point
Jacobian of endpoint `k` seen only across the line (`n` its unit normal).

Set `JAXPOSE_NB_SMALL=1` to run everything at a small size (the test suite does).""")

code("""import os
from pathlib import Path
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import matplotlib.pyplot as plt

import jaxpose as jp
from jaxpose import select as sel

SMALL = os.environ.get("JAXPOSE_NB_SMALL") == "1"
FIGURES = Path("../docs/figures")  # figures for the docs when run from notebooks/
rng = np.random.default_rng(1)
camera = jp.PinholeCamera.from_focal_length(0.05, 5.5e-6, (2048, 2048))""")

md("""## What one line tells
The block of a segment has rank 2, like a point's, but it is blind to every motion that keeps the
3-D line on itself: sliding along it and rotating about it. A point on the line sees the slide.""")

code("""pose = jp.Pose.from_euler(np.deg2rad([20.0, 20.0, 20.0]), np.array([0.0, 0.0, 10.0]))
segment = np.array([[[-0.4, -0.2, 0.0], [0.4, 0.3, 0.0]]])
A_line = jp.line_information_blocks(segment, pose, camera, parameterization="tangent")[0]
A_mid = jp.information_blocks(segment.mean(1), pose, camera, parameterization="tangent")[0]
u = np.asarray(pose.R) @ (segment[0, 1] - segment[0, 0]); u /= np.linalg.norm(u)
slide = np.r_[u, 0, 0, 0]
rotate = np.r_[-np.cross(u, np.asarray(pose.R) @ segment[0, 0]), u]
rotate /= np.linalg.norm(rotate)
print("eigenvalues, line :", np.linalg.eigvalsh(A_line).round(1))
print("eigenvalues, point:", np.linalg.eigvalsh(A_mid).round(1))
for name, v in (("slide along the line", slide), ("rotate about the line", rotate)):
    print(f"{name:22s} |A_line v| = {np.linalg.norm(A_line @ v):.1e}"
          f"   |A_point v| = {np.linalg.norm(A_mid @ v):.1e}")""")

md("""## When is a line worth more than a point?
Start from four random points on a 1 m plate at 10 m (the minimum for a DOP; random attitude
within 20 deg per axis) and add **one** more feature, either a point or a segment of length `L`
centred on that point in a random direction of the plate. The ratio `DOP(base + line) /
DOP(base + point)` below 1 means the line is worth more. For reference, the two endpoints of the
segment added as *points* (four measurements instead of two). Every case is one `vmap` lane.""")

code("""C = 60 if SMALL else 1000
lengths = jnp.linspace(0.02, 1.0, 8 if SMALL else 25)
base = np.concatenate([rng.uniform(-0.5, 0.5, (C, 4, 2)), np.zeros((C, 4, 1))], -1)
centre = np.c_[rng.uniform(-0.5, 0.5, (C, 2)), np.zeros(C)]
theta = rng.uniform(0.0, np.pi, C)
direction = np.c_[np.cos(theta), np.sin(theta), np.zeros(C)]
angles = np.deg2rad(rng.uniform(-20.0, 20.0, (C, 3)))


def ratios(points, c, d, ang, L):
    pose = jp.Pose.from_euler(ang, jnp.array([0.0, 0.0, 10.0]))
    A0 = jnp.sum(jp.information_blocks(points, pose, camera), 0)
    seg = jnp.stack([c - 0.5 * L * d, c + 0.5 * L * d])
    point = jp.dop_from_information(A0 + jp.information_blocks(c[None], pose, camera)[0])
    line = jp.dop_from_information(A0 + jp.line_information_blocks(seg[None], pose, camera)[0])
    ends = jp.dop_from_information(A0 + jnp.sum(jp.information_blocks(seg, pose, camera), 0))
    return jnp.array([[line.pdop, ends.pdop], [line.adop, ends.adop]]) / jnp.array(
        [[point.pdop], [point.adop]])


sweep = jax.jit(jax.vmap(jax.vmap(ratios, (None, None, None, None, 0)), (0, 0, 0, 0, None)))
r = np.asarray(sweep(base, centre, direction, angles, lengths))  # (C, L, 2, 2)
fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
for ax, k, name in ((axes[0], 0, "PDOP"), (axes[1], 1, "ADOP")):
    for j, label in ((0, "one segment (2 distances)"), (1, "its two endpoints as points")):
        q = np.percentile(r[:, :, k, j], [25, 50, 75], axis=0)
        ax.plot(lengths, q[1], label=label, color=f"C{j}")
        ax.fill_between(lengths, q[0], q[2], alpha=0.2, color=f"C{j}")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set(xlabel="segment length L (m)", ylabel=f"{name} ratio to adding its midpoint",
           title=f"{name}: median and quartiles, {C} cases")
axes[0].legend(fontsize=8)
for k, name in ((0, "PDOP"), (1, "ADOP")):
    axes[2].plot(lengths, np.mean(r[:, :, k, 0] < 1.0, axis=0), label=name)
axes[2].set(xlabel="segment length L (m)", ylabel="fraction of cases", ylim=(0, 1),
            title="the segment beats the point")
axes[2].legend(); fig.tight_layout()
if FIGURES.is_dir() and not SMALL:
    fig.savefig(FIGURES / "line_dop_worth.png", dpi=120)
for k, name in ((0, "PDOP"), (1, "ADOP")):
    med = np.median(r[:, :, k, :], axis=0)
    wins = np.mean(r[:, :, k, 0] < 1.0, axis=0)
    for i in (0, -1):
        print(f"{name}, L = {lengths[i]:.2f} m: median ratio {med[i, 0]:.3f} (endpoints as "
              f"points {med[i, 1]:.3f}); the segment wins in {wins[i]:.0%} of the cases")""")

md("""A short segment is nearly a point measured twice across the line and never along it, and is
usually worth less than the point. As it grows, its endpoints' lever arm pins the attitude and,
for a target about as large as the segment, it wins in about half of the cases; which half
depends on the direction: a line tells nothing along itself, so it helps when its normal is the
direction the other features measure poorly. Two endpoint points always do better than the
segment (the line's two distances are a projection of their four coordinates), so a line is worth
more than a *point*, never more than its own two endpoints.""")

md("""### The direction matters
One base set of four points (20 deg per axis, 10 m), the added feature at the plate's centre:
the ratio over the segment's direction in the plate and its length (blue: the segment wins; the
black line is ratio 1).""")

code("""one_base = np.c_[np.random.default_rng(3).uniform(-0.5, 0.5, (4, 2)), np.zeros(4)]
angles_deg = np.linspace(0.0, 180.0, 25 if SMALL else 73)
grid = jax.vmap(lambda a: jax.vmap(lambda L: ratios(
    one_base, np.zeros(3), jnp.array([jnp.cos(a), jnp.sin(a), 0.0]), np.deg2rad([20.0] * 3), L))(
    lengths))(jnp.deg2rad(angles_deg))
grid = np.asarray(grid)[..., 0]  # (angle, L, criterion): the segment's ratio to the point
fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
for ax, k, name in ((axes[0], 0, "PDOP"), (axes[1], 1, "ADOP")):
    z = np.log2(grid[:, :, k])
    lim = np.abs(z).max()
    im = ax.pcolormesh(lengths, angles_deg, z, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax.contour(lengths, angles_deg, grid[:, :, k], levels=[1.0], colors="k")
    fig.colorbar(im, ax=ax, label="log2 ratio")
    ax.set(xlabel="segment length L (m)", ylabel="direction in the plate (deg)", title=name)
axes[2].scatter(*one_base[:, :2].T, label="base points")
axes[2].scatter(0.0, 0.0, marker="x", color="C3", label="added feature")
axes[2].set(xlim=(-0.5, 0.5), ylim=(-0.5, 0.5), aspect="equal", title="the plate (body frame, m)")
axes[2].legend(fontsize=8); fig.tight_layout()""")

md("""For this base set the direction decides PDOP (a segment in the band of directions between
the black lines wins at any length, one across it loses at any length), while the length
decides ADOP (beyond about 0.2 m the segment wins in every direction): the lever arm of the two
endpoints is what a line adds to the attitude.

## Selecting from points and lines together
Twelve points and six segments of a 1 m plate; branch and bound picks the 8 features of minimum
PDOP, and of minimum ADOP, from the stacked blocks (point blocks first, then line blocks).""")

code("""pose = jp.Pose.from_euler(np.deg2rad([15.0, -10.0, 20.0]), np.array([0.0, 0.0, 10.0]))
points = np.c_[rng.uniform(-0.5, 0.5, (12, 2)), np.zeros(12)]
mid = np.c_[rng.uniform(-0.3, 0.3, (6, 2)), np.zeros(6)]
phi = rng.uniform(0.0, np.pi, 6)
half = 0.5 * rng.uniform(0.1, 1.0, 6)[:, None] * np.c_[np.cos(phi), np.sin(phi), np.zeros(6)]
segments = np.stack([mid - half, mid + half], 1)
blocks = jnp.concatenate([jp.information_blocks(points, pose, camera),
                          jp.line_information_blocks(segments, pose, camera)])
m = 8
fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
for ax, criterion in zip(axes, ("pdop", "adop")):
    res = sel.branch_and_bound(blocks, m, criterion=criterion)
    idx = set(np.asarray(res.idx).tolist())
    pix = np.asarray(camera.project(pose.apply(points)))
    seg_pix = np.asarray(camera.project(pose.apply(segments.reshape(-1, 3)))).reshape(-1, 2, 2)
    ax.scatter(*pix.T, c=["C0" if i in idx else "lightgray" for i in range(12)], zorder=3)
    for j, s in enumerate(seg_pix):
        ax.plot(*s.T, color="C3" if 12 + j in idx else "lightgray", lw=2)
    chosen_lines = sum(i >= 12 for i in idx)
    only_points = sel.branch_and_bound(blocks[:12], m, criterion=criterion)
    print(f"min {criterion.upper()}: {chosen_lines} lines; {res.value:.4e} against "
          f"{only_points.value:.4e} with points only (ratio {res.value / only_points.value:.3f})")
    ax.set_title(f"min {criterion.upper()}: {chosen_lines} lines of {m}\\n"
                 f"{res.value:.2e} (points only: {only_points.value:.2e})", fontsize=9)
    ax.invert_yaxis(); ax.set_aspect("equal"); ax.set_xticks([]); ax.set_yticks([])
fig.tight_layout()
if FIGURES.is_dir() and not SMALL:
    fig.savefig(FIGURES / "line_dop_selection.png", dpi=120)""")

md("""The same stack works with `sel.greedy` and `sel.exhaustive`, and
`jp.dop_from_information(blocks[idx].sum(0))` gives the PDOP and ADOP of any mixed subset. The
quasi-optimal rule of Ning et al. is defined on points (lines of sight) and takes no lines.""")

kernel = {"kernelspec": {"name": "python3", "display_name": "Python 3"}}
for i, cell in enumerate(cells):  # fixed ids: regenerating gives no diff
    cell["id"] = f"cell-{i:02d}"
nb = nbf.v4.new_notebook(cells=cells, metadata=kernel)
nbf.write(nb, "notebooks/line_dop.ipynb")
