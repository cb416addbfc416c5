"""Perspective-n-point: the pose of a target from 3-D/2-D point correspondences (pure JAX).

Every solver takes **one** problem, ``points_body (n, 3)`` (metres, target body frame) and the
``pixels (n, 2)`` where they are seen (distorted pixels, as measured), and returns a
:class:`PnPResult` whose pose satisfies ``x_cam = R @ x_body + t``. Batches come from
``jax.vmap``; point sets of different sizes share one compiled function through padding with a
``mask`` (``(n,)`` bool, ``True`` for the valid points).

* :func:`epnp`: EPnP (Lepetit, Moreno-Noguer, Fua 2009; Sharma et al. 2018, eqs. 17-22);
* :func:`dlt`: the direct linear transform (``>= 6`` non-coplanar points);
* :func:`ransac_pnp`: RANSAC over EPnP (Sharma et al. 2018, eq. 35 for the hypothesis count);
* :func:`solve_pnp`: the eager entry point, batched, with refinement and statuses, configured
  by one :class:`PnPOptions` (:class:`RansacOptions`, :class:`~jaxpose.core.refine.RefineOptions`);
* :func:`planar_flip`: the mirrored candidate of a planar target far away.
"""

from jaxpose.core.pnp._batch import THREAD_MIN_PROBLEMS as THREAD_MIN_PROBLEMS
from jaxpose.core.pnp._dlt import dlt as dlt
from jaxpose.core.pnp._epnp import epnp as epnp
from jaxpose.core.pnp._epnp import planar_flip as planar_flip
from jaxpose.core.pnp._options import METHODS as METHODS
from jaxpose.core.pnp._options import SOLVE_REFINE as SOLVE_REFINE
from jaxpose.core.pnp._options import PnPOptions as PnPOptions
from jaxpose.core.pnp._options import RansacOptions as RansacOptions
from jaxpose.core.pnp._options import ransac_iterations as ransac_iterations
from jaxpose.core.pnp._problem import COLLINEAR_TOL as COLLINEAR_TOL
from jaxpose.core.pnp._problem import DLT_MIN_POINTS as DLT_MIN_POINTS
from jaxpose.core.pnp._problem import MIN_POINTS as MIN_POINTS
from jaxpose.core.pnp._problem import PLANAR_TOL as PLANAR_TOL
from jaxpose.core.pnp._ransac import ransac_pnp as ransac_pnp
from jaxpose.core.pnp._result import PnPResult as PnPResult
from jaxpose.core.pnp._solve import solve_pnp as solve_pnp
