"""The ADMM loop of Algorithm 1 and the steps it is made of.

* :mod:`~moju_core.loop.admm` - the loop itself (:func:`~moju_core.loop.admm.run`), its
  steps numbered as in Algorithm 1;
* :mod:`~moju_core.loop.loop_state` - the loop's state and its data terms;
* :mod:`~moju_core.loop.stopping` - convergence and stop reasons;
* :mod:`~moju_core.loop.lrr` - the low-rank representation and its singular value
  thresholding;
* :mod:`~moju_core.loop.grassmann`, :mod:`~moju_core.loop.jump`,
  :mod:`~moju_core.loop.grouping_steps`, :mod:`~moju_core.loop.clustering` - the local
  trajectory subspaces as Grassmann points, the jump between the low- and
  high-dimensional manifolds, and the grouping of points;
* :mod:`~moju_core.loop.leading_svd` - the truncated SVDs the loop needs;
* :mod:`~moju_core.loop.closed_form` - method ``pta``, which needs no loop, in the loop's
  output form.
"""
