"""Builds notebooks/monocular.ipynb (a script: the notebook's source stays reviewable)."""

import nbformat as nbf

cells = []
md = lambda s: cells.append(nbf.v4.new_markdown_cell(s))  # noqa: E731
code = lambda s: cells.append(nbf.v4.new_code_cell(s))  # noqa: E731

md("""# The pose of a spacecraft from one image, with a confidence class

`jaxpose.initialise_pose` (after Sharma, Ventura, D'Amico 2018) finds the pose of a known target
in one image with no prior: it detects the target's region and straight edges, forms pose
hypotheses (EPnP on matched feature groups, and an attitude grid placed on the silhouette), scores
them in batches in JAX, refines the best and classes the answer `high`, `low`, `position-only` or
`none`. This notebook:

1. finds the pose of a rendered image of the Tango spacecraft and draws it;
2. looks inside: which stage held the right answer, and where the time went;
3. runs a small Monte Carlo over random poses: how often the answer is right, and what the
   confidence class says about it;
4. runs on real SPEED+ photographs when `JAXPOSE_SPEEDPLUS` points to the data set.

Set `JAXPOSE_NB_SMALL=1` to run at a small size (the test suite does). The first call compiles
for about 20 seconds; later calls take under a second an image.""")

code("""import os
import time

import jax

jax.config.update("jax_enable_x64", True)  # before any jaxpose import
import matplotlib.pyplot as plt
import numpy as np

import jaxpose as jp
from jaxpose.core.geometry import euler_to_dcm
from jaxpose.core.metrics import rotation_error
from jaxpose.pipelines.monocular import diagnose
from jaxpose.vision.models import tango
from jaxpose.vision.overlay import draw_overlay
from jaxpose.vision.render import random_pose, render

SMALL = os.environ.get("JAXPOSE_NB_SMALL") == "1"
model = tango()  # the built-in wireframe of Tango (PRISMA), from the SPEED keypoints""")

md("""## One image
The SPEED+ camera (1920 x 1200, 2988 px focal length, its lens distortion), the target 6 m away
over a rendered Earth. `x_cam = R @ x_body + t` is the pose convention everywhere.""")

code("""camera = jp.PinholeCamera(2988.6, 2988.3, 960.0, 600.0,
                          [-0.2238, 0.5141, -0.00066, -0.00021, -0.1312], width=1920, height=1200)
truth = jp.Pose(np.asarray(euler_to_dcm(np.array([2.3, 0.4, 0.6]))), np.array([0.15, -0.1, 6.0]))
image = render(model, truth, camera, rng=7, earth=True).image

t0 = time.perf_counter()
result = jp.initialise_pose(image, camera, options=jp.InitOptions(trace=True))
print(f"first call {time.perf_counter() - t0:.1f} s (with compilation)")
print("confidence:", result.confidence, "|", result.message)
if result.pose is not None:
    dt = np.linalg.norm(np.asarray(result.pose.t) - truth.t)
    dr = np.rad2deg(float(rotation_error(result.pose.R, truth.R)))
    print(f"error: {dt * 100:.1f} cm, {dr:.2f} deg")""")

code("""overlay = draw_overlay(image, result)
plt.figure(figsize=(10, 7))
plt.imshow(overlay[..., ::-1])  # OpenCV's BGR to RGB
plt.axis("off")
plt.title("detected edges, the winning feature group and the model at the returned pose");""")

md("""## Inside the pipeline
With `InitOptions(trace=True)` the result keeps the poses each stage held;
`diagnose.stage_breakdown` asks of each stage whether it held a pose within 10 degrees and
0.30 m of the truth (the success criterion). `result.timings` holds the seconds of each stage.""")

code("""stages = diagnose.stage_breakdown(result, truth, model)
for s in diagnose.STAGES:
    print(f"{s:18s} {stages[s]}")
print(f"ROI IoU with the true box: {stages['roi_iou']:.2f}; hypotheses: {stages.get('hypotheses')}")

again = jp.initialise_pose(image, camera)  # compiled now
names, secs = zip(*sorted(again.timings.items(), key=lambda kv: -kv[1]), strict=True)
plt.figure(figsize=(7, 3))
plt.barh(names, np.asarray(secs) * 1000)
plt.gca().invert_yaxis()
plt.xlabel("ms (second call)")
plt.title(f"time per stage, {sum(secs):.2f} s in all");""")

md("""## A small Monte Carlo: how often right, and what the class says
Random attitudes at 4-9 m, half over the Earth and half on a black sky. The class should mean
something: `high` answers should be right, and wrong answers should be `low`. (The project's own
evaluation, 200 renders and real photographs, is in the documentation; this is a quick look.)""")

code("""rng = np.random.default_rng(2018)
n = 2 if SMALL else 40
rows = []
for i in range(n):
    pose = random_pose(rng, camera, range_m=(4.0, 9.0))
    img = render(model, pose, camera, rng=rng, earth=bool(i % 2)).image
    res = jp.initialise_pose(img, camera)
    if res.pose is None:
        rows.append((float(pose.t[2]), np.nan, np.nan, res.confidence))
        continue
    dr = np.rad2deg(float(rotation_error(res.pose.R, pose.R)))
    dt = float(np.linalg.norm(np.asarray(res.pose.t) - pose.t))
    rows.append((float(pose.t[2]), dr, dt, res.confidence))

rng_m, rot, tra, conf = map(np.array, zip(*rows, strict=True))
right = (rot < 10) & (tra < 0.30)
for c in ("high", "low", "position-only", "none"):
    sel = conf == c
    if sel.any():
        print(f"{c:14s} {sel.sum():3d} answers, right: {int(right[sel].sum())}")
print(f"success {right.mean():.0%} of {n}")""")

code("""colours = {"high": "tab:green", "low": "tab:orange"}
plt.figure(figsize=(7, 4))
for c, col in colours.items():
    sel = conf == c
    plt.scatter(rng_m[sel], np.maximum(rot[sel], 0.01), color=col, label=c)
plt.axhline(10, color="grey", ls="--", lw=1, label="10 deg (success)")
plt.yscale("log")
plt.xlabel("range (m)")
plt.ylabel("attitude error (deg)")
plt.legend()
plt.title("rendered images: attitude error by confidence class");""")

md("""## Real photographs (SPEED+)
Point `JAXPOSE_SPEEDPLUS` at a SPEED+ root (`camera.json` and per domain `images/` with the label
JSON) or at a folder with `labels.csv`; `jaxpose eval-speedplus ROOT` is the full evaluation with
the 2021 competition's score. On real photographs the pipeline is right far less often than on
renders (the documentation's evaluation says where and why); the class tells which answers to
trust.""")

code("""from jaxpose.studies.speedplus import evaluate_speedplus

root = os.environ.get("JAXPOSE_SPEEDPLUS")
if root and os.path.isdir(root):
    report = evaluate_speedplus(root, limit=3 if SMALL else None, progress=not SMALL)
    for e in report["per_image"]:
        print(e["image"], e["confidence"], "right" if e["success"] else "wrong",
              e.get("rotation_error_deg"))
    print("success rate", report["success_rate"], "| ESA score", report["esa_score_mean"])
else:
    print("JAXPOSE_SPEEDPLUS is not set: skipped")""")

nb = nbf.v4.new_notebook()
nb["cells"] = cells
nb["metadata"]["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
nbf.write(nb, "monocular.ipynb")
