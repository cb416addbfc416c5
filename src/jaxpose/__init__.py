"""jaxpose: vision-based relative navigation of non-cooperative spacecraft in JAX.

Pure-JAX core (jit, vmap, grad): geometry, cameras, DOP and feature selection, pose solvers.
Image-side steps (OpenCV) live in :mod:`jaxpose.vision`; pipelines and studies above them.

Float64 is recommended for navigation work: ``jax.config.update("jax_enable_x64", True)`` (the
``jaxpose`` command does this itself).
"""

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
from jaxpose.core.pnp import PnPResult as PnPResult
from jaxpose.core.pnp import dlt as dlt
from jaxpose.core.pnp import epnp as epnp
from jaxpose.core.pnp import ransac_pnp as ransac_pnp
from jaxpose.core.pnp import solve_pnp as solve_pnp
from jaxpose.core.refine import PoseSensitivity as PoseSensitivity
from jaxpose.core.refine import RefineResult as RefineResult
from jaxpose.core.refine import pose_covariance as pose_covariance
from jaxpose.core.refine import refine_pose as refine_pose
from jaxpose.core.refine import sensitivity as sensitivity
from jaxpose.core.status import Status as Status

__version__ = "0.1.0"
