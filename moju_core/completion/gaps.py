"""Hidden entries near their track's observed frames: the completion corrected by the track.

A low-rank completion (:mod:`moju_core.completion.missing`) predicts a hidden entry from the other
points.
Where the tracks are not of low rank (41 markers of an articulated body) it misses motion that
the point's own neighbouring frames show. Two corrections use them, each weighted by
``exp(-d / L)``, d the distance in frames to the nearest observed frame of the point:

* the track itself interpolated linearly across the gap, in place of the completion. Where
  the completion's error changes from frame to frame with the set of points each frame
  sees, this is far better close to the gap's ends: 41 markers over 350 frames, 10 % of the
  entries hidden at random, noise-free (seeds 46-47), the median error at the hidden
  entries went from 0.056 / 0.025 of the tracks' RMS to 0.002 / 0.007 on the body, from
  0.010 / 0.012 to 0.001 on a face. On a fast-moving dense face or sheet it is far worse
  than the completion (face3 and the paper under the closing occlusion: 0.03-0.26 one
  frame into a gap, against 0.0-0.012);
* the completion's residual at the gap's ends, interpolated across it: the completion's
  motion kept, its offset from the track corrected. On face4's markers under the closing
  occlusion this is the better one four frames into a gap (0.005 against 0.015).

Beyond a track's first or last observed frame the residual there is held (the track's last
value held was 2-40 times worse than that, on every sequence measured). Which of the two
inside gaps, and L, are chosen per input by the error at held-out observed entries
(:func:`moju_core.completion.missing.choose_rank`); L = 0 is the completion alone. Under noise the
correction carries the neighbouring frames' noise, and the choice weighs that too.
Cost O(F P) per call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GapFill:
    """How far hidden entries move from the completion (see the module docstring).

    track : float
        Decay length (frames) of the move to the track interpolated inside a gap; 0: none.
    residual : float
        Decay length (frames) of the completion's interpolated or held residual, for what the
        first move leaves; 0: none.
    """

    track: float = 0.0
    residual: float = 0.0

    @property
    def corrects(self) -> bool:
        """Whether any hidden entry moves."""
        return self.track > 0 or self.residual > 0


#: Decay lengths (frames) the held-out choice combines; 0 first, so that it wins ties.
#: Held-out check: benchmarks/notes/2026-12-06-rule-ablation.md.
DECAYS = (0.0, 1.0, 3.0, 10.0, 30.0, np.inf)
#: The corrections the held-out choice tries, in order; the first of equal error wins.
CANDIDATES = tuple(GapFill(track, residual) for track in DECAYS for residual in DECAYS)


def nearest_observed(visibility: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The previous and the next observed frame of every entry, each (F, P) int.

    An observed entry is its own previous and next frame; -1 where no frame before is
    observed, F where none after is.
    """
    n_frames = visibility.shape[0]
    frames = np.arange(n_frames)[:, None]
    previous = np.maximum.accumulate(np.where(visibility, frames, -1), axis=0)
    following = np.where(visibility, frames, n_frames)[::-1]
    following = np.minimum.accumulate(following, axis=0)[::-1]
    return previous, following


def _distances(previous: np.ndarray, following: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frames from each entry back to the previous and on to the next observed frame of its
    point (:func:`nearest_observed`), each (F, P) float: 0 at observed entries, inf where
    there is none."""
    n_frames = previous.shape[0]
    frames = np.arange(n_frames)[:, None]
    return (
        np.where(previous >= 0, frames - previous, np.inf),
        np.where(following < n_frames, following - frames, np.inf),
    )


def distance_to_observed(visibility: np.ndarray) -> np.ndarray:
    """Frames from each entry to the nearest observed frame of its point, (F, P) float.

    0 at observed entries; inf for a point seen in no frame.
    """
    return np.minimum(*_distances(*nearest_observed(visibility)))


@dataclass(frozen=True)
class Pieces:
    """The parts of :func:`correction` that do not depend on the decays, per row of W.

    track : ndarray of shape (2F, P)
        ``w - v`` inside a gap, 0 elsewhere.
    residual : ndarray of shape (2F, P)
        ``r``, the residual interpolated inside a gap and held beyond a track's ends.
    distance : ndarray of shape (2F, P)
        d, frames to the nearest observed frame of the point; inf at observed entries and for
        a point seen in no frame (no correction there).
    inside : ndarray of shape (2F, P), bool
        Between two observed frames of the point.
    """

    track: np.ndarray
    residual: np.ndarray
    distance: np.ndarray
    inside: np.ndarray

    def correction(self, gap: GapFill) -> np.ndarray:
        """``a (w - v) + (1 - a) b r`` (see :func:`correction`), of the shape of the pieces."""
        out = _weight(self.distance, gap.residual) * self.residual
        if gap.track > 0:
            moved = np.where(self.inside, _weight(self.distance, gap.track), 0.0)
            out += moved * (self.track - out)
        return out

    def at(self, mask: np.ndarray) -> Pieces:
        """The pieces at the entries of a (2F, P) mask, as 1-d arrays."""
        return Pieces(self.track[mask], self.residual[mask], self.distance[mask], self.inside[mask])


def pieces(W: np.ndarray, values: np.ndarray, visibility: np.ndarray) -> Pieces:
    """:class:`Pieces` of the completion ``values`` (2F, P) of W (2F, P; read at the observed
    entries of ``visibility``, (F, P) bool). O(F P)."""
    n_frames, n_points = visibility.shape
    shape = (n_frames, 2, n_points)
    previous, following = nearest_observed(visibility)
    to_previous, to_next = _distances(previous, following)
    before, after = previous >= 0, following < n_frames
    previous, following = np.clip(previous, 0, n_frames - 1), np.clip(following, 0, n_frames - 1)
    # The next frame's share: by distance inside a gap, all of it before the first frame seen.
    inside = before & after & ~visibility
    span = np.where(inside, to_previous + to_next, 1.0)
    share = np.where(inside, to_previous / span, np.where(before, 0.0, 1.0))[:, None, :]
    distance = np.where(visibility, np.inf, np.minimum(to_previous, to_next))
    residual = np.where(np.repeat(visibility, 2, axis=0), W - values, 0.0).reshape(shape)
    held = _take_frames(residual, previous) * (1.0 - share)
    held += _take_frames(residual, following) * share
    tracks = W.reshape(shape)
    track = _take_frames(tracks, previous) * (1.0 - share)
    track += _take_frames(tracks, following) * share
    track -= values.reshape(shape)
    track *= inside[:, None, :]
    rows = (2 * n_frames, n_points)
    return Pieces(
        track.reshape(rows),
        held.reshape(rows),
        np.repeat(distance, 2, axis=0),
        np.repeat(inside, 2, axis=0),
    )


def correction(
    W: np.ndarray, values: np.ndarray, visibility: np.ndarray, gap: GapFill
) -> np.ndarray:
    """How far each hidden entry moves from the completion, (2F, P).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Measurements; read at the observed entries only.
    values : ndarray of shape (2F, P)
        The completion.
    visibility : ndarray of shape (F, P), bool
        True where observed.
    gap : GapFill

    Returns
    -------
    ndarray of shape (2F, P)
        ``a (w - v) + (1 - a) b r`` at a hidden entry: v the completion, w the track
        interpolated linearly between the observed frames on either side (a = 0 before the
        first or after the last observed frame), r the residual ``W - values`` interpolated
        the same way (held beyond the ends), ``a = exp(-d / gap.track)``,
        ``b = exp(-d / gap.residual)`` and d the distance to the nearer observed frame. 0 at
        observed entries and for a point seen in no frame.
    """
    if not gap.corrects:
        return np.zeros(W.shape)
    return pieces(W, values, visibility).correction(gap)


def _weight(distance: np.ndarray, decay: float) -> np.ndarray:
    """``exp(-distance / decay)``: 0 everywhere for decay 0, 1 at finite distances for inf
    (0 at infinite ones)."""
    if decay <= 0.0:
        return np.zeros_like(distance)
    if np.isinf(decay):
        return np.isfinite(distance).astype(np.float64)
    return np.exp(-distance / decay)


def _take_frames(tracks: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """``tracks[frames[f, p], :, p]`` as (F, 2, P)."""
    return np.take_along_axis(tracks, frames[:, None, :].repeat(2, axis=1), axis=0)


def filled(values: np.ndarray, W: np.ndarray, visibility: np.ndarray, gap: GapFill) -> np.ndarray:
    """W at the observed entries, ``values`` moved by the :func:`correction` at the hidden
    ones, (2F, P)."""
    mask = np.repeat(visibility, 2, axis=0)
    return np.where(mask, W, values + correction(W, values, visibility, gap))
