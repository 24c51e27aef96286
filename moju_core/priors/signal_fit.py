"""Noisy tracks fitted exactly once projected onto their signal subspace.

Noise-free complete tracks are fitted exactly and the temporal prior sets only the unseen
depths (:func:`moju_core.priors.temporal_prior.depth_step`). Noisy tracks are fitted softly, and the
discrepancy rule of :mod:`moju_core.priors.smoothness` then keeps the prior's weight low wherever a
stronger prior would pull against the observed motion: on the sheets under an oscillating
camera it chooses weight 1 at 1-3 % noise, where the depths need 10 or more, and e3D with
known cameras is 4-5 times the noise-free value; on the cloth it chooses 10.

The projection ``U_r U_r^T W`` onto the r left singular vectors of W above the noise
(:func:`moju_core.spectrum.significant_rank`) keeps the signal and about ``r / 2F`` of the
noise. With known cameras, when the soft rule chooses a weight of at most
:data:`~moju_core.defaults.MIN_DEPTH_PRIOR`, the solver tries the projected tracks with the
exact fit's rule; if that rule accepts a depth-setting weight (at least
``MIN_DEPTH_PRIOR``), the loop fits the projected tracks exactly with that weight, as it
fits noise-free tracks. Otherwise (the 10-frame faces, where no prior helps) nothing changes.
Tracks with missing entries are projected once completed (the observed values and the
completion's at the hidden entries, :mod:`moju_core.completion.missing`); their smoothness trials
fitted
the observed entries only, so the exact fit's rule runs its own trials on the projection.
Where the soft rule chooses more (face3, the paper: 100-1000) the soft loop denoises well
through its own low-rank model, and the projection cost up to 25 % at 3 % noise.
Estimated cameras keep the soft fit: an exact fit trusts the cameras, and the estimates of
the noisy oscillating sheets are 20-30 degrees off.
Design in docs/solver.md, "Noisy tracks"; the measurements in benchmarks/notes/.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moju_core.defaults import MIN_DEPTH_PRIOR
from moju_core.loop import admm
from moju_core.params import SolverParams
from moju_core.priors.smoothness import SmoothnessChoice, choose_smoothness
from moju_core.spectrum import project_tracks


@dataclass(frozen=True)
class SignalFit:
    """The projected tracks and the prior weight the exact fit's rule chose for them.

    Attributes
    ----------
    tracks : ndarray of shape (F, 2, P)
        ``U_r U_r^T W`` in per-frame form (centred, scale-normalised like the input).
    smoothness : float
        The weight chosen, at least :data:`~moju_core.defaults.MIN_DEPTH_PRIOR`.
    trials : list of (float, float)
        The rule's trials on the projected tracks, as
        :func:`moju_core.priors.smoothness.choose_smoothness` returns them.
    """

    tracks: np.ndarray
    smoothness: float
    trials: list[tuple[float, float]]


def signal_fit(
    tracks: np.ndarray,
    rotations: np.ndarray,
    params: SolverParams,
    signal_basis: np.ndarray,
    *,
    choice: SmoothnessChoice | None = None,
    hook: admm.IterationHook | None = None,
) -> SignalFit | None:
    """The exact fit of the projected tracks, if the exact fit's rule accepts a depth-setting
    weight.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred, scale-normalised tracks, every entry filled (with missing data: the observed
        values and the completion's at the hidden entries).
    rotations : ndarray of shape (F, 2, 3)
        Fixed camera rotations (not refined by the loop).
    params : SolverParams
        Resolved parameters, as for :func:`moju_core.priors.smoothness.choose_smoothness`.
    signal_basis : ndarray of shape (2F, r)
        Left singular vectors of W above the noise.
    choice : SmoothnessChoice, optional
        The smoothness trials' choice on these tracks, when they fitted every entry (complete
        tracks): :func:`moju_core.priors.smoothness.choose_smoothness` projects onto the same basis,
        so its exact weight is this rule's and no further solve runs. None (trials fitted on
        the observed entries only): the trials run again on the projected tracks.
    hook : callable, optional
        Passed to the trial solves (progress, cancellation).

    Returns
    -------
    SignalFit or None
        None when the exact fit's rule chooses a weight below
        :data:`~moju_core.defaults.MIN_DEPTH_PRIOR` too.
    """
    projected = project_tracks(tracks, signal_basis)
    if choice is None:
        choice = choose_smoothness(projected, rotations, params, signal_basis, hook=hook)
    if choice.exact_weight < MIN_DEPTH_PRIOR:
        return None
    return SignalFit(projected, choice.exact_weight, choice.trials)
