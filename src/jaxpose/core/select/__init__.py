"""Feature-point selection (Ning, Zhang, Wang 2018, Sec. 4): which ``m`` of ``n`` points to use.

* :func:`quasi_optimal`, :func:`one_step`: the paper's geometric rules (redundancy of the
  line-of-sight directions);
* :func:`exhaustive`, :func:`exhaustive_batch`: the minimum-PDOP and minimum-ADOP subsets over all
  ``C(n, m)`` subsets (refused above :data:`MAX_SUBSETS`: use :func:`branch_and_bound` there);
* :func:`greedy`: backward elimination on the DOP itself;
* :func:`branch_and_bound`: the exact optimum without full enumeration
  (:mod:`jaxpose.core.select.bnb`);
* :func:`subset_dop`: PDOP and ADOP of a subset from the per-point information blocks;
* :func:`select_features`: eager convenience from points, pose and camera.

Every function except :func:`select_features` takes one problem and works under ``jit`` and
``vmap``; ``m`` is a static Python int. The DOP-based methods (greedy, exhaustive, branch and bound,
:func:`subset_dop`) take any stack of ``6 x 6`` information blocks: points
(:func:`jaxpose.core.dilution.information_blocks`), lines
(:func:`jaxpose.core.line_dop.line_information_blocks`) or a mix of both.
"""

from jaxpose.core.select._exhaustive import MAX_SUBSETS as MAX_SUBSETS
from jaxpose.core.select._exhaustive import ExhaustiveResult as ExhaustiveResult
from jaxpose.core.select._exhaustive import exhaustive as exhaustive
from jaxpose.core.select._exhaustive import exhaustive_batch as exhaustive_batch
from jaxpose.core.select._exhaustive import subsets_count as subsets_count
from jaxpose.core.select._exhaustive import unrank_combinations as unrank_combinations
from jaxpose.core.select._features import METHODS as METHODS
from jaxpose.core.select._features import select_features as select_features
from jaxpose.core.select._greedy import greedy as greedy
from jaxpose.core.select._kernel import subset_dop as subset_dop
from jaxpose.core.select._quasi import one_step as one_step
from jaxpose.core.select._quasi import quasi_optimal as quasi_optimal
from jaxpose.core.select._quasi import redundancies as redundancies
from jaxpose.core.select._quasi import selection_status as selection_status
from jaxpose.core.select.bnb import BnBResult as BnBResult
from jaxpose.core.select.bnb import branch_and_bound as branch_and_bound
