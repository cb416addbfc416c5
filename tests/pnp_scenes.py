"""Synthetic PnP scenes shared by test_pnp.py and test_solve_pnp.py (not a test module)."""

import jax.numpy as jnp
import numpy as np

from jaxpose.core.geometry import quat_to_dcm, rotation_angle

K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
BATCH, N = 12, 20


def scenes(rng, count=BATCH, n=N, planar=False, depth=5.0, noise=0.0, K=K):
    """A 1 m object (cube, or square for ``planar``) at ``depth`` metres, random attitudes:
    ``(points_body, pixels, R, t)`` with ``noise`` pixels of Gaussian noise."""
    P = rng.uniform(-0.5, 0.5, (count, n, 3))
    if planar:
        P[..., 2] = 0.0
    R = np.asarray(quat_to_dcm(jnp.asarray(rng.normal(size=(count, 4)))))
    t = np.stack(
        [rng.uniform(-0.2, 0.2, count), rng.uniform(-0.2, 0.2, count), np.full(count, depth)], -1
    )
    cam = np.einsum("bij,bnj->bni", R, P) + t[:, None]
    pix = cam[..., :2] / cam[..., 2:] * K[[0, 1], [0, 1]] + K[:2, 2]
    return P, pix + noise * rng.normal(size=pix.shape), R, t


def angle(Ra, Rb):
    """Rotation angle (radians) between rotation matrices."""
    return np.asarray(rotation_angle(jnp.asarray(Ra), jnp.asarray(Rb)))
