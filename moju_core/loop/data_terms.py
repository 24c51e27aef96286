"""The data terms of the S-update: how the shapes are fitted to the tracks.

One term per case, each owning its S-step (step 1 of Algorithm 1) and its residual, chosen
once per solve by :func:`choose_term`:

======================  ==============================================================
:class:`SoftTerm`       ``||R S - W||^2`` over the fitted entries, a 3 x 3 solve per frame
                        and point; with hidden entries the per-frame translation is an
                        unknown of the term too (:meth:`SoftTerm.prepare`).
:class:`BandedPriorTerm` the same data with the temporal prior solved exactly in the
                        S-update (a banded solve over the frames), for cameras the loop
                        refines; hidden entries at the current shapes' projection.
:class:`ExactTerm`      the tracks fitted exactly, the temporal prior setting the depths
                        only: noise-free tracks seen by fixed cameras.
:class:`MaskedExactTerm` the exact fit of the measured entries, the other fitted entries
                        softly; abandoned when it throws hidden entries off the object.
:class:`AnchoredTerm`   the soft data term plus a pull towards given shapes (a surface
                        prior's), which sets the depths the tracks do not.
======================  ==============================================================

A term is built over the entries it fits (``observed``) and, for the masked exact fit, the
ones it fits exactly (``measured``), in the input's point order; the loop's
:class:`~moju_core.loop.loop_state.LoopState` takes them from it and keeps them in group
order, and the steps read the state's copies. :meth:`DataTerm.residual` is a metric:
it changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from moju_core.cameras import projection as camera
from moju_core.loop.loop_state import LoopState, flat
from moju_core.priors import temporal_prior
from moju_core.priors.temporal_prior import TemporalPrior

#: Iterations between two :meth:`DataTerm.gone_astray` checks: a diverging masked exact fit
#: grows about twofold per iteration, so a check every ten finds it within a few tens of
#: iterations at a small cost.
ABANDON_CHECK_EVERY = 10


@dataclass(eq=False)
class DataTerm:
    """The data term of the S-update (base class: the soft fit of every entry).

    Attributes
    ----------
    observed : ndarray of shape (F, P), bool, or None
        The fitted entries, input order (None: all).
    measured : ndarray of shape (F, P), bool, or None
        The entries fitted exactly (masked exact fit only).
    n_observed : int
        Fitted (frame, point) entries.
    frame_counts : ndarray of shape (F, 1), float, or None
        Fitted points per frame; None when every entry is fitted.
    """

    #: Short name, recorded in the solve plan.
    name: ClassVar[str] = "soft"
    #: Whether the term fits the tracks exactly (the loop's tolerance then follows the
    #: rounding of the exact fit, :func:`moju_core.loop.stopping.loop_tolerance`).
    exact: ClassVar[bool] = False
    #: Whether the S-step solves the temporal prior itself (else the S#-update filters by it).
    solves_prior: ClassVar[bool] = False

    observed: np.ndarray | None = field(repr=False)
    n_observed: int
    frame_counts: np.ndarray | None = field(default=None, repr=False)
    measured: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def over(
        cls, n_frames: int, n_points: int, observed: np.ndarray | None, **extra: object
    ) -> DataTerm:
        """The term over the entries ``observed`` (F, P) bool (None: all of them)."""
        if observed is None:
            return cls(None, n_frames * n_points, None, **extra)
        counts = observed.sum(axis=1)[:, None].astype(float)
        return cls(observed, int(observed.sum()), counts, **extra)

    def start(self, state: LoopState) -> None:
        """What the term sets in a fresh state (input point order); nothing here: the loop
        starts from the zero-depth back-projection of the tracks."""

    def prepare(self, state: LoopState, iteration: int) -> None:
        """What the term updates before the S-step of ``iteration`` (1-based); nothing here."""

    def shape_step(self, state: LoopState, prior: TemporalPrior | None, target: np.ndarray) -> None:
        """The S-update towards ``target`` (F, 3, P) = ``S# + L1/rho``, in place on the shapes.

        Per frame and point a 3 x 3 solve over the fitted entries
        (:func:`moju_core.cameras.projection.data_step`); O(F P).
        """
        self._soft_step(state, target, state.rho)

    @staticmethod
    def _soft_step(state: LoopState, target: np.ndarray, penalty: float) -> None:
        """``argmin ||R S - W||^2 + penalty/2 ||S - target||^2`` over the fitted entries."""
        camera.data_step(
            state.back_projected,
            state.normals,
            target,
            penalty,
            out=state.shapes,
            observed=state.observed,
        )

    def residual(self, state: LoopState) -> float:
        """RMS of ``R S - W`` over the fitted entries, in the tracks' units; O(F P).

        With hidden entries and a soft fit, after the best per-frame translation (the one
        :meth:`prepare` moves into the tracks before the next S-step).
        """
        squared, sums = self._squared_residual(state)
        if sums is not None and not self.exact:
            shift = sums / self.frame_counts
            # Over the n_f fitted entries of a frame, sum (r - shift)^2 = sum r^2 - shift * sum r.
            squared = max(squared - float(np.vdot(shift, sums)), 0.0)
        return float(np.sqrt(squared / (2 * self.n_observed)))

    def gone_astray(self, state: LoopState, iteration: int) -> bool:
        """Whether the loop should stop because the fit has left the object; never here."""
        return False

    def _squared_residual(self, state: LoopState) -> tuple[float, np.ndarray | None]:
        """Sum of squared residuals over the fitted entries, and with hidden entries the
        per-frame sums of the residuals (F, 2). Into the state's scratch array."""
        reprojection = camera.project(state.rotations, state.shapes, out=state.reprojection)
        reprojection -= state.tracks
        if state.observed is None:
            return float(np.vdot(reprojection, reprojection)), None
        # Zeroed at the few unobserved entries (cheaper than masking).
        flat(reprojection)[state.unobserved_entries()] = 0.0
        return float(np.vdot(reprojection, reprojection)), reprojection.sum(axis=2)


class SoftTerm(DataTerm):
    """``||R S - W||^2`` over the fitted entries (the paper's data term).

    With hidden entries the per-frame translation is an unknown of the masked term: the
    tracks are centred on all points, completed ones included, and the mean residual of a
    frame's fitted points is what the translation should absorb.
    """

    name = "soft"

    def prepare(self, state: LoopState, iteration: int) -> None:
        """From the second iteration on, with hidden entries: move each frame's mean residual
        into its tracks (and the data term's right-hand side, linear in them); O(F P).

        Into every entry: no step reads the tracks at an unfitted entry (the soft and banded
        steps mask or fill them), so moving them too changes nothing and saves indexing them.
        """
        if state.observed is None or iteration == 1:
            return
        _, sums = self._squared_residual(state)
        shift = sums / self.frame_counts  # (F, 2), R S - W on average
        state.tracks += shift[:, :, None]
        state.back_projected += np.einsum("fji,fj->fi", state.rotations, shift)[:, :, None]


class BandedPriorTerm(SoftTerm):
    """The soft data term with the temporal prior solved in the S-update.

    A banded solve over the frames per point
    (:func:`moju_core.priors.temporal_prior.smooth_data_step`), which needs every entry: the
    hidden ones take the current shapes' projection (a majoriser of the masked data term,
    :func:`moju_core.cameras.projection.fill_unobserved`). Used when the loop refines the
    cameras, where filtering S# instead would fight the camera refit; O(F P).
    """

    name = "banded-prior"
    solves_prior = True

    def shape_step(self, state: LoopState, prior: TemporalPrior | None, target: np.ndarray) -> None:
        if state.observed is not None:
            filled = camera.fill_unobserved(
                state.rotations, state.tracks, state.shapes, state.observed
            )
            state.back_projected = camera.back_project(state.rotations, filled)
        temporal_prior.smooth_data_step(
            state.back_projected, state.normals, target, state.rho, prior, state.shapes
        )


class ExactTerm(DataTerm):
    """The tracks fitted exactly; the temporal prior sets the depths only.

    :func:`moju_core.priors.temporal_prior.depth_step`, a banded solve per point along the
    viewing directions; O(F P). For tracks without measurable noise seen by fixed cameras.
    Its translation is the tracks' own: moving a frame's translation by ``t`` and its shape
    by ``-R_f^T t`` leaves every residual as it is, so the term cannot determine it.
    """

    name = "exact"
    exact = True
    solves_prior = True

    def shape_step(self, state: LoopState, prior: TemporalPrior | None, target: np.ndarray) -> None:
        self._pull(state, prior)
        temporal_prior.depth_step(
            state.back_projected,
            state.normals,
            target,
            state.rho,
            prior,
            state.shapes,
            pull=state.depth_pull,
        )

    @staticmethod
    def _pull(state: LoopState, prior: TemporalPrior | None) -> None:
        """The exact fit's constant term, computed once (the tracks do not move)."""
        if state.depth_pull is None:
            state.depth_pull = temporal_prior.depth_pull(state.back_projected, state.normals, prior)


@dataclass(eq=False)
class MaskedExactTerm(ExactTerm):
    """The measured entries fitted exactly, the other fitted entries softly, the rest free.

    :func:`moju_core.priors.temporal_prior.masked_depth_step`; O(F P). Such a fit can throw
    hidden stretches of track far off the object (it does not come back); :meth:`gone_astray`
    tells the caller, which then solves softly.

    Attributes
    ----------
    limit : float
        A reconstructed point further than this from its frame's centroid is off the object.
    """

    name = "masked-exact"
    limit: float = float("inf")

    def shape_step(self, state: LoopState, prior: TemporalPrior | None, target: np.ndarray) -> None:
        self._pull(state, prior)
        hidden = ~state.measured
        temporal_prior.masked_depth_step(
            state.back_projected,
            state.measured,
            hidden if state.observed is None else hidden & state.observed,
            state.normals,
            target,
            state.rho,
            prior,
            state.shapes,
            pull=state.depth_pull,
        )

    def gone_astray(self, state: LoopState, iteration: int) -> bool:
        """Every :data:`ABANDON_CHECK_EVERY` iterations: a point beyond ``limit``."""
        return iteration % ABANDON_CHECK_EVERY == 0 and beyond(state.shapes, self.limit)


@dataclass(eq=False)
class AnchoredTerm(SoftTerm):
    """``||R S - W||^2 + weight ||S - A||^2``: the soft data term and a pull towards the
    shapes A of a surface prior (``state.anchor``, (F, 3, P)).

    With cameras that hardly rotate the tracks say nothing about depth, and the nuclear norm
    alone pulls the shapes flat; the anchor keeps the depths of the prior where the low-rank
    model and the local groups have nothing better. Completing the square, the S-update is
    the soft one towards ``(rho T + weight A) / (rho + weight)`` with penalty
    ``rho + weight``; O(F P).

    Attributes
    ----------
    anchor : ndarray of shape (F, 3, P)
        The prior's shapes in the loop's frame and units, input point order; the loop starts
        from them instead of the zero-depth start.
    weight : float
        Weight of the pull, relative to the data term of the scale-normalised tracks.
    """

    name = "anchored"
    anchor: np.ndarray | None = field(default=None, repr=False)
    weight: float = 1.0

    def start(self, state: LoopState) -> None:
        state.anchor = np.ascontiguousarray(self.anchor, dtype=np.float64)
        state.shapes[...] = state.anchor
        state.sharp[...] = state.anchor.reshape(state.sharp.shape)

    def shape_step(self, state: LoopState, prior: TemporalPrior | None, target: np.ndarray) -> None:
        total = state.rho + self.weight
        self._soft_step(state, (state.rho * target + self.weight * state.anchor) / total, total)


def beyond(shapes: np.ndarray, limit: float) -> bool:
    """Whether shapes (F, 3, P) put a point further than ``limit`` from its frame's centroid.

    A first look at the largest coordinate (one pass) rules most cases out: no point is
    further than ``2 sqrt(3)`` times it from a centroid.
    """
    if 2.0 * np.sqrt(3.0) * float(np.abs(shapes).max()) <= limit:
        return False
    centred = shapes - shapes.mean(axis=2, keepdims=True)
    return bool(np.linalg.norm(centred, axis=1).max() > limit)


def choose_term(
    n_frames: int,
    n_points: int,
    observed: np.ndarray | None,
    *,
    exact: bool = False,
    banded_prior: bool = False,
    measured: np.ndarray | None = None,
    limit: float = float("inf"),
) -> DataTerm:
    """The data term of a loop.

    Parameters
    ----------
    n_frames, n_points : int
    observed : ndarray of shape (F, P), bool, or None
        The entries the term fits (None: all).
    exact : bool
        Fit exactly (:func:`moju_core.loop.loop_state.fits_exactly`).
    banded_prior : bool
        Solve the temporal prior in the S-update (refined cameras and a prior); soft only.
    measured : ndarray of shape (F, P), bool, optional
        With ``exact`` and hidden entries: the entries fitted exactly.
    limit : float
        :attr:`MaskedExactTerm.limit`.
    """
    if exact and measured is not None:
        return MaskedExactTerm.over(n_frames, n_points, observed, measured=measured, limit=limit)
    if exact:
        return ExactTerm.over(n_frames, n_points, observed)
    if banded_prior:
        return BandedPriorTerm.over(n_frames, n_points, observed)
    return SoftTerm.over(n_frames, n_points, observed)
