"""The eager front door: ``jp.dop`` in a fresh process, the first call (tracing and compilation
included) and later calls, against the same DOP under the caller's own ``jax.jit``.

    python bench/front_door.py

Prints one line. ``jp.dop`` compiles itself (``eqx.filter_jit``) on the first call for a shape,
dtype and option set; later calls with new values reuse it.
"""

import time

t0 = time.perf_counter()
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import jaxpose as jp  # noqa: E402

t_import = time.perf_counter() - t0


def main(calls: int = 200) -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (10, 3))
    pose = jp.Pose.from_euler(np.array([0.1, 0.2, 0.3]), np.array([0.1, -0.1, 5.0]))
    camera = jp.PinholeCamera.from_K([[1000, 0, 320], [0, 1000, 240], [0, 0, 1]])
    t0 = time.perf_counter()
    jp.dop(points, pose, camera).pdop.block_until_ready()
    first = time.perf_counter() - t0
    eager = []
    for k in range(calls):
        moved = points + 1e-3 * k
        t0 = time.perf_counter()
        jp.dop(moved, pose, camera).pdop.block_until_ready()
        eager.append(time.perf_counter() - t0)
    jitted = jax.jit(lambda p: jp.dop(p, pose, camera, throw=False).pdop)
    jitted(points).block_until_ready()
    inside = []
    for k in range(calls):
        moved = points + 1e-3 * k
        t0 = time.perf_counter()
        jitted(moved).block_until_ready()
        inside.append(time.perf_counter() - t0)
    print(
        f"import {t_import:.2f} s; first eager jp.dop {first:.2f} s; later eager calls "
        f"{1e3 * np.median(eager):.3f} ms (median of {calls}); under the caller's jax.jit "
        f"{1e3 * np.median(inside):.3f} ms"
    )


if __name__ == "__main__":
    main()
