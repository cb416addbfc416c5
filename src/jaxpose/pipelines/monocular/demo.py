"""The monocular part of ``jaxpose demo``: one rendered image, its pose and overlay."""

from __future__ import annotations

import cv2
import jax.numpy as jnp
import numpy as np

from jaxpose.core.camera import PinholeCamera
from jaxpose.core.geometry import Pose
from jaxpose.pipelines.monocular.options import _finite_or_none
from jaxpose.pipelines.monocular.pipeline import initialise_pose
from jaxpose.vision.models import tango
from jaxpose.vision.overlay import draw_overlay

__all__ = ["demo_report"]


def demo_report(out_dir) -> dict:
    """Render a Tango image (SPEED+-like camera, Earth background), initialise its pose, save the
    overlay in ``out_dir`` and return a few figures."""
    from pathlib import Path

    from jaxpose.core.metrics import esa_score, rotation_error, success
    from jaxpose.vision.render import render

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    camera = PinholeCamera(
        2988.6,
        2988.3,
        960.0,
        600.0,
        [-0.2238, 0.5141, -0.00066, -0.00021, -0.1312],
        width=1920,
        height=1200,
    )
    from jaxpose.core.geometry import euler_to_dcm

    pose = Pose(np.asarray(euler_to_dcm(jnp.array([2.3, 0.4, 0.6]))), np.array([0.15, -0.1, 6.0]))
    r = render(tango(), pose, camera, rng=7, earth=True)
    cv2.imwrite(str(out / "monocular_input.png"), r.image)
    res = initialise_pose(r.image, camera)
    cv2.imwrite(str(out / "monocular_overlay.png"), draw_overlay(r.image, res))
    report = {
        "confidence": res.confidence,
        "reprojection_error_px": _finite_or_none(res.reprojection_error_px),
        "range_true_m": float(np.linalg.norm(pose.t)),
        "coarse_range_m": None
        if res.coarse_t_cam is None
        else float(np.linalg.norm(res.coarse_t_cam)),
        "runtime_s": float(sum(res.timings.values())),
        "overlay": str(out / "monocular_overlay.png"),
    }
    if res.pose is not None:
        report["translation_error_m"] = float(np.linalg.norm(np.asarray(res.pose.t) - pose.t))
        report["rotation_error_deg"] = float(
            np.rad2deg(rotation_error(res.pose.R, jnp.asarray(pose.R)))
        )
        report["success"] = bool(success(res.pose, Pose(jnp.asarray(pose.R), jnp.asarray(pose.t))))
        report["esa_score"] = float(
            esa_score(res.pose, Pose(jnp.asarray(pose.R), jnp.asarray(pose.t)))[0]
        )
    return report
