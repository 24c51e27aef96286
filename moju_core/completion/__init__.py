"""Missing data: completing tracks that are not seen in every frame.

* :mod:`~moju_core.completion.missing` - the low-rank completion of W from its observed
  entries (rank chosen by held-out error), which entries it predicts reliably, and the
  noise of the fully observed blocks;
* :mod:`~moju_core.completion.exact_model` - the exact model of noise-free tracks, tried
  first;
* :mod:`~moju_core.completion.least_squares` - the masked least-squares solves of both;
* :mod:`~moju_core.completion.window_subspace` - the exact model's candidate column spaces
  from windows of frames;
* :mod:`~moju_core.completion.neighbours` - values for the entries the completion does not
  determine, borrowed from a point's image neighbours;
* :mod:`~moju_core.completion.gaps` - hidden entries near a track's observed frames,
  corrected by the track itself;
* :mod:`~moju_core.completion.completed` - all of it run once for the solver: the completed
  tracks and which entries the loop fits.

The solver uses them before the loop: translation, cameras, the smoothness trials and the
initial groups see the completed tracks; the loop fits the entries the completion trusts.
"""
