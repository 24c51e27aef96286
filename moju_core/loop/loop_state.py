"""The state of the ADMM loop (:mod:`moju_core.loop.admm`) between two of its steps.

:class:`LoopSettings` holds what the parameters and the input fix for the whole loop. Every
step of Algorithm 1 reads and updates a :class:`LoopState` (the shapes, their low-rank
copy, the multiplier, the penalty, the groups) and, for the adaptive grouping, a
:class:`GroupCoefficients` (the LRR variables of the groups' Grassmann points). The shapes
are kept in per-frame form ``(F, 3, P)``; the trajectory form ``S`` (3F x P) and the shape
form ``S#`` (F x 3P) are free reshapes of it (:attr:`LoopState.trajectories`,
:attr:`LoopState.shape_form`). Point-indexed arrays are kept permuted into group order, so
that every group is a contiguous column block; :meth:`LoopState.permute` reorders all of them
together.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from moju_core.cameras import projection as camera
from moju_core.defaults import (
    MIN_DEPTH_PRIOR,
    SETTLED_MOVE_FRACTION,
    UNSHRINK_AFTER,
    min_group_size,
)
from moju_core.loop import jump, lrr
from moju_core.params import SolverParams
from moju_core.priors import temporal_prior


def permute_points(points_last: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Reorder the last (point) axis into a new C-contiguous array.

    ``a[:, :, perm]`` would return a non-contiguous layout, and every later reshape of it to
    the trajectory or shape form would silently copy.
    """
    return np.take(points_last, perm, axis=-1)


def flat(array: np.ndarray) -> np.ndarray:
    """``array`` raveled as a view (writes go to it); it must be C-contiguous."""
    if not array.flags.c_contiguous:
        raise ValueError("a flat view needs a C-contiguous array")
    return array.reshape(-1)


def group_bounds(sorted_labels: np.ndarray, n_groups: int) -> np.ndarray:
    """Column bounds of the groups: group i is columns ``bounds[i]:bounds[i + 1]``.

    Parameters
    ----------
    sorted_labels : ndarray of shape (P,), int, non-decreasing
    n_groups : int

    Returns
    -------
    ndarray of shape (n_groups + 1,), int
    """
    return np.concatenate([[0], np.cumsum(np.bincount(sorted_labels, minlength=n_groups))])


@dataclass(eq=False)
class LoopState:
    """Variables of the ADMM loop, point-indexed arrays in group order.

    Attributes
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Camera rotations (refined in the loop when it re-fits them to the shapes).
    tracks : ndarray of shape (F, 2, P)
        Centred measurements; zero where unobserved, and with the masked data term's
        per-frame translation moved into them (:meth:`moju_core.loop.data_terms.SoftTerm.prepare`).
    observed : ndarray of shape (F, P), bool, or None
        Where the points are observed; None: everywhere.
    back_projected : ndarray of shape (F, 3, P)
        ``R_f^T W_f``, the data term's right-hand side.
    normals : ndarray of shape (F, 3)
        Unit viewing direction of every frame (the null space of ``R_f``).
    shapes : ndarray of shape (F, 3, P)
        The shapes S (the S-update's variable).
    sharp : ndarray of shape (F, 3P)
        The low-rank copy S# (the S#-update's variable).
    scaled : ndarray of shape (F, 3P)
        The multiplier L1 stored scaled, ``L1 / rho``: both places it enters (the S-update
        target ``S# + L1/rho`` and the S#-step input ``f(S) - L1/rho``) need it so, and its
        update becomes ``scaled <- (rho / rho_next) (scaled + S# - f(S))``.
    work : ndarray of shape (F, 3P)
        Scratch space of the S- and S#-updates (large arrays are updated in place: allocating
        fresh (F, 3P) arrays every iteration costs more in page faults than the arithmetic).
    reprojection : ndarray of shape (F, 2, P)
        Scratch space of the reprojection residual ``R S - W``.
    rho : float
        The penalty parameter.
    order : ndarray of shape (P,), int
        Column j holds input point ``order[j]`` (the paper's ordering vector).
    labels : ndarray of shape (P,), int, non-decreasing
        Group of every column.
    n_groups : int
        Number of groups K.
    bounds : ndarray of shape (K + 1,), int
        Group i is columns ``bounds[i]:bounds[i + 1]``.
    features : ndarray of shape (P, c), or None
        Track coordinates of the spatial neighbour graph; None without local groups.
    bases : ndarray of shape (K, 3F, p), or None
        The groups' Grassmann points; None before the first regrouping.
    grouping_settled : bool
        The last regrouping moved at most ``SETTLED_MOVE_FRACTION`` of the trajectories.
    label_changes : int
        Trajectories moved between groups so far (summed over the regroupings).
    svt_warm : WarmStart
        The S#-update's vectors from one iteration to the next
        (:class:`moju_core.loop.lrr.WarmStart`).
    depth_pull : ndarray of shape (F, P) or None
        The exact fit's constant term (:func:`moju_core.priors.temporal_prior.depth_pull`), kept
        once computed (the exact fit's translation is the tracks' own:
        :class:`moju_core.loop.data_terms.ExactTerm`).
    measured : ndarray of shape (F, P), bool, or None
        With an exact fit of tracks with hidden entries, the observed entries (fitted exactly;
        the other entries of ``observed`` softly); None otherwise.
    anchor : ndarray of shape (F, 3, P) or None
        The shapes a surface prior pulls towards (:class:`moju_core.loop.data_terms.AnchoredTerm`);
        None otherwise.
    unobserved : ndarray of int or None
        The entries ``observed`` leaves out, as indices into the raveled (F, 2, P) tracks,
        once computed (:meth:`unobserved_entries`); reset when the points are permuted.
    """

    rotations: np.ndarray
    tracks: np.ndarray
    observed: np.ndarray | None
    back_projected: np.ndarray
    normals: np.ndarray
    shapes: np.ndarray
    sharp: np.ndarray
    scaled: np.ndarray
    work: np.ndarray
    reprojection: np.ndarray
    rho: float
    order: np.ndarray
    labels: np.ndarray
    n_groups: int
    bounds: np.ndarray
    features: np.ndarray | None = None
    bases: np.ndarray | None = None
    grouping_settled: bool = True
    label_changes: int = 0
    svt_warm: lrr.WarmStart = field(default_factory=lrr.WarmStart)
    depth_pull: np.ndarray | None = None
    measured: np.ndarray | None = None
    anchor: np.ndarray | None = None
    unobserved: np.ndarray | None = None

    def unobserved_entries(self) -> np.ndarray:
        """The entries not in ``observed`` (which must be set) as indices into the raveled
        (F, 2, P) tracks (both coordinates), cached: they are few, and indexing them by flat
        indices is about 5x faster than by (frames, :, points) and than masking (F, P)."""
        if self.unobserved is None:
            frames, points = np.nonzero(~self.observed)
            rows = (frames[:, None] * 2 + np.arange(2)).ravel()
            self.unobserved = rows * self.n_points + np.repeat(points, 2)
        return self.unobserved

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return int(self.shapes.shape[2])

    @property
    def trajectories(self) -> np.ndarray:
        """The shapes in trajectory form S, shape (3F, P): a view, writes go to the shapes."""
        return self.shapes.reshape(3 * self.n_frames, self.n_points)

    @property
    def shape_form(self) -> np.ndarray:
        """The shapes in shape form f(S), shape (F, 3P): a view, writes go to the shapes."""
        return self.shapes.reshape(self.n_frames, 3 * self.n_points)

    def permute(self, perm: np.ndarray) -> None:
        """Reorder the columns of every point-indexed array by ``perm`` (``a <- a[..., perm]``).

        ``perm`` sorts ``labels[perm]`` into groups; ``order`` and ``bounds`` follow, and
        the scratch arrays are reallocated in the new layout.

        Parameters
        ----------
        perm : ndarray of shape (P,), int
            A permutation of the columns.
        """
        n_frames, n_points = self.n_frames, self.n_points
        self.labels = self.labels[perm]
        self.order = self.order[perm]
        self.back_projected = permute_points(self.back_projected, perm)
        self.tracks = permute_points(self.tracks, perm)
        if self.observed is not None:
            self.observed = permute_points(self.observed, perm)
            self.unobserved = None
        if self.measured is not None:
            self.measured = permute_points(self.measured, perm)
        if self.anchor is not None:
            self.anchor = permute_points(self.anchor, perm)
        if self.features is not None:
            self.features = self.features[perm]
        self.shapes = permute_points(self.shapes, perm)
        if self.depth_pull is not None:
            self.depth_pull = permute_points(self.depth_pull, perm)
        self.sharp = permute_points(self.sharp.reshape(n_frames, 3, n_points), perm).reshape(
            n_frames, -1
        )
        self.scaled = permute_points(self.scaled.reshape(n_frames, 3, n_points), perm).reshape(
            n_frames, -1
        )
        self.work = np.empty_like(self.sharp)
        self.reprojection = np.empty_like(self.tracks)
        self.bounds = group_bounds(self.labels, self.n_groups)

    def inverse_order(self) -> np.ndarray:
        """The permutation back to the input's point order: ``a[..., inverse_order()]``."""
        inverse = np.empty_like(self.order)
        inverse[self.order] = np.arange(self.n_points)
        return inverse


def initial_state(
    tracks: np.ndarray,
    rotations: np.ndarray,
    rho: float,
    observed: np.ndarray | None,
    measured: np.ndarray | None = None,
) -> LoopState:
    """The loop's start: ``S = S# = pinv(R) W`` (zero depth), zero multiplier, one group.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
        Centred measurements; for a masked input, the hidden entries at their completion
        (:mod:`moju_core.completion.missing`), which the start uses and the data term does not.
    rotations : ndarray of shape (F, 2, 3)
    rho : float
        Initial penalty parameter.
    observed : ndarray of shape (F, P), bool, or None
        The entries the data term fits.
    measured : ndarray of shape (F, P), bool, optional
        :attr:`LoopState.measured`.

    Returns
    -------
    LoopState
        In the input's point order, all points in group 0 (see :meth:`LoopState.permute`).
    """
    n_frames, _, n_points = tracks.shape
    start = camera.back_project(rotations, tracks)
    if observed is not None:
        # The unobserved entries carry no data: zero there, so that the S-update's right-hand
        # side uses the observed entries only.
        tracks = np.where(observed[:, None, :], tracks, 0.0)
    sharp = start.reshape(n_frames, 3 * n_points).copy()
    labels = np.zeros(n_points, dtype=np.int64)
    return LoopState(
        rotations=rotations,
        tracks=tracks,
        observed=observed,
        measured=measured,
        back_projected=camera.back_project(rotations, tracks),
        normals=camera.viewing_directions(rotations),
        shapes=start,
        sharp=sharp,
        scaled=np.zeros_like(sharp),
        work=np.empty_like(sharp),
        reprojection=np.empty_like(tracks),
        rho=rho,
        order=np.arange(n_points),
        labels=labels,
        n_groups=1,
        bounds=group_bounds(labels, 1),
    )


@dataclass(eq=False)
class GroupCoefficients:
    """The LRR variables over the groups' Grassmann points (steps 4-8 and 11).

    Attributes
    ----------
    coefficients : ndarray of shape (K, K)
        C, the self-expression coefficients.
    aux : ndarray of shape (K, K)
        Z, the nuclear-norm copy of C.
    multiplier : ndarray of shape (K, K)
        L2, the multiplier of ``C = Z`` (unscaled).
    kernel : (ndarray of shape (K,), ndarray of shape (K, K))
        Eigendecomposition of the kernel Gamma (:func:`moju_core.loop.lrr.kernel_eigh`), set by
        every regrouping.
    delta : ndarray of shape (3F, d)
        The jump map Delta to the low-dimensional manifold (``moju`` only).
    """

    coefficients: np.ndarray
    aux: np.ndarray
    multiplier: np.ndarray
    kernel: tuple[np.ndarray, np.ndarray]
    delta: np.ndarray

    @classmethod
    def initial(cls, n_groups: int, n_frames: int, low_dim: int, seed: int) -> GroupCoefficients:
        """Zero C, Z, L2 and kernel; ``Delta = [I_d; small random]`` with ``d <= 3F``."""
        zeros = np.zeros((n_groups, n_groups))
        d_low = min(low_dim, 3 * n_frames)
        delta = jump.initial_map(3 * n_frames, d_low, np.random.default_rng(seed))
        return cls(
            coefficients=zeros,
            aux=np.zeros_like(zeros),
            multiplier=np.zeros_like(zeros),
            kernel=lrr.kernel_eigh(np.zeros_like(zeros)),
            delta=delta,
        )


@dataclass(frozen=True)
class LoopSettings:
    """What the parameters and the input fix for the whole loop (:func:`loop_settings`).

    Attributes
    ----------
    params : SolverParams
        Fully resolved parameters.
    local : bool
        Local groups (not ``bmm``, more than one group): steps 2 and 9 run.
    adaptive : bool
        The groups adapt (``grouping="adaptive"``): steps 4-8 and the Z-update run too. With
        ``grouping="fixed"`` (an ablation) the initial groups stay, and each is still
        reconstructed on its own subspace (steps 2 and 9).
    prior : TemporalPrior or None
        The temporal smoothness prior (None for ``smoothness=0``). The data term solves it
        in the S-update or the S#-update filters by it
        (:attr:`moju_core.loop.data_terms.DataTerm.solves_prior`).
    kept_values : int
        Singular values of S# left unshrunk in the first
        :data:`~moju_core.defaults.UNSHRINK_AFTER` iterations: 1 with ``free_mean_shape`` (the
        truncated nuclear norm), else 0.
    unshrunk_values : int
        Singular values of S# left unshrunk after them (``params.unshrunk_values``).
    min_size : int
        Smallest group size (:func:`moju_core.defaults.min_group_size`).
    settled_moves : int
        A regrouping that moves at most this many trajectories leaves the grouping settled.
    """

    params: SolverParams
    local: bool
    adaptive: bool
    prior: temporal_prior.TemporalPrior | None
    kept_values: int
    unshrunk_values: int
    min_size: int
    settled_moves: int

    def kept_at(self, iteration: int) -> int:
        """Singular values of S# the S#-update leaves unshrunk at ``iteration`` (1-based)."""
        return self.kept_values if iteration <= UNSHRINK_AFTER else self.unshrunk_values


def fits_exactly(exact_data: bool, refine_rotations: bool, smoothness: float) -> bool:
    """Whether a loop fits the tracks exactly (:func:`moju_core.priors.temporal_prior.depth_step`).

    Only noise-free tracks (``exact_data``) seen by fixed cameras, with a prior strong enough
    to set the depths (``smoothness >=`` :data:`~moju_core.defaults.MIN_DEPTH_PRIOR`). With
    hidden entries the observed ones are fitted exactly and the others softly
    (:func:`moju_core.priors.temporal_prior.masked_depth_step`). Refined cameras are corrected
    through the data term's misfit, which an exact fit removes (paper, windowed cameras 20
    degrees off: e3D 0.009 soft, 0.103 exact).
    """
    return exact_data and not refine_rotations and smoothness >= MIN_DEPTH_PRIOR


def loop_settings(params: SolverParams, n_frames: int, n_points: int) -> LoopSettings:
    """The :class:`LoopSettings` of a solve, derived once before the first iteration.

    Parameters
    ----------
    params : SolverParams
        Fully resolved parameters (:func:`moju_core.defaults.resolve`).
    n_frames, n_points : int
        F and P.
    """
    local = params.method != "bmm" and params.n_groups > 1
    prior = (
        temporal_prior.temporal_prior(n_frames, params.smoothness) if params.smoothness else None
    )
    return LoopSettings(
        params=params,
        local=local,
        adaptive=local and params.grouping == "adaptive",
        prior=prior,
        kept_values=1 if params.free_mean_shape else 0,
        unshrunk_values=params.unshrunk_values,
        min_size=min_group_size(params.subspace_dim),
        settled_moves=int(SETTLED_MOVE_FRACTION * n_points),
    )
