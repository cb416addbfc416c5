"""Input checks shared by the core entry points (shapes at trace time, ``ValueError`` naming the
argument). Values (NaN, inf, degenerate geometry) are never checked here: they become statuses."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

ONE_PROBLEM = "one problem; use jax.vmap for batches"


def _dtype_of(x) -> np.dtype:
    """The dtype of an array, a tracer or a NumPy scalar, else of ``np.asarray(x)``; ``object``
    for what NumPy cannot read as one array (a ragged list)."""
    dtype = getattr(x, "dtype", None)
    if dtype is not None:
        return dtype
    try:
        return np.asarray(x).dtype
    except (TypeError, ValueError):
        return np.dtype(object)


def real_array(x, name: str = "the array"):
    """``x`` unchanged, or a ``ValueError`` naming ``name`` when it holds something other than
    real numbers: complex values (a cast would drop the imaginary part silently), objects or
    strings (JAX's own error names no argument)."""
    dtype = _dtype_of(x)
    if np.dtype(dtype).kind not in "biuf":
        raise ValueError(f"{name} must hold real numbers; got dtype {dtype}")
    return x


def as_float(x, dtype=None, name: str = "the array") -> Array:
    """``x`` as a JAX array of ``dtype``, or of the default float dtype when it is not floating;
    ``ValueError`` naming ``name`` for complex, object or string values (:func:`real_array`)."""
    x = jnp.asarray(real_array(x, name))
    if dtype is not None:
        return x.astype(dtype)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def float_dtype(x) -> jnp.dtype:
    """The dtype of ``x`` if floating, else the default float dtype."""
    dtype = jnp.asarray(x).dtype
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


def check_last(x, size: int, name: str) -> Array:
    """A float array of shape ``(..., size)``."""
    x = as_float(x, name=name)
    if x.ndim < 1 or x.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}); got {x.shape}")
    return x


def check_matrix(R, name: str = "R") -> Array:
    """A float array of shape ``(..., 3, 3)``."""
    x = as_float(R)
    if x.ndim < 2 or x.shape[-2:] != (3, 3):
        raise ValueError(f"{name} must have shape (..., 3, 3); got {x.shape}")
    return x


def check_rows(x, tail: tuple[int, ...], name: str, dtype=None, *, prefix: str = "") -> Array:
    """A float array of shape ``(n, *tail)`` (one problem)."""
    x = as_float(x, dtype, name=f"{prefix}{name}")
    if x.ndim != len(tail) + 1 or x.shape[1:] != tail:
        want = ", ".join(["n", *map(str, tail)])
        raise ValueError(f"{prefix}{name} must have shape ({want}) ({ONE_PROBLEM}); got {x.shape}")
    return x


def check_same_length(a: Array, b: Array, name_a: str, name_b: str) -> None:
    if a.shape[0] != b.shape[0]:
        raise ValueError(
            f"{name_a} and {name_b} must have the same length; got {a.shape[0]} and {b.shape[0]}"
        )


def check_pose(pose, name: str = "pose") -> None:
    """One :class:`~jaxpose.core.geometry.Pose` (rotation ``(3, 3)``, translation ``(3,)``)."""
    from jaxpose.core.geometry import Pose

    if not isinstance(pose, Pose):
        raise ValueError(f"{name} must be a jaxpose.Pose; got {type(pose).__name__}")
    if jnp.shape(pose.R) != (3, 3) or jnp.shape(pose.t) != (3,):
        raise ValueError(
            f"{name} must hold one rotation (3, 3) and one translation (3,); got "
            f"{jnp.shape(pose.R)} and {jnp.shape(pose.t)} (use jax.vmap for batches)"
        )


def check_line_inputs(segments_body, lines_img, *, prefix: str = "", **line_options) -> bool:
    """Whether lines are given. ``ValueError`` when only one of ``segments_body`` and
    ``lines_img`` is, or when an option of the lines (``line_mask=``, ``line_sigma=``,
    ``line_information=``, passed by name) is given without them: it would be ignored."""
    if (segments_body is None) != (lines_img is None):
        raise ValueError(f"{prefix}segments_body and lines_img go together (both or neither)")
    if segments_body is None:
        for name, value in line_options.items():
            if value is not None:
                raise ValueError(
                    f"{prefix}{name} was given without lines: it applies to segments_body and "
                    "lines_img, which are None (pass the lines, or leave out the line options)"
                )
    return segments_body is not None


def as_bool_mask(mask, name: str = "mask") -> Array:
    """``mask`` as a JAX bool array. Booleans pass; numbers only when every value is 0 or 1 (a
    0/1 mask), since other numbers are most likely indices or weights, which a cast to bool would
    turn silently into another selection; anything else (strings, objects) is refused. A traced
    numeric mask cannot be looked at and is cast."""
    if isinstance(mask, jax.core.Tracer):
        return mask if mask.dtype == bool else mask.astype(bool)
    if isinstance(mask, jax.Array) and mask.dtype == jnp.bool_:  # no copy to the host and back
        return mask
    a = np.asarray(mask)
    if a.dtype == bool:
        return jnp.asarray(a)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be booleans (True: use the feature); got dtype {a.dtype}")
    if not np.all((a == 0) | (a == 1)):
        raise ValueError(
            f"{name} must be booleans or 0/1 (True: use the feature), not indices or weights; "
            f"got values {np.unique(a)[:6].tolist()}"
        )
    return jnp.asarray(a.astype(bool))


def check_mask(mask, n: int, name: str = "mask", *, prefix: str = "") -> Array:
    """A bool array of shape ``(n,)`` (:func:`as_bool_mask`); all ``True`` when ``mask`` is
    ``None``."""
    if mask is None:
        return jnp.ones((n,), bool)
    shape = jnp.shape(mask)
    if shape != (n,):
        raise ValueError(f"{prefix}{name} must have shape ({n},); got {shape}")
    return as_bool_mask(mask, prefix + name)


def is_rotation(R) -> Array:
    """Whether ``R`` (``(..., 3, 3)``) is a rotation: ``R^T R = I`` to ``max(1e-6, 1e3 eps)``
    entry-wise and ``det R > 0`` (a traced boolean; NaN gives ``False``)."""
    R = jnp.asarray(R)
    tol = max(1e-6, 1e3 * float(jnp.finfo(R.dtype).eps))
    eye = jnp.eye(3, dtype=R.dtype)
    gram = jnp.swapaxes(R, -1, -2) @ R
    ortho = jnp.all(jnp.abs(gram - eye) <= tol, axis=(-2, -1))
    return ortho & (jnp.linalg.det(R) > 0)


def check_positive(x, name: str) -> None:
    """``ValueError`` when ``x`` is not numeric (a bool, a string) or is known (not traced) and
    holds a value that is not positive and finite; ``None`` and traced numeric values pass (a
    traced bad value becomes a status downstream)."""
    if x is None:
        return
    dtype = x.dtype if isinstance(x, jax.core.Tracer) else np.asarray(x).dtype
    if dtype.kind not in "iuf":  # a bool was taken as 1 or 0, a numeric string as its number
        raise ValueError(f"{name} must be a number or an array of numbers; got {x!r}")
    if isinstance(x, jax.core.Tracer):
        return
    values = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError(f"{name} must be positive and finite; got {values.tolist()}")


def _is_real(x) -> bool:
    """Whether ``x`` is one Python or NumPy integer or float (not a bool, a string or an array)."""
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


def is_finite_number(x) -> bool:
    """Whether ``x`` is one finite real number given as a Python or NumPy integer or float (not a
    bool, a string or an array): the test behind the option and scene checks that name their
    field in their own message."""
    return bool(_is_real(x) and np.isfinite(x))


def _is_integer(x) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def check_fields(
    obj,
    *,
    flags=(),
    integers=None,
    positive=(),
    limits=(),
    non_negative=(),
    fractions=(),
    optional=(),
) -> None:
    """``ValueError`` naming ``Type.field`` for a field of the options object ``obj`` that is not
    of its kind, so that a bad value is refused where it is set instead of acting silently (a
    bool taken as 1, a string compared with a number) deep in a pipeline:

    * ``flags``: a bool (``True``/``False``, NumPy's too);
    * ``integers``: ``{field: least value}``, an integer (not a bool) at least that;
    * ``positive``: a finite number above 0;
    * ``limits``: a number above 0, ``inf`` allowed (a threshold that can be turned off);
    * ``non_negative``: a finite number at least 0;
    * ``fractions``: a finite number in ``[0, 1]``.

    A field also named in ``optional`` may be ``None``.
    """
    owner = type(obj).__name__

    def bad(name, what, value):
        if name in optional:
            what += " or None"
        raise ValueError(f"{owner}.{name} must be {what}; got {value!r}")

    kinds = (
        (flags, lambda x: isinstance(x, bool | np.bool_), "True or False"),
        (positive, lambda x: is_finite_number(x) and x > 0, "a finite number > 0"),
        (limits, lambda x: _is_real(x) and x > 0, "a number > 0 (inf: no limit)"),
        (non_negative, lambda x: is_finite_number(x) and x >= 0, "a finite number >= 0"),
        (fractions, lambda x: is_finite_number(x) and 0 <= x <= 1, "a number in [0, 1]"),
    )
    for names, ok, what in kinds:
        for name in names:
            value = getattr(obj, name)
            if not (value is None and name in optional) and not ok(value):
                bad(name, what, value)
    for name, least in (integers or {}).items():
        value = getattr(obj, name)
        if not (value is None and name in optional) and not (_is_integer(value) and value >= least):
            bad(name, f"an integer >= {least}", value)


def _described(x) -> str:
    """``x`` for a message: its repr, or its shape and dtype when it is a larger array."""
    shape, dtype = getattr(x, "shape", None), getattr(x, "dtype", None)
    if shape is not None and dtype is not None and int(np.prod(shape)) > 9:
        return f"an array of shape {tuple(shape)} and dtype {dtype}"
    return repr(x)


def check_real(x, name: str, *, prefix: str = "") -> None:
    """``ValueError`` naming ``name`` when ``x`` does not hold real numbers (integers or floats):
    a bool (which would be taken as 1 or 0), a string (which would be parsed, or fail deep in
    JAX), a complex number (whose imaginary part would be dropped) or an object. A traced ``x`` is
    judged by its dtype; values are not looked at here."""
    if isinstance(x, bool | np.bool_ | str | bytes):
        raise ValueError(f"{prefix}{name} must be a real number or an array of them; got {x!r}")
    dtype = _dtype_of(x)
    if not (jnp.issubdtype(dtype, jnp.integer) or jnp.issubdtype(dtype, jnp.floating)):
        raise ValueError(
            f"{prefix}{name} must be a real number or an array of them; got {_described(x)} "
            f"(dtype {dtype})"
        )


def as_image_size(x, name: str, *, prefix: str = "") -> int:
    """``x`` as an image side in pixels: an integer ``>= 0`` (an integral float such as ``640.0``
    too). ``ValueError`` naming ``name`` for a bool, a string, a fraction (``640.7``), a negative
    or non-finite number, an array of more than one number, or a traced value (an image size is
    static)."""

    def bad():
        return ValueError(
            f"{prefix}{name} must be an image size in pixels, an integer >= 0; got {x!r}"
        )

    if isinstance(x, jax.core.Tracer):
        raise ValueError(
            f"{prefix}{name} must be a concrete integer (the image size is static); got a traced "
            "value"
        )
    if isinstance(x, bool | np.bool_ | str | bytes):
        raise bad()
    if isinstance(x, np.ndarray | jax.Array):
        if x.ndim != 0:
            raise bad()
        x = x.item()
    if isinstance(x, int | np.integer) and not isinstance(x, bool):
        value = int(x)
    elif isinstance(x, float | np.floating) and np.isfinite(x) and float(x) == int(x):
        value = int(x)
    else:
        raise bad()
    if value < 0:
        raise bad()
    return value


def intrinsic_matrix_problem(K) -> str | None:
    """What keeps a concrete ``3x3`` ``K`` (finite) from having the layout ``[[fx, 0, cx],
    [0, fy, cy], [0, 0, 1]]``, which is all a :class:`~jaxpose.core.camera.PinholeCamera` holds:
    a skew ``K[0, 1]`` above ``1e-9 fx``, a ``K[1, 0]`` above ``1e-9 fy``, or a last row more than
    ``1e-12`` from ``(0, 0, 1)``; ``None`` when it has that layout."""
    K = np.asarray(K, dtype=float)
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
        return f"a skew K[0, 1] = {float(K[0, 1]):g} (not supported: it must be 0)"
    if abs(K[1, 0]) > 1e-9 * abs(K[1, 1]):
        return f"K[1, 0] = {float(K[1, 0]):g} (it must be 0)"
    if np.max(np.abs(K[2] - np.array([0.0, 0.0, 1.0]))) > 1e-12:
        return f"a last row {K[2].tolist()} (it must be (0, 0, 1))"
    return None


def check_rotation(R, name: str = "R", *, nonfinite_ok: bool = False, prefix: str = "") -> None:
    """``ValueError`` naming ``name`` when a concrete ``R`` (``(..., 3, 3)``) holds a matrix that is
    not a rotation: the tolerance of :func:`is_rotation` (``R^T R = I`` to ``max(1e-6, 1e3 eps)``
    entry-wise, ``det R > 0``), computed with NumPy. A traced ``R`` is not looked at (it cannot be
    without breaking ``jit``); with ``nonfinite_ok``, a matrix holding NaN or inf passes (a failed
    estimate, which becomes NaN or a status downstream)."""
    if isinstance(R, jax.core.Tracer):
        return
    a = np.asarray(R)
    dtype = a.dtype if jnp.issubdtype(a.dtype, jnp.floating) else np.dtype(np.float64)
    tol = max(1e-6, 1e3 * float(jnp.finfo(dtype).eps))
    a = a.astype(np.float64)
    with np.errstate(all="ignore"):
        gram = np.swapaxes(a, -1, -2) @ a
        ok = np.all(np.abs(gram - np.eye(3)) <= tol, axis=(-2, -1)) & (np.linalg.det(a) > 0)
    finite = np.all(np.isfinite(a), axis=(-2, -1))
    if nonfinite_ok:
        ok = ok | ~finite
    if not np.all(ok):
        got = a.tolist() if a.size <= 9 else f"{np.count_nonzero(~ok)} of {ok.size} matrices not"
        raise ValueError(
            f"{prefix}{name} must be a {'' if nonfinite_ok else 'finite '}rotation matrix "
            f"({name}^T {name} = I to {tol:g}, det {name} = +1); got {got}"
        )
