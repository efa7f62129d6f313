"""The map searcher's belief, apart from any policy: the predicted maps of every candidate user cell, their cache and
the belief arithmetic (docs/searcher.md; the predictor's tiers and their loader are ``rl.predictor``).

For each canvas (a city under a symmetry) the predictor (a tier of ``rl.predictor``) gives the SINR map of a
user at every *candidate* cell (open ground on a lattice of ``stride`` cells; with ``buildings=False`` every lattice
cell, the predictor shown open ground: the map ablation): ``CandidateMaps``. A belief is the log-probability of each
candidate, uniform at the start. After every measurement ``m`` at cell ``x``:

- ``m`` above the SINR floor: ``log b += temper * log[(1 - p_dead) N(m; mu_c(x), sigma)]``;
- ``m`` at the floor (dead, or live and below it): censored, ``log b += temper * log[p_dead + (1 - p_dead)
  Phi((floor - mu_c(x)) / sigma)]``,

with ``mu_c(x)`` the predicted SINR, ``p_dead`` the predictor's dead-cell probability and ``sigma`` its measured
error, a share ``outlier`` of the likelihood flat. ``temper`` < 1 makes up for the errors of one candidate's map
being alike from cell to cell. The posterior probability that a cell ``x'`` reaches P_T is ``sum_c b_c (1 - p_dead)
Phi((mu_c(x') - P_T) / sigma)`` (``posterior_cover``).

The predicted maps of a canvas are computed once and kept on disk (``PredictionCache``), keyed by the bundle version,
the symmetry, the candidate lattice, the blanked map and the predictor's version (its weights, constants and code),
and checked whenever they are read (``cache.py``). ``BeliefModel`` holds the arithmetic (``model.py``), ``BeliefTracker`` the belief of every row
of a ``BatchedEnv`` as an observation channel (``tracker.py``; the hybrid learner, ``EnvConfig.belief_channel``). The planners
(``rl.tasks.placement.searcher``, ``rl.tasks.tracking.searcher``, ``rl.tasks.fleet``) use it; this package imports none of them.
"""

from __future__ import annotations

from uavplace.rl.belief.cache import ENTRY_BYTES, PREDICTIONS, PredictionCache
from uavplace.rl.belief.model import (
    OUTLIER_SPAN_DB,
    PREDICT_CHUNK,
    BeliefModel,
    CandidateMaps,
    candidate_cells,
    posterior_cover,
    probit_of,
    rows_of,
)
from uavplace.rl.belief.tracker import BeliefTracker

__all__ = [
    "ENTRY_BYTES",
    "OUTLIER_SPAN_DB",
    "PREDICTIONS",
    "PREDICT_CHUNK",
    "BeliefModel",
    "BeliefTracker",
    "CandidateMaps",
    "PredictionCache",
    "candidate_cells",
    "posterior_cover",
    "probit_of",
    "rows_of",
]
