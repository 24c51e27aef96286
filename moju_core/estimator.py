"""The scikit-learn estimator :class:`MoJu`, over :func:`moju_core.reconstruct`."""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.params import Grouping, Method, RotationMethod, SolverParams, SurfacePrior
from moju_core.result import Result
from moju_core.solver import ProgressCallback, reconstruct

#: Constructor parameters that are not solver parameters (how the solve runs, not what it is).
_RUN_PARAMETERS = ("threads", "callback")


class MoJu(BaseEstimator):
    """Dense non-rigid structure from motion (MoJu, Kumar CVPR 2019) as an estimator.

    The hyper-parameters are the fields of :class:`moju_core.SolverParams`, with the same
    names, defaults and meanings (``None``: derived from the data when fitting), plus
    ``threads`` and ``callback`` of :func:`moju_core.reconstruct`. They are stored as given
    and validated by :meth:`fit`, so :func:`sklearn.base.clone`, ``get_params`` and
    ``set_params`` work as for any scikit-learn estimator.

    Attributes
    ----------
    shapes_ : ndarray of shape (F, P, 3), float64
        Per-frame 3D points in the units of W, each frame centred.
    rotations_ : ndarray of shape (F, 2, 3), float64
        Camera rotations used (known or estimated).
    labels_ : ndarray of shape (P,), int64
        Local group of every point after the last regrouping.
    n_iter_ : int
        Iterations run.
    stop_reason_ : StopReason
        Why the loop stopped (``"converged"``, ``"rho_max"`` or ``"max_iter"``).
    diagnostics_ : Diagnostics
        By-products of the solve: local groups used, where the rotations came from, the noise
        variance of the tracks (squared units of W), the smoothness trials, ...
    result_ : Result
        Everything :func:`moju_core.reconstruct` returned (history, timings, the resolved
        parameters in ``result_.params``).

    Examples
    --------
    >>> from moju_core import MoJu
    >>> from moju_core.datasets import make_sequence
    >>> face = make_sequence("face1", n_points=300)
    >>> model = MoJu(max_iter=30).fit(face.W)
    >>> model.shapes_.shape
    (10, 300, 3)
    """

    def __init__(
        self,
        *,
        method: Method = "moju",
        rotations: RotationMethod | None = None,
        n_bases: int | None = None,
        n_groups: int | None = None,
        subspace_dim: int | None = None,
        low_dim: int | None = None,
        n_clusters: int | None = None,
        n_neighbors: int = 8,
        grouping: Grouping = "adaptive",
        beta1: float | None = None,
        beta2: float | None = None,
        beta3: float | None = None,
        smoothness: float | None = None,
        surface_prior: SurfacePrior = "auto",
        free_mean_shape: bool | None = None,
        unshrunk_values: int | None = None,
        trajectory_bases: int | None = None,
        regroup_every: int = 10,
        max_iter: int = 300,
        tol: float = 1e-10,
        rho: float = 1e-2,
        rho_max: float = 1e8,
        rho_growth: float = 1.1,
        seed: int = 0,
        threads: int | None = None,
        callback: ProgressCallback | None = None,
    ) -> None:
        self.method = method
        self.rotations = rotations
        self.n_bases = n_bases
        self.n_groups = n_groups
        self.subspace_dim = subspace_dim
        self.low_dim = low_dim
        self.n_clusters = n_clusters
        self.n_neighbors = n_neighbors
        self.grouping = grouping
        self.beta1 = beta1
        self.beta2 = beta2
        self.beta3 = beta3
        self.smoothness = smoothness
        self.surface_prior = surface_prior
        self.free_mean_shape = free_mean_shape
        self.unshrunk_values = unshrunk_values
        self.trajectory_bases = trajectory_bases
        self.regroup_every = regroup_every
        self.max_iter = max_iter
        self.tol = tol
        self.rho = rho
        self.rho_max = rho_max
        self.rho_growth = rho_growth
        self.seed = seed
        self.threads = threads
        self.callback = callback

    def solver_params(self) -> SolverParams:
        """The hyper-parameters as validated :class:`SolverParams` (pydantic's ValidationError,
        a ValueError, names any that is out of range)."""
        values = self.get_params()
        return SolverParams(**{k: v for k, v in values.items() if k not in _RUN_PARAMETERS})

    def fit(
        self,
        W: np.ndarray,
        rotations: np.ndarray | None = None,
        visibility: np.ndarray | None = None,
        intrinsics: Intrinsics | None = None,
    ) -> MoJu:
        """Reconstruct the shapes and cameras of the tracks W.

        Parameters
        ----------
        W : array_like of shape (2F, P)
            Rows ``2f`` and ``2f + 1`` are the x and y image coordinates of frame f; NaN where
            a point is not observed.
        rotations : array_like of shape (F, 2, 3), optional
            Known camera rotations; used by the rule of :func:`moju_core.reconstruct`
            (``rotations=None`` or ``"known"``; an estimating method with them is an error).
        visibility : array_like of shape (F, P), bool, optional
            True where a point is observed.
        intrinsics : Intrinsics, optional
            The camera of W's pixels: the solve is then perspective (see
            :func:`moju_core.reconstruct`).

        Returns
        -------
        self
        """
        result = reconstruct(
            W,
            self.solver_params(),
            rotations=rotations,
            visibility=visibility,
            intrinsics=intrinsics,
            callback=self.callback,
            threads=self.threads,
        )
        self._set_fitted(result)
        return self

    def _set_fitted(self, result: Result) -> None:
        self.result_ = result
        self.shapes_ = result.shapes
        self.rotations_ = result.rotations
        self.labels_ = result.labels
        self.n_iter_ = result.n_iter
        self.stop_reason_ = result.stop_reason
        self.diagnostics_ = result.diagnostics
