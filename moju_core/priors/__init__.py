"""Priors on the shapes beyond the low-rank model.

* :mod:`~moju_core.priors.temporal_prior` - the temporal smoothness prior on the shapes
  and the depth steps that solve the S-update with it;
* :mod:`~moju_core.priors.smoothness` - choosing the prior's weight from short trial solves;
* :mod:`~moju_core.priors.signal_fit` - noisy tracks fitted exactly once projected onto
  their signal subspace;
* :mod:`~moju_core.priors.max_depth` - the surface prior that creates depth without rotation:
  per-image perspective shapes by the maximum-depth heuristic with edge-length consistency
  (:mod:`~moju_core.priors.cone_program` on spread anchors, then
  :mod:`~moju_core.priors.dense_depth` on every point of the
  :mod:`~moju_core.priors.neighbour_graph`).
"""
