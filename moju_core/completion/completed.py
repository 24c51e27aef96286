"""Tracks with hidden entries made ready for the solver: completed, and which entries to fit.

:func:`complete_tracks` runs the completion of :mod:`moju_core.completion` once, before the
cameras: the low-rank model of W (:func:`~moju_core.completion.missing.complete`), the
entries it predicts reliably, values for the others from the points' neighbours, and the
hidden entries near a track's observed frames corrected by the track. It returns the completed
tracks and the masks the later stages read (:class:`CompletedTracks`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moju_core import defaults
from moju_core.completion import gaps, missing, neighbours
from moju_core.preprocessing import normalise
from moju_core.spectrum import Spectrum, spectrum

#: With missing data the cameras are estimated from the well-seen points whose entries are all
#: reliable; from all well-seen points when fewer than this are, and from all points when
#: fewer than this are well seen. The trials of the smoothness choice likewise need this many
#: complete points to run unmasked. Twenty points are many times the rank of the tracks
#: (at most 3K for K shape bases) that both fit.
MIN_COMPLETE_POINTS = 20


@dataclass(frozen=True, eq=False)
class CompletedTracks:
    """The completion of tracks with hidden entries.

    Attributes
    ----------
    W : ndarray of shape (2F, P)
        The tracks with every hidden entry filled (model, neighbour or gap value).
    values : ndarray of shape (2F, P)
        The model's values, with the unreliable entries from the neighbours.
    observed : ndarray of shape (F, P), bool
        The observed entries.
    reliable : ndarray of shape (F, P), bool
        The entries the model predicts reliably (observed ones included).
    fitted : ndarray of shape (F, P), bool, or None
        The entries the loop fits: observed, reliable, and those of borrowed points; None when
        that is every entry.
    borrowed : bool
        Whether any point took its values from its neighbours.
    exact_entries : ndarray of shape (F, P), bool
        The entries an exact fit fits exactly: the reliable ones of an exact model, else the
        observed ones.
    noise : float or None
        Noise variance of the fully observed blocks, in squared input units (None when there
        are too few of them).
    noisy : bool
        Whether that noise is measurable against the completed tracks' scale.
    rank : int
        Rank of the model.
    exact : bool
        Whether W was found exactly of that rank.
    unexplained : float or None
        The held-out error its rank leaves beyond the noise (None for an exact model).
    """

    W: np.ndarray
    values: np.ndarray
    observed: np.ndarray
    reliable: np.ndarray
    fitted: np.ndarray | None
    borrowed: bool
    exact_entries: np.ndarray
    noise: float | None
    noisy: bool
    rank: int
    exact: bool
    unexplained: float | None


def complete_tracks(W: np.ndarray, observed: np.ndarray) -> CompletedTracks:
    """Complete tracks W (2F, P) with NaN at the hidden entries ``~observed`` (F, P).

    Costs those of :func:`moju_core.completion.missing.complete` (alternating least squares,
    O(F P r^2) per sweep) and of the neighbour search (O(P log P)).
    """
    # The noise from the fully observed blocks, relative to the completed tracks' mean
    # square; a completion less precise than a measurement of noisy tracks is not data.
    block_noise = missing.observed_noise_variance(W, observed)
    model = missing.complete(W, observed, noise=block_noise)
    noisy = block_noise is not None and (
        block_noise / normalise(model.fill(W, observed))[1] ** 2 > defaults.EXACT_DATA_NOISE
    )
    reliable = missing.trusted_entries(model, observed, noisy=noisy)
    values, borrowed_points = neighbours.borrow_values(
        model, W, observed, reliable, noise=block_noise or 0.0
    )
    # The entries the loop fits: the observed ones, the hidden ones the low-rank model
    # predicts well and those of the borrowed points, at their model values. The smoothness
    # trials fit the observed ones only: the model's errors at trusted entries would count as
    # misfit there.
    fitted = reliable | borrowed_points[None, :]
    return CompletedTracks(
        W=gaps.filled(values, W, observed, model.gap),
        values=values,
        observed=observed,
        reliable=reliable,
        fitted=None if fitted.all() else fitted,
        borrowed=bool(borrowed_points.any()),
        # An exact model predicts its trusted entries as exactly as they would be measured.
        exact_entries=reliable if model.exact else observed,
        noise=block_noise,
        noisy=noisy,
        rank=model.rank,
        exact=model.exact,
        unexplained=None if model.exact else model.unexplained,
    )


def camera_points(observed: np.ndarray, reliable: np.ndarray) -> np.ndarray:
    """The points the camera step sees with missing data, (P,) bool.

    The well-seen points whose entries are all reliable (their values elsewhere come from
    their neighbours and are not of the model's rank: with them the camera step read the
    mixture as motion a single camera fit cannot explain); failing
    :data:`MIN_COMPLETE_POINTS` of those, the well-seen points; failing those, all.
    """
    seen = missing.well_seen(observed)
    for points in (seen & reliable.all(axis=0), seen):
        if points.sum() >= MIN_COMPLETE_POINTS:
            return points
    return np.ones_like(seen)


def camera_tracks(
    completed: CompletedTracks, measured: np.ndarray, scale: float, noisy: bool
) -> tuple[np.ndarray, Spectrum]:
    """Centred, normalised tracks (2F, n) for the camera step with missing data, and their
    spectrum; the points of :func:`camera_points`.

    Noise-free tracks give the model's ``values``: mixing exact observed values with the
    model's errors at the hidden entries leaves a spectrum without a floor. Noisy tracks give
    the observed values with the model's at the hidden entries (``measured``, the tracks
    before the gap correction): there the held-out error chooses a low rank whose values lose
    what the cameras need.
    """
    columns = np.flatnonzero(camera_points(completed.observed, completed.reliable))
    if noisy:
        filled = np.where(missing.expand_mask(completed.observed), measured, completed.values)
        tracks = filled[:, columns] / scale
        tracks = tracks - tracks.mean(axis=1, keepdims=True)
    else:
        tracks = completed.values[:, columns]
        tracks = (tracks - tracks.mean(axis=1, keepdims=True)) / scale
    return tracks, spectrum(tracks)


def trial_tracks(
    tracks: np.ndarray, observed: np.ndarray | None, exact_entries: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The tracks (F, 2, n) and visibility the smoothness trials fit.

    With missing data, the observed entries only, unless an exact model predicts the hidden
    ones (``exact_entries`` is not ``observed``): then the points all of whose entries it
    predicts or observes, complete, as on complete tracks (at :data:`MIN_COMPLETE_POINTS` or
    more; a masked trial loop costs more than an unmasked one).
    """
    if observed is None or exact_entries is observed:
        return tracks, observed
    points = exact_entries.all(axis=0)
    if points.sum() < MIN_COMPLETE_POINTS:
        return tracks, exact_entries
    return np.ascontiguousarray(tracks[:, :, points]), None
