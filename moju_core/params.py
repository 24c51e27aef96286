"""Solver parameters: the one schema shared by the library, the CLI, the API and the worker.

Every field that is ``None`` is derived from the data by :func:`moju_core.defaults.resolve`
with a documented rule, so a user never has to tune anything by hand; every derived value can
be overridden by setting the field.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Method = Literal["moju", "sdg", "bmm", "pta"]
#: The surface prior of a solve with a known camera (:mod:`moju_core.perspective`).
SurfacePrior = Literal["auto", "isometric", "none"]
RotationMethod = Literal["auto", "intersection", "windowed", "rigid", "plane", "known"]
Grouping = Literal["adaptive", "fixed"]


class SolverParams(BaseModel):
    """Parameters of :func:`moju_core.reconstruct`.

    Unknown keys are rejected (``extra="forbid"``) so that a typo in a parameter name is an
    error and not a silently ignored setting.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: Method = Field(
        "moju",
        description=(
            "'moju': local subspaces clustered on the low-dimensional Grassmann manifold "
            "(the paper); 'sdg': the same loop clustering the high-dimensional Grassmann "
            "points directly (Kumar et al. CVPR 2018 in spirit); 'bmm': only the nuclear norm "
            "of the shape matrix (Dai et al.'s prior-free method, no local groups); 'pta': "
            "trajectories in a DCT basis of size trajectory_bases, one least-squares solve "
            "(Akhter et al.'s point trajectory approach, no iterations)."
        ),
    )
    rotations: RotationMethod | None = Field(
        None,
        description=(
            "How camera rotations are obtained. Unset: 'known' when rotations are supplied "
            "with the input, else 'auto'. 'intersection' (Dai et al.'s method), "
            "'windowed' (rigid factorisations of short windows of frames, chained, then "
            "refined with the shapes; for a camera that turns fast relative to the "
            "deformation), 'auto' (intersection, unless the windowed rotations explain the "
            "tracks as nearly rigid over every three frames far better), 'rigid' "
            "(Tomasi-Kanade with metric upgrade), 'plane' (a sheet's rotations from the "
            "calibration of its dominant plane, robust over groups of tracks) or 'known' "
            "(supplied with the input; an estimating method with supplied rotations is "
            "refused as a contradiction)."
        ),
    )
    n_bases: int | None = Field(
        None, ge=1, le=10, description="Number of shape bases K for rotation estimation."
    )
    n_groups: int | None = Field(
        None, ge=1, le=5000, description="Number of local trajectory groups (Grassmann points)."
    )
    subspace_dim: int | None = Field(
        None, ge=1, le=30, description="Dimension p of each local subspace."
    )
    low_dim: int | None = Field(
        None, ge=1, le=300, description="Dimension of the low-dimensional Grassmann manifold."
    )
    n_clusters: int | None = Field(
        None, ge=1, le=5000, description="Number of spectral clusters of Grassmann points."
    )
    n_neighbors: int = Field(
        8,
        ge=1,
        le=1000,
        description=(
            "Spatial neighbours per group in the similarity graph; a value of at least "
            "n_groups - 1 connects every pair of groups (the full graph)."
        ),
    )
    grouping: Grouping = Field(
        "adaptive",
        description=(
            "'adaptive': the groups follow the subspace structure (graph, jump, LRR and "
            "clustering steps 4-8 move trajectories between groups); 'fixed': the initial "
            "k-means groups are kept and steps 4-8 are skipped (local reconstruction only, an "
            "ablation). Ignored by 'bmm' and 'pta'."
        ),
    )
    beta1: float | None = Field(None, gt=0, le=1e6, description="Weight of the LRR error term.")
    beta2: float | None = Field(
        None, gt=0, le=1e6, description="Weight of the nuclear norm of the shape matrix S#."
    )
    beta3: float | None = Field(
        None, gt=0, le=1e6, description="Weight of the nuclear norm of the coefficients Z."
    )
    smoothness: float | None = Field(
        None,
        ge=0,
        le=1e6,
        description=(
            "Weight gamma of the temporal smoothness prior gamma/2 ||D S||^2 on the second "
            "differences of every 3D trajectory along the frames, relative to the data term "
            "of the scale-normalised tracks. Unset: 'moju' and 'sdg' choose it from the data "
            "(the largest weight the tracks do not contradict), 'bmm' uses 0. 0 turns it off "
            "(the paper's loop). Ignored by 'pta'."
        ),
    )
    surface_prior: SurfacePrior = Field(
        "auto",
        description=(
            "The surface prior that gives depth without camera rotation, for tracks with a "
            "known camera (intrinsics): 'isometric' starts from the maximum-depth shapes of an "
            "inextensible surface seen in perspective and keeps the loop close to them; "
            "'none' solves orthographically as without a camera. 'auto': 'isometric' when "
            "intrinsics are given, else 'none'."
        ),
    )
    free_mean_shape: bool | None = Field(
        None,
        description=(
            "Leave the largest singular value of S# (the mean shape) out of the nuclear norm, "
            "so that only the deformation is penalised. Unset: true for 'moju' and 'sdg', "
            "false for 'bmm' (Dai et al. penalise all of S#). Ignored by 'pta'."
        ),
    )
    unshrunk_values: int | None = Field(
        None,
        ge=0,
        le=100,
        description=(
            "Leading singular values of S# left out of the nuclear norm once the loop has run "
            "its first 20 iterations (before then: 1 with free_mean_shape, else 0). Values "
            "left out are not shrunk, so the deformations they carry keep their depth. Unset: "
            "'moju' and 'sdg' leave out min(k, max(4, ceil(r / 3))) when the cameras "
            "determine a trajectory basis of k >= 3 cosines (PTA's well-conditioned size), "
            "the smoothness is at least 10 and the tracks are free of measurable noise, "
            "otherwise only the mean shape; r is the rank of the tracks above the noise, so "
            "r / 3 the fewest basis shapes that explain them. 'bmm' follows free_mean_shape. "
            "Ignored by 'pta'."
        ),
    )
    trajectory_bases: int | None = Field(
        None,
        ge=1,
        le=1000,
        description=(
            "Size k of the DCT trajectory basis of method 'pta' (needs 3k <= 2F); ignored by "
            "the other methods."
        ),
    )
    regroup_every: int = Field(
        10, ge=1, le=1000, description="Run the grouping steps 4-8 every m-th iteration."
    )
    max_iter: int = Field(300, ge=1, le=10000, description="Iteration cap of the ADMM loop.")
    tol: float = Field(
        1e-10,
        ge=0,
        le=1.0,
        description=(
            "Convergence threshold on the shape gap ||S# - f(S)||_inf; 0 turns the convergence "
            "test off, and the loop runs to rho_max or max_iter."
        ),
    )
    rho: float = Field(1e-2, gt=0, le=1e6, description="Initial penalty parameter.")
    rho_max: float = Field(1e8, gt=0, le=1e12, description="Largest penalty parameter.")
    rho_growth: float = Field(1.1, gt=1.0, le=10.0, description="Penalty growth factor c.")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="Seed of every random choice.")


def rotation_method(requested: RotationMethod | None, has_rotations: bool) -> RotationMethod:
    """The rotation method a solve uses: the one rule of the library, the CLI and the service.

    ``requested`` is ``SolverParams.rotations``; ``has_rotations`` says whether camera rotations
    come with the input (a ``rotations=`` array, or a dataset ``R`` in a file). Unset
    (``None``) means ``"known"`` when they do and ``"auto"`` when they do not; a named method
    is used as it is. Whether the named method and the input agree (``"known"`` without
    rotations, an estimator with rotations) is for the caller to judge: a file's ``R`` may be
    ground truth to score estimated rotations against.
    """
    if requested is not None:
        return requested
    return "known" if has_rotations else "auto"


def as_params(params: object) -> SolverParams | None:
    """``params`` as SolverParams: None stays None, a mapping is validated, others refused."""
    if params is None or isinstance(params, SolverParams):
        return params
    if isinstance(params, Mapping):
        return SolverParams.model_validate(dict(params))
    raise TypeError(
        f"params must be a SolverParams or a mapping such as {{'max_iter': 100}}, not "
        f"{type(params).__name__}"
    )
