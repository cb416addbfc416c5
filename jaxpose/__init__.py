"""jaxpose: vision-based relative navigation of non-cooperative spacecraft in JAX.

Pure-JAX core (jit, vmap, grad): geometry, cameras, DOP and feature selection, pose solvers.
Image-side steps (OpenCV) live in :mod:`jaxpose.vision`; pipelines and studies above them.

Float64 is recommended for navigation work: ``jax.config.update("jax_enable_x64", True)`` (the
``jaxpose`` command does this itself).
"""

from . import geometry as geometry
from . import select as select
from .camera import PinholeCamera as PinholeCamera
from .camera import StereoCamera as StereoCamera
from .camera import as_camera as as_camera
from .dop import DOPResult as DOPResult
from .dop import dop as dop
from .dop import dop_from_information as dop_from_information
from .dop import information_blocks as information_blocks
from .dop import observation_jacobian as observation_jacobian
from .geometry import Pose as Pose
from .pnp import PnPResult as PnPResult
from .pnp import dlt as dlt
from .pnp import epnp as epnp
from .pnp import ransac_pnp as ransac_pnp
from .refine import PoseSensitivity as PoseSensitivity
from .refine import RefineResult as RefineResult
from .refine import pose_covariance as pose_covariance
from .refine import refine_pose as refine_pose
from .refine import sensitivity as sensitivity
from .solve import solve_pnp as solve_pnp
from .status import Status as Status

__version__ = "0.1.0"
