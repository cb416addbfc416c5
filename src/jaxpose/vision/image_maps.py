"""Image-side maps that the monocular scores read: the distance map and samples of the detected
segments, area-averaged grey-level cells over the ROI (region term), silhouette cells
(silhouette term) and the thin-rod response (antenna term). NumPy and OpenCV; the pipeline
hands the arrays to the pure-JAX scores."""

from __future__ import annotations

import cv2
import numpy as np

from jaxpose.vision.roi import roi_diagonal

__all__ = [
    "REGION_GRID",
    "REGION_MARGIN",
    "SILHOUETTE_GRID",
    "SILHOUETTE_MARGIN",
    "ORIENTATION_BINS",
    "distance_map",
    "orientation_maps",
    "region_grid",
    "roi_cells",
    "rod_map",
    "segment_samples",
    "SHADING_GRID",
    "shading_grid",
    "silhouette_grid",
    "texture_maps",
]


#: Region term (``pipelines.monocular.score._region_energy``): a ``REGION_GRID x REGION_GRID``
#: grid of cells over the ROI grown by ``REGION_MARGIN`` of its size on every side; each cell's
#: value is its mean grey level (area averaging: noise averaged over the cell, thin creases
#: smeared). Chosen, not tuned.
REGION_GRID = 32
REGION_MARGIN = 0.1

#: Silhouette term (``pipelines.monocular.score._silhouette_term``): a
#: ``SILHOUETTE_GRID x SILHOUETTE_GRID`` grid of cells over the ROI grown by
#: ``SILHOUETTE_MARGIN`` of its size on every side (wider than the region grid's: a pose whose
#: projection spills far beyond the silhouette must pay for it). Chosen, not tuned.
SILHOUETTE_GRID = 32
SILHOUETTE_MARGIN = 0.25

#: Rod detector of :func:`rod_map`: the ROI grown by this share of its size, area-shrunk so its
#: longer side is at most ``ROD_SIDE`` pixels; top-hat kernel ``ROD_KERNEL x l_ROI`` (about six
#: antenna diameters: 15 mm against an effective length of 1.46 m for Tango), response dilated
#: by ``0.01 l_ROI`` (about one diameter: a fitted pose is a few pixels off). Chosen, not tuned.
ROD_GROW = 0.3
ROD_SIDE = 256
ROD_KERNEL = 0.06


def roi_cells(image, roi, grid, margin, *, factor=1, min_cells=2, fill=None):
    """Area-averaged ``grid x grid`` cells over ``roi`` (pixels of the undistorted image) grown
    by ``margin`` of its size on every side, read from ``image`` sampled at ``1 / factor`` of
    that resolution (image pixel ``p`` lies in cell ``(p + 0.5) / factor - 0.5``); the crop spans
    at least ``min_cells`` image cells a side. Where the grown ROI leaves the image, its edge is
    replicated (``fill=None``) or ``fill`` is used. Returns the cell centres ``(G^2, 2)`` in
    image pixels and the cell means ``(G^2,)`` (NumPy float64)."""
    u0, v0, u1, v1 = (float(x) for x in roi)
    mu, mv = margin * (u1 - u0), margin * (v1 - v0)
    f = float(factor)
    a = np.floor([(u0 - mu) / f, (v0 - mv) / f]).astype(int)
    b = np.ceil([(u1 + mu) / f, (v1 + mv) / f]).astype(int) + 1
    b = np.maximum(b, a + min_cells)
    H, W = image.shape
    pad = (max(-a[1], 0), max(b[1] - H, 0), max(-a[0], 0), max(b[0] - W, 0))
    if fill is None:
        img = cv2.copyMakeBorder(image.astype(np.float32), *pad, cv2.BORDER_REPLICATE)
    else:
        img = cv2.copyMakeBorder(image.astype(np.float32), *pad, cv2.BORDER_CONSTANT, value=fill)
    crop = img[a[1] + pad[0] : b[1] + pad[0], a[0] + pad[2] : b[0] + pad[2]]
    cells = cv2.resize(crop, (grid, grid), interpolation=cv2.INTER_AREA)
    s = (np.arange(grid) + 0.5) / grid
    # image cell c covers image pixels [c f - 0.5, (c + 1) f - 0.5)
    uu, vv = np.meshgrid(
        f * a[0] - 0.5 + f * s * (b[0] - a[0]), f * a[1] - 0.5 + f * s * (b[1] - a[1])
    )
    return np.stack([uu.ravel(), vv.ravel()], 1), cells.ravel().astype(np.float64)


def region_grid(image: np.ndarray, roi) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres ``(G^2, 2)`` and cell mean grey levels ``(G^2,)`` over the grown ROI (the
    image edge replicated where the grown ROI leaves the image)."""
    pts, val = roi_cells(image, roi, REGION_GRID, REGION_MARGIN, min_cells=REGION_GRID)
    return pts, val


#: Face-shading term (``pipelines.monocular.score._face_spread``): a ``SHADING_GRID x
#: SHADING_GRID`` grid of cells over the ROI grown by ``REGION_MARGIN`` (finer than the region
#: grid: a face must keep cells once its border is left out). Chosen, not tuned.
SHADING_GRID = 48


def shading_grid(image: np.ndarray, roi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres ``(G^2, 2)``, cell mean grey levels ``(G^2,)`` and cell mean *squared* grey
    levels ``(G^2,)`` over the grown ROI (``G = SHADING_GRID``; grey levels over the crop's
    99th percentile, so that the two moments keep the spread of the texture inside each cell)."""
    u0, v0, u1, v1 = (float(x) for x in roi)
    mu, mv = REGION_MARGIN * (u1 - u0) + 2.0, REGION_MARGIN * (v1 - v0) + 2.0
    H, W = image.shape
    a0, b0 = int(min(max(np.floor(u0 - mu), 0), W - 1)), int(min(max(np.floor(v0 - mv), 0), H - 1))
    a1, b1 = int(max(np.ceil(u1 + mu) + 1, a0 + 1)), int(max(np.ceil(v1 + mv) + 1, b0 + 1))
    # the crop that roi_cells reads (the replicated border outside the image is the same)
    crop = image[b0:b1, a0:a1].astype(np.float32)
    sub = np.asarray(roi, float) - [a0, b0, a0, b0]
    pts, val = roi_cells(crop, sub, SHADING_GRID, REGION_MARGIN, min_cells=SHADING_GRID)
    _, sq = roi_cells(crop * crop, sub, SHADING_GRID, REGION_MARGIN, min_cells=SHADING_GRID)
    pts = pts + [a0, b0]
    top = max(float(np.percentile(val, 99.0)), 1e-6)
    return pts, val / top, sq / (top * top)


def silhouette_grid(mask: np.ndarray, factor: int, roi) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres ``(G^2, 2)`` (pixels of the undistorted image) and the share of each cell
    inside the silhouette ``(G^2,)`` in ``[0, 1]`` (area averaging of the mask, sampled at
    ``1 / factor``; outside the image, 0), over the ROI grown by ``SILHOUETTE_MARGIN``."""
    pts, val = roi_cells(mask, roi, SILHOUETTE_GRID, SILHOUETTE_MARGIN, factor=factor, fill=0.0)
    return pts, np.clip(val, 0.0, 1.0)


def rod_map(image: np.ndarray, roi) -> tuple[np.ndarray, np.ndarray]:
    """Thin-rod response around the ROI: ``(map (S, S) in [0, 1], [u0, v0, scale])``.

    The white top-hat plus the black top-hat of the area-shrunk crop (a structure thinner than the
    kernel, brighter or darker than what surrounds it: an antenna against space, a face or the
    Earth; faces and their edges give almost nothing), dilated, divided by its 99.5th percentile
    and clipped. A pixel ``(u, v)`` of the image is cell ``((u, v) - origin) * scale`` of the map
    (zero-padded to one shape, so one compilation serves every image)."""
    u0, v0, u1, v1 = (float(x) for x in roi)
    H, W = image.shape
    g = ROD_GROW * max(u1 - u0, v1 - v0)
    a0, b0 = int(max(np.floor(u0 - g), 0)), int(max(np.floor(v0 - g), 0))
    a1, b1 = int(min(np.ceil(u1 + g), W)), int(min(np.ceil(v1 + g), H))
    a1, b1 = max(a1, min(a0 + 2, W)), max(b1, min(b0 + 2, H))
    k = min(1.0, ROD_SIDE / max(a1 - a0, b1 - b0))
    w = min(max(int(round((a1 - a0) * k)), 1), ROD_SIDE)
    h = min(max(int(round((b1 - b0) * k)), 1), ROD_SIDE)
    small = cv2.resize(image[b0:b1, a0:a1].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    l_small = roi_diagonal(roi) * k
    size = max(3, int(ROD_KERNEL * l_small) | 1)
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    r = cv2.morphologyEx(small, cv2.MORPH_TOPHAT, ker) + cv2.morphologyEx(
        small, cv2.MORPH_BLACKHAT, ker
    )
    size = max(3, int(0.01 * l_small) | 1)
    dil = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    r = cv2.dilate(r, dil)
    top = float(np.percentile(r, 99.5))
    out = np.zeros((ROD_SIDE, ROD_SIDE))
    if top > 0:
        out[:h, :w] = np.clip(r / top, 0.0, 1.0)
    # cell centres: pixel a0 - 0.5 + (i + 0.5) / scale of the image is cell i
    frame = [a0 - 0.5 + 0.5 / k, b0 - 0.5 + 0.5 / k, k]
    return out, np.asarray(frame)


#: Gradient-orientation maps (:func:`orientation_maps`, in the manner of LINE-2D, Hinterstoisser
#: et al. 2012): orientations modulo 180 deg quantised into ``ORIENTATION_BINS`` bins on the
#: area-shrunk crop of the ROI grown by ``ROD_GROW`` (longer side at most ``ROD_SIDE``); a pixel
#: votes when its gradient magnitude is at least ``ORIENTATION_LEVEL`` times the crop's 99th
#: percentile; each bin's votes spread over ``ORIENTATION_SPREAD x l_ROI`` (a fitted pose is a
#: few pixels off). Chosen, not tuned.
ORIENTATION_BINS = 8
ORIENTATION_LEVEL = 0.1
ORIENTATION_SPREAD = 0.01


def _crop_frame(shape, roi, grow, side):
    """Grown, clipped crop ``(a0, b0, a1, b1)`` of ``roi`` and its shrink factor ``k <= 1`` so that
    its longer side is at most ``side``, with the shrunk size ``(w, h)``."""
    u0, v0, u1, v1 = (float(x) for x in roi)
    H, W = shape
    g = grow * max(u1 - u0, v1 - v0)
    a0, b0 = int(max(np.floor(u0 - g), 0)), int(max(np.floor(v0 - g), 0))
    a1, b1 = int(min(np.ceil(u1 + g), W)), int(min(np.ceil(v1 + g), H))
    a1, b1 = max(a1, min(a0 + 2, W)), max(b1, min(b0 + 2, H))
    k = min(1.0, side / max(a1 - a0, b1 - b0))
    w = min(max(int(round((a1 - a0) * k)), 1), side)
    h = min(max(int(round((b1 - b0) * k)), 1), side)
    return (a0, b0, a1, b1), k, (w, h)


def orientation_maps(
    image: np.ndarray, roi, spread: float = ORIENTATION_SPREAD
) -> tuple[np.ndarray, np.ndarray]:
    """Spread gradient-orientation responses around the ROI: ``(maps (B, S, S) in [0, 1],
    [u0, v0, scale])`` with ``B = ORIENTATION_BINS``, ``S = ROD_SIDE``; ``spread``: the diameter
    of the spreading disc as a share of ``l_ROI`` (``ORIENTATION_SPREAD`` by default; the template
    search of :mod:`jaxpose.pipelines.monocular.templates` spreads by its shift stride).

    ``maps[o]`` at a cell is ``max |cos(o - b)|`` over the orientation bins ``b`` (modulo
    180 deg, bin ``b`` centred on ``b x 180 / B`` deg) that a strong gradient within the spread
    radius votes for (0 where none does): the similarity of LINE-2D (Hinterstoisser et al. 2012)
    for a template point whose edge normal lies in bin ``o``. A score reads it only at the
    model's projected edges, so background texture away from them does not vote. Cells map to
    image pixels as in :func:`rod_map` (zero-padded to one shape)."""
    (a0, b0, a1, b1), k, (w, h) = _crop_frame(image.shape, roi, ROD_GROW, ROD_SIDE)
    small = cv2.resize(image[b0:b1, a0:a1].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    top = float(np.percentile(mag, 99.0)) if mag.size else 0.0
    B = ORIENTATION_BINS
    maps = np.zeros((B, ROD_SIDE, ROD_SIDE), np.float32)
    frame = np.asarray([a0 - 0.5 + 0.5 / k, b0 - 0.5 + 0.5 / k, k])
    if top <= 0:
        return maps, frame
    theta = np.mod(np.arctan2(gy, gx), np.pi)
    bins = np.mod(np.rint(theta / (np.pi / B)).astype(int), B)
    strong = mag >= ORIENTATION_LEVEL * top
    size = max(3, int(spread * roi_diagonal(roi) * k) | 1)
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    spread = np.stack(
        [cv2.dilate((strong & (bins == b)).astype(np.uint8), ker) for b in range(B)]
    ).astype(np.float32)
    d = np.arange(B)
    sim = np.abs(np.cos((d[:, None] - d[None]) * np.pi / B)).astype(np.float32)  # (o, b)
    resp = np.max(sim[:, :, None, None] * spread[None], axis=1)  # (o, h, w)
    maps[:, :h, :w] = resp
    return maps, frame


#: Texture-orientation maps (:func:`texture_maps`): the local histogram of gradient orientations
#: (modulo 180 deg, ``ORIENTATION_BINS`` bins, magnitude-weighted, each pixel voting for its two
#: nearest bins) over a box window of ``TEXTURE_WINDOW x l_ROI`` on the same crop as
#: :func:`orientation_maps`. A panel of solar cells (a grid of straight lines) gives peaks at its
#: lines' normals; a smooth or blanket-wrinkled face a flat histogram. Chosen, not tuned.
TEXTURE_WINDOW = 0.04


def texture_maps(image: np.ndarray, roi) -> tuple[np.ndarray, np.ndarray]:
    """Local gradient-orientation histograms around the ROI: ``(maps (B, S, S), [u0, v0,
    scale])`` with ``B = ORIENTATION_BINS``, ``S = ROD_SIDE`` and the frame of :func:`rod_map`.

    ``maps[:, i, j]`` sums to at most 1: the share of the gradient magnitude in the window around
    cell ``(i, j)`` whose orientation falls in each bin (bin ``b`` centred on ``b x 180 / B``
    deg); a flat window (no gradient above the crop's noise) gives about zero everywhere."""
    (a0, b0, a1, b1), k, (w, h) = _crop_frame(image.shape, roi, ROD_GROW, ROD_SIDE)
    small = cv2.resize(image[b0:b1, a0:a1].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    B = ORIENTATION_BINS
    maps = np.zeros((B, ROD_SIDE, ROD_SIDE), np.float32)
    frame = np.asarray([a0 - 0.5 + 0.5 / k, b0 - 0.5 + 0.5 / k, k])
    x = np.mod(np.arctan2(gy, gx), np.pi) / (np.pi / B)  # in [0, B)
    lo = np.floor(x).astype(int)
    f = (x - lo).astype(np.float32)
    size = max(3, int(TEXTURE_WINDOW * roi_diagonal(roi) * k) | 1)
    votes = np.zeros((B, h, w), np.float32)
    for b in range(B):
        v = mag * ((lo % B == b) * (1.0 - f) + ((lo + 1) % B == b) * f)
        votes[b] = cv2.boxFilter(v, -1, (size, size), normalize=True)
    noise = float(np.median(mag)) if mag.size else 0.0
    total = votes.sum(0) + noise + 1e-6
    maps[:, :h, :w] = votes / total[None]
    return maps, frame


def distance_map(segments: np.ndarray, shape) -> np.ndarray:
    canvas = np.full(shape, 255, np.uint8)
    for a, b in segments:
        cv2.line(canvas, tuple(int(round(x)) for x in a), tuple(int(round(x)) for x in b), 0, 1)
    return cv2.distanceTransform(canvas, cv2.DIST_L2, 3).astype(np.float64)


def segment_samples(segments: np.ndarray, per_segment: int = 3, pad: int = 128):
    s = np.linspace(0.0, 1.0, per_segment)
    pts = (segments[:, :1] + s[None, :, None] * (segments[:, 1:] - segments[:, :1])).reshape(-1, 2)[
        :pad
    ]
    mask = np.zeros(pad, bool)
    mask[: len(pts)] = True
    out = np.zeros((pad, 2))
    out[: len(pts)] = pts
    return out, mask
