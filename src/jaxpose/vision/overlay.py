"""Overlay of a monocular result on its image, with a legend."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["LEGEND", "draw_overlay"]

#: Colours (BGR) and legend entries of :func:`draw_overlay`, in drawing order.
LEGEND = (
    ("roi", (0, 255, 255), "region of interest"),
    ("silhouette", (0, 128, 255), "silhouette outline (dark sky only)"),
    ("segments", (0, 200, 0), "detected line segments"),
    ("antennas", (255, 255, 0), "detected antenna candidates"),
    ("group", (255, 0, 255), "segments of the winning feature group"),
    ("model", (0, 0, 255), "model edges projected at the returned pose"),
)


def draw_overlay(image: np.ndarray, result, model=None) -> np.ndarray:
    """Colour overlay ``(H + h, W, 3)`` uint8 on the undistorted image of ``result`` (an
    :class:`~jaxpose.pipelines.monocular.InitResult`): ROI, the silhouette's outline when there is
    one, detected segments and antenna candidates, the segments of the winning group, and the
    visible model edges projected at the returned pose (colours in :data:`LEGEND`). A legend strip
    of height ``h`` under the image names each colour and states the confidence and ``E2D``: the
    mean distance in pixels from the projected model's edge endpoints to their nearest detected
    endpoints (Sharma, Ventura, D'Amico 2018, eq. 22; endpoints farther than ``0.06 l_ROI`` do not
    count). ``model`` is accepted for compatibility and not used (the result holds the projected
    edges)."""
    colours = {k: c for k, c, _ in LEGEND}
    det = result.detection
    base = det.image if det.image is not None else np.asarray(image)
    img = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR) if base.ndim == 2 else base.copy()
    thick = max(1, int(round(max(img.shape) / 800)))

    def line(seg, colour, w=thick):
        a, b = (tuple(int(round(v)) for v in p) for p in seg)
        cv2.line(img, a, b, colour, w, cv2.LINE_AA)

    if result.roi is not None:
        u0, v0, u1, v1 = (int(round(v)) for v in result.roi)
        cv2.rectangle(img, (u0, v0), (u1, v1), colours["roi"], thick)
    if det.silhouette is not None:
        f = det.silhouette_factor
        contours, _ = cv2.findContours(det.silhouette, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        # mask cell c is centred on image pixel c f + (f - 1) / 2
        scaled = [np.rint(c * f + (f - 1) / 2).astype(np.int32) for c in contours]
        cv2.polylines(img, scaled, True, colours["silhouette"], thick, cv2.LINE_AA)
    ant = set(det.antennas.tolist())
    for i, seg in enumerate(det.segments):
        line(seg, colours["antennas"] if i in ant else colours["segments"])
    if result.used_segments is not None and result.group_kind != "ransac":
        for i in result.used_segments:
            if 0 <= i < len(det.segments):
                line(det.segments[i], colours["group"], 2 * thick)
    if result.projected is not None:
        for seg in result.projected:
            line(seg, colours["model"], thick)
    return np.vstack([img, _legend(result, img.shape[1], thick)])


def _legend(result, width: int, thick: int) -> np.ndarray:
    """The legend strip ``(h, width, 3)``: colour swatches and names, confidence and E2D."""
    e2d = result.reprojection_error_px
    e2d_txt = f"{e2d:.1f} px" if e2d is not None and np.isfinite(e2d) else "n/a"
    lines = [(None, f"confidence: {result.confidence}")]
    lines.append((None, f"E2D = {e2d_txt}: mean distance of the projected model's endpoints"))
    lines.append((None, "to the nearest detected endpoints (Sharma et al. 2018, eq. 22)"))
    lines += [(c, text) for _, c, text in LEGEND]
    scale = 0.45 * thick
    font = cv2.FONT_HERSHEY_SIMPLEX
    h = int(20 * thick)
    strip = np.full((h * len(lines) + 10 * thick, width, 3), 32, np.uint8)
    for k, (colour, text) in enumerate(lines):
        y = 5 * thick + h * k + h // 2
        x = 8 * thick
        if colour is not None:
            cv2.line(strip, (x, y), (x + 20 * thick, y), colour, 2 * thick, cv2.LINE_AA)
        cv2.putText(
            strip,
            text,
            (x + 28 * thick, y + 5 * thick),
            font,
            scale,
            (255, 255, 255),
            thick,
            cv2.LINE_AA,
        )
    return strip
