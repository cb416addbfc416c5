"""jaxpose: vision-based relative navigation of non-cooperative spacecraft in JAX.

Three systems, each with its entry points here:

* **DOP and feature selection** (Ning, Zhang, Wang 2018): :func:`dop`, :func:`information_blocks`,
  :func:`select_features`;
* **monocular pose initialisation** (Sharma, Ventura, D'Amico 2018): :func:`solve_pnp` with
  :class:`PnPOptions`, :func:`refine_pose` with :class:`RefineOptions`, and the whole pipeline from
  an image, :func:`initialise_pose` (returning an :class:`InitResult`);
* **stereo point-line tracking** (Yang et al. 2024): :class:`StereoTracker` on a
  :class:`StereoCamera`.

The core (``jaxpose.core``) is pure JAX: jit, vmap and grad work. The image-side steps (OpenCV)
live in :mod:`jaxpose.vision`, pipelines and studies above them; their names here are imported on
first use, so that ``import jaxpose`` stays fast.

Float64 is recommended for navigation work: ``jax.config.update("jax_enable_x64", True)`` (the
``jaxpose`` command does this itself; :func:`initialise_pose` and :class:`StereoTracker` run in
float64 whatever the flag says).
"""

from importlib import import_module as _import_module
from importlib import metadata as _metadata

from jaxpose.core import geometry as geometry
from jaxpose.core import select as select
from jaxpose.core.camera import PinholeCamera as PinholeCamera
from jaxpose.core.camera import StereoCamera as StereoCamera
from jaxpose.core.camera import as_camera as as_camera
from jaxpose.core.dilution import DOPResult as DOPResult
from jaxpose.core.dilution import dop as dop
from jaxpose.core.dilution import dop_from_information as dop_from_information
from jaxpose.core.dilution import information_blocks as information_blocks
from jaxpose.core.dilution import observation_jacobian as observation_jacobian
from jaxpose.core.geometry import Pose as Pose
from jaxpose.core.line_dop import line_information_blocks as line_information_blocks
from jaxpose.core.pnp import PnPOptions as PnPOptions
from jaxpose.core.pnp import PnPResult as PnPResult
from jaxpose.core.pnp import RansacOptions as RansacOptions
from jaxpose.core.pnp import dlt as dlt
from jaxpose.core.pnp import epnp as epnp
from jaxpose.core.pnp import ransac_pnp as ransac_pnp
from jaxpose.core.pnp import solve_pnp as solve_pnp
from jaxpose.core.refine import PoseSensitivity as PoseSensitivity
from jaxpose.core.refine import RefineOptions as RefineOptions
from jaxpose.core.refine import RefineResult as RefineResult
from jaxpose.core.refine import pose_covariance as pose_covariance
from jaxpose.core.refine import refine_pose as refine_pose
from jaxpose.core.refine import sensitivity as sensitivity
from jaxpose.core.select import select_features as select_features
from jaxpose.core.status import Status as Status

try:
    __version__ = _metadata.version("jaxpose")
except _metadata.PackageNotFoundError:  # pragma: no cover - run from a source tree
    __version__ = "0+unknown"

_LAZY = {
    # layer 3 (pipelines, I/O): imported on first use
    "initialise_pose": "jaxpose.pipelines.monocular",
    "InitOptions": "jaxpose.pipelines.monocular",
    "InitResult": "jaxpose.pipelines.monocular",
    "StereoTracker": "jaxpose.pipelines.stereo",
    "TrackerOptions": "jaxpose.pipelines.stereo",
    "load_camera": "jaxpose.io",
    "save_camera": "jaxpose.io",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxpose' has no attribute {name!r}")
    value = getattr(_import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = sorted(
    [
        "DOPResult",
        "PinholeCamera",
        "PnPOptions",
        "PnPResult",
        "Pose",
        "PoseSensitivity",
        "RansacOptions",
        "RefineOptions",
        "RefineResult",
        "StereoCamera",
        "Status",
        "as_camera",
        "dlt",
        "dop",
        "dop_from_information",
        "epnp",
        "geometry",
        "information_blocks",
        "line_information_blocks",
        "observation_jacobian",
        "pose_covariance",
        "ransac_pnp",
        "refine_pose",
        "select",
        "select_features",
        "sensitivity",
        "solve_pnp",
        *_LAZY,
    ]
)
