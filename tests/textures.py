"""A smooth random texture for the alignment and stereo tests, defined everywhere."""

import numpy as np


def random_texture(seed: int, waves: int, spread: float, contrast: float):
    """``f(x, y)``: ``128 + contrast * sum(a cos(kx x + ky y + phase))`` over ``waves`` plane
    waves with wave numbers drawn from N(0, spread) (radians per unit of ``x, y``)."""
    rng = np.random.default_rng(seed)
    kx, ky = rng.normal(0, spread, waves), rng.normal(0, spread, waves)
    phase, amp = rng.uniform(0, 2 * np.pi, waves), rng.uniform(0.5, 1.0, waves)

    def texture(x, y):
        arg = kx * np.asarray(x)[..., None] + ky * np.asarray(y)[..., None] + phase
        return 128 + contrast * np.sum(amp * np.cos(arg), axis=-1)

    return texture
