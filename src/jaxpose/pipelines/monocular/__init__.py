"""Monocular pose initialisation from one image (Sharma, Ventura, D'Amico 2018, the SVD
architecture), and the RANSAC baseline of its Test 4.

Stages, one module each (:func:`initialise_pose` in :mod:`.pipeline` runs them in order):

1. detect (:func:`jaxpose.vision.features.detect`): undistortion, WGE, ROI, coarse position, two
   Hough streams (or LSD), merging, feature synthesis; the image maps the scores read
   (:mod:`jaxpose.vision.image_maps`) are gathered in :mod:`.scene`;
2. hypothesise (:mod:`.hypothesise`): the image group kinds that the model also has (Table 1
   ranking) paired with every model group of that kind under the kind's permutations, sharing
   ``max_hypotheses`` by water-filling; with a silhouette (a dark sky), ``attitude_grid``
   attitudes spread over SO(3), each placed on the silhouette by its area and centroid; EPnP of
   every hypothesis in one batched call (``jax.vmap(jaxpose.core.pnp.epnp)``); optionally
   (``template_slots``, off by default) the grid attitudes ranked by a LINE-2D template search
   over in-plane shifts and scales (:mod:`.templates`) take places in the shortlist;
3. score (:mod:`.score`, pure JAX, batched with ``jax.vmap``): a quick model-side score of all
   hypotheses; the best 128 are fitted to the edges (:mod:`.fit`) and ranked by the symmetric
   truncated chamfer distance plus the region, antenna and silhouette terms; the ``top_k``
   *distinct* poses go on (``rank_by="e2d"`` gives the paper's rule, eq. 22 over each
   hypothesis's own points, refined by Newton-Raphson on them);
4. refine (:mod:`.rematch`): visible model edges projected, matched to detected endpoints and
   lines, the pose refined on those matches; the candidate with the lowest ranking key wins;
5. classify (:mod:`.classify`): the confidence class from the chamfer distance and the edge
   coverage (:data:`CONFIDENCE`).
"""

from jaxpose.io.image import load_image as load_image
from jaxpose.pipelines.monocular.classify import classify as classify
from jaxpose.pipelines.monocular.demo import demo_report as demo_report
from jaxpose.pipelines.monocular.options import ANTENNA_WEIGHT as ANTENNA_WEIGHT
from jaxpose.pipelines.monocular.options import ATTITUDE_GRID as ATTITUDE_GRID
from jaxpose.pipelines.monocular.options import CONFIDENCE as CONFIDENCE
from jaxpose.pipelines.monocular.options import GRID_WITHOUT_SILHOUETTE as GRID_WITHOUT_SILHOUETTE
from jaxpose.pipelines.monocular.options import ORIENTATION_WEIGHT as ORIENTATION_WEIGHT
from jaxpose.pipelines.monocular.options import PANEL_WEIGHT as PANEL_WEIGHT
from jaxpose.pipelines.monocular.options import REGION_WEIGHT as REGION_WEIGHT
from jaxpose.pipelines.monocular.options import ROI_LENGTH_FACTOR as ROI_LENGTH_FACTOR
from jaxpose.pipelines.monocular.options import SILHOUETTE_WEIGHT as SILHOUETTE_WEIGHT
from jaxpose.pipelines.monocular.options import SPREAD_QUICK_WEIGHT as SPREAD_QUICK_WEIGHT
from jaxpose.pipelines.monocular.options import SPREAD_WEIGHT as SPREAD_WEIGHT
from jaxpose.pipelines.monocular.options import TEMPLATE_SLOTS as TEMPLATE_SLOTS
from jaxpose.pipelines.monocular.options import InitOptions as InitOptions
from jaxpose.pipelines.monocular.options import InitResult as InitResult
from jaxpose.pipelines.monocular.pipeline import initialise_pose as initialise_pose
from jaxpose.vision.overlay import draw_overlay as draw_overlay

__all__ = [
    "ANTENNA_WEIGHT",
    "ATTITUDE_GRID",
    "CONFIDENCE",
    "GRID_WITHOUT_SILHOUETTE",
    "ORIENTATION_WEIGHT",
    "PANEL_WEIGHT",
    "REGION_WEIGHT",
    "ROI_LENGTH_FACTOR",
    "SILHOUETTE_WEIGHT",
    "SPREAD_QUICK_WEIGHT",
    "SPREAD_WEIGHT",
    "TEMPLATE_SLOTS",
    "InitOptions",
    "InitResult",
    "classify",
    "demo_report",
    "draw_overlay",
    "initialise_pose",
    "load_image",
]
