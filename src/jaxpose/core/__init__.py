"""Layer 1, the pure-JAX core: rotations and poses, cameras, DOP and selection, residuals, PnP,
refinement, metrics and statuses. jit, vmap and grad work on everything here; no OpenCV, no files.
"""
