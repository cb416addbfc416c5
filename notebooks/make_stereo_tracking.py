"""Builds notebooks/stereo_tracking.ipynb (a script: the notebook's source stays reviewable)."""

import nbformat as nbf

cells = []
md = lambda s: cells.append(nbf.v4.new_markdown_cell(s))  # noqa: E731
code = lambda s: cells.append(nbf.v4.new_code_cell(s))  # noqa: E731

md("""# Tracking a tumbling target with a stereo camera: points, lines and a feature budget

`jaxpose.StereoTracker` (after Yang, Kang, Yuan, Qiu 2024) follows the pose of a tumbling,
non-cooperative target frame by frame: ORB points and LSD segments (LBD descriptors) matched
between the two images along the epipolar line (ZNCC), triangulated into a landmark map, and the
pose solved by Levenberg-Marquardt on the point and point-to-line reprojection errors. This
notebook:

1. renders a stereo video of a tumbling target and tracks it, with lines and with points only;
2. starts without ground truth (the first camera frame as the target frame);
3. solves each pose on a budget of 30 features chosen by their DOP (Ning et al. 2018) or at random.

Set `JAXPOSE_NB_SMALL=1` to run at a small size (the test suite does).""")

code("""import os

import jax

jax.config.update("jax_enable_x64", True)  # before any jaxpose import
import matplotlib.pyplot as plt
import numpy as np

from jaxpose.pipelines.stereo import TrackerOptions
from jaxpose.studies.stereo_track import summarize, track_sequence
from jaxpose.vision.stereo_render import StereoScene, default_rig, render_sequence

SMALL = os.environ.get("JAXPOSE_NB_SMALL") == "1"
frames = 6 if SMALL else 40""")

md("""## A rendered scene
A 1 m target 2.5 m away spinning at 12 degrees a second about an axis off its principal axes,
with 10 degrees of nutation, seen at 5 Hz with motion blur by a 1024 x 768 rig with a 0.3 m
baseline. The renderer returns rectified pairs and the true pose of each frame. The video is
rendered once and kept, so that every run below sees the same frames.""")

code("""scene = StereoScene(
    frames=frames, range_m=2.5, rate_deg_s=12.0, spin_axis_body=(0.3, 0.2, 1.0),
    nutation_deg=10.0, blur=0.5, seed=0,
)
rig = default_rig(1024, 768)
video = list(render_sequence(scene, rig))
fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
for a, img, name in zip(ax, (video[0].left, video[0].right), ("left", "right"), strict=True):
    a.imshow(img, cmap="gray")
    a.set_title(f"frame 0, {name}")
    a.axis("off")""")

md("""## Points and lines, points only
Errors are those of the paper's figures: the chaser's position in the target frame (mm, per
target axis) and the roll, pitch, yaw of the attitude error (degrees). The first pose is the
ground truth here; the next section starts without it. The first run's frame rate includes the
compilation of the tracker's solvers.""")

code("""runs = {}
for name, lines in (("points + lines", True), ("points only", False)):
    results, truths, seconds = track_sequence(video, rig, options=TrackerOptions(use_lines=lines))
    runs[name] = summarize(results, truths, seconds)
    s = runs[name]["summary"]
    print(f"{name:15s} RMS position {s['rms_position_mm']} mm,"
          f" attitude {s['rms_attitude_deg']} deg, lost {s['lost_frames']}, {s['fps']} fps")""")

code("""fig, ax = plt.subplots(2, 3, figsize=(13, 6), sharex=True)
for name, style in (("points + lines", "-"), ("points only", "--")):
    rows = runs[name]["rows"]
    k = [r["frame"] for r in rows]
    for j, a in enumerate("xyz"):
        ax[0, j].plot(k, [r[f"err_pos_{a}_mm"] for r in rows], style, label=name)
        ax[1, j].plot(k, [r[f"err_att_{a}_deg"] for r in rows], style, label=name)
for j, (p, q) in enumerate(zip("xyz", ("roll", "pitch", "yaw"), strict=True)):
    ax[0, j].set_title(f"chaser position error, {p} (mm)")
    ax[1, j].set_title(f"attitude error, {q} (deg)")
    ax[1, j].set_xlabel("frame")
ax[0, 0].legend()
fig.tight_layout()""")

md("""## Without ground truth
A user has no true first pose. `initial_pose=jp.Pose.identity()` (the command line's `--init
identity`) makes the first left camera frame the target frame; the poses then follow `T_k T_0^-1`
of the true ones, and `summarize` reports the errors after aligning the first frame. They are
close to those of the run started from the truth but not identical: the body frame (and so the
point about which the solver turns the pose, and the map's coordinates) is another, so the
iterations take other paths.""")

code("""import jaxpose as jp

results, truths, seconds = track_sequence(video, rig, initial_pose=jp.Pose.identity(),
                                          options=TrackerOptions(use_lines=True))
s = summarize(results, truths, seconds)["summary"]
print("identity start, aligned:", s["rms_position_mm"], "mm,", s["rms_attitude_deg"], "deg")
print("truth start:            ", runs["points + lines"]["summary"]["rms_position_mm"], "mm")""")

md("""## A budget of 30 features a frame
An onboard computer may not afford the pose solve on every match. `TrackerOptions(feature_budget=N,
budget_rule=...)` solves each frame's pose on `N` of the matched points and lines: `dop` keeps the
`N` whose information (Ning et al.'s blocks for points, Yang et al.'s endpoint-to-line distances
for lines) gives the lowest DOP, `random` draws them. The landmark map still uses every match.""")

code("""budget = {}
for rule in ("dop", "random"):
    opts = TrackerOptions(use_lines=True, feature_budget=30, budget_rule=rule)
    results, truths, seconds = track_sequence(video, rig, options=opts)
    budget[rule] = summarize(results, truths, seconds)["summary"]
budget["all features"] = runs["points + lines"]["summary"]

fig, ax = plt.subplots(1, 2, figsize=(11, 3.5))
width = 0.25
for i, (name, s) in enumerate(budget.items()):
    ax[0].bar(np.arange(3) + i * width, s["rms_position_mm"], width, label=name)
    ax[1].bar(np.arange(3) + i * width, s["rms_attitude_deg"], width, label=name)
for a, labels, unit in ((ax[0], "xyz", "mm"), (ax[1], ("roll", "pitch", "yaw"), "deg")):
    a.set_xticks(np.arange(3) + width, labels)
    a.set_ylabel(f"RMS error ({unit})")
ax[0].legend()
fig.suptitle(f"{frames} frames, pose solved on 30 features a frame");""")

md("""On the project's scene suite the three rules land within a few per cent of all features: the
error at this range comes mostly from the landmark map, which every rule shares, rather than
from the noise of one frame's features (see the stereo evaluation in the documentation).""")

nb = nbf.v4.new_notebook()
nb["cells"] = cells
nb["metadata"]["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
nbf.write(nb, "stereo_tracking.ipynb")
