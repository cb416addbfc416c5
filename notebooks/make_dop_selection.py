"""Builds notebooks/dop_selection.ipynb (a script, so that the notebook's source is reviewable)."""

import nbformat as nbf

cells = []
md = lambda s: cells.append(nbf.v4.new_markdown_cell(s))  # noqa: E731
code = lambda s: cells.append(nbf.v4.new_code_cell(s))  # noqa: E731

md("""# DOP and feature-point selection

A walk through `jaxpose.core.dilution` and `jaxpose.core.select`, after Ning, Zhang and Wang, *A
Non-Cooperative Satellite Feature Point Selection Method for Vision-Based Navigation System*,
Sensors 18(3):854, 2018.

* The **observation matrix** `H` (2n x 6) is the Jacobian of the pixels of `n` feature points with
  respect to the relative position `T` (m) and attitude Euler angles (rad), eq. 7.
* `Q = (H^T H)^-1` maps pixel noise into pose error (eq. 14); `PDOP = sqrt(tr Q_pp)`,
  `ADOP = sqrt(tr Q_aa)` (eq. 15).
* **Selection**: keep `m` of `n` points with a small DOP: the exhaustive optimum over all `C(n, m)`
  subsets, the quasi-optimal rule (remove the most redundant direction, Sec. 4), greedy backward
  elimination on the DOP itself, and an exact branch and bound.

Set `JAXPOSE_NB_SMALL=1` to run everything at a small size (the test suite does).""")

code("""import os
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import matplotlib.pyplot as plt

import jaxpose as jp
from jaxpose import select as sel

SMALL = os.environ.get("JAXPOSE_NB_SMALL") == "1"
rng = np.random.default_rng(1)""")

md("""## A scene
Sixteen features uniform in a 1 m x 1 m plane of the target, 10 m along the boresight, attitude
20 deg about each axis (jaxpose's default study scenario), a 50 mm lens with 5.5 um pixels.""")

code("""camera = jp.PinholeCamera.from_focal_length(0.05, 5.5e-6, (2048, 2048))
pose = jp.Pose.from_euler(np.deg2rad([20.0, 20.0, 20.0]), np.array([0.0, 0.0, 10.0]))
n = 16
points = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), np.zeros(n)]
pixels = np.asarray(camera.project(pose.apply(points)))

H = jp.observation_jacobian(points, pose, camera)
res = jp.dop(points, pose, camera)
print("H:", H.shape, " PDOP = %.3e m/px   ADOP = %.3e rad/px" % (res.pdop, res.adop))
print("1-sigma with 0.5 px noise: position %.1f mm, attitude %.3f deg"
      % (0.5 * res.pdop * 1e3, np.rad2deg(0.5 * res.adop)))
plt.figure(figsize=(4, 4))
plt.scatter(*pixels.T)
for i, (u, v) in enumerate(pixels):
    plt.annotate(str(i), (u, v), fontsize=8)
plt.gca().invert_yaxis(); plt.title("features in the image (px)"); plt.axis("equal");""")

md("""## How DOP moves with range and attitude
DOP is a pure function, so `vmap` sweeps a whole grid of geometries in one call.""")

code("""ranges = np.linspace(3.0, 30.0, 12 if SMALL else 40)
def pdop_at(r, deg):
    p = jp.Pose.from_euler(jnp.deg2rad(jnp.array([deg, deg, deg])), jnp.array([0.0, 0.0, r]))
    d = jp.dop(points, p, camera, throw=False)
    return d.pdop, d.adop
fig, ax = plt.subplots(1, 2, figsize=(10, 3.5))
for deg in (0.0, 20.0, 40.0):
    pd, ad = jax.vmap(lambda r: pdop_at(r, deg))(ranges)
    ax[0].plot(ranges, pd, label=f"{deg:g} deg"); ax[1].plot(ranges, ad, label=f"{deg:g} deg")
ax[0].set(xlabel="range (m)", ylabel="PDOP (m/px)", yscale="log")
ax[1].set(xlabel="range (m)", ylabel="ADOP (rad/px)", yscale="log")
ax[0].legend(); fig.tight_layout()""")

md("""PDOP grows roughly with the square of the range (depth is observed through the angular size of
the pattern), ADOP roughly linearly.

## Which feature matters? The gradient of PDOP
`jax.grad` of PDOP with respect to the feature positions says how moving each feature in the body
plane would change the precision; the arrows point downhill (better).""")

code("""grad = jax.grad(lambda p: jp.dop(p, pose, camera, throw=False).pdop)(jnp.asarray(points))
g = -np.asarray(grad)[:, :2]
plt.figure(figsize=(4.5, 4.5))
plt.scatter(points[:, 0], points[:, 1])
plt.quiver(points[:, 0], points[:, 1], g[:, 0], g[:, 1], color="C3")
plt.title("-dPDOP/dp (body plane)"); plt.axis("equal");""")

md("""Features are pushed outwards: a wider pattern fixes the pose better.

## Selecting 8 of 16 features""")

code("""m = 8
blocks = jp.information_blocks(points, pose, camera)
points_cam = np.asarray(pose.apply(points))
choices = {
    "quasi-optimal": np.asarray(sel.quasi_optimal(points_cam, m)),
    "one-step": np.asarray(sel.one_step(points_cam, m)),
    "greedy (PDOP)": np.asarray(sel.greedy(blocks, m, criterion="pdop")),
    "exhaustive (PDOP)": np.asarray(sel.exhaustive(blocks, m).pdop_idx),
    "branch and bound (PDOP)": np.asarray(sel.branch_and_bound(blocks, m, criterion="pdop").idx),
}
fig, axes = plt.subplots(1, len(choices), figsize=(3.2 * len(choices), 3.2))
for ax, (name, idx) in zip(axes, choices.items()):
    pd, ad = sel.subset_dop(blocks, jnp.asarray(idx))
    ax.scatter(*pixels.T, c="lightgray"); ax.scatter(*pixels[idx].T, c="C0")
    ax.set_title(f"{name}\\nPDOP {pd:.2e}", fontsize=9); ax.invert_yaxis()
    ax.set_xticks([]); ax.set_yticks([])
fig.tight_layout()""")

md("""The exhaustive search and branch and bound agree (branch and bound is exact); the
quasi-optimal rule needs no DOP evaluation at all and lands close.

## A small Monte Carlo study (the paper's Table 4)
`jaxpose.studies.selection.run_study` is what `jaxpose select-study` runs: cases in resumable
chunks, sharded over devices, `results.json` and figures.""")

code("""from jaxpose.studies.selection import Scenario, run_study, format_report
cases = 20 if SMALL else 300
study = run_study(Scenario(), [(12, 8), (16, 8)], cases=cases, progress=False)
print(format_report(study.results))
fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
for (n, m), c in study.cases.items():
    ax[0].hist(c["pdop_quasi"] / c["pdop_opt"], bins=20, alpha=0.6, label=f"n={n}")
    ax[1].hist(c["adop_quasi"] / c["adop_opt"], bins=20, alpha=0.6, label=f"n={n}")
ax[0].set_xlabel("PDOP ratio quasi/optimal"); ax[1].set_xlabel("ADOP ratio quasi/optimal")
ax[0].legend();""")

kernel = {"kernelspec": {"name": "python3", "display_name": "Python 3"}}
for i, cell in enumerate(cells):  # fixed ids: regenerating gives no diff
    cell["id"] = f"cell-{i:02d}"
nb = nbf.v4.new_notebook(cells=cells, metadata=kernel)
nbf.write(nb, "notebooks/dop_selection.ipynb")
