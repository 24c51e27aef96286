"""The one entry point: :func:`reconstruct`."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from moju_core import cameras, defaults, feasibility, neighbour_check, perspective, solve_plan
from moju_core.cameras.intrinsics import Intrinsics
from moju_core.cameras.smoothing import smooth_rotations
from moju_core.completion.completed import (
    CompletedTracks,
    camera_tracks,
    complete_tracks,
    trial_tracks,
)
from moju_core.errors import Cancelled, MeasurementError
from moju_core.loop import admm, closed_form, clustering, lrr
from moju_core.loop.data_terms import DataTerm, beyond, choose_term
from moju_core.loop.loop_state import fits_exactly
from moju_core.params import SolverParams, as_params, rotation_method
from moju_core.preprocessing import normalise
from moju_core.priors import discrepancy
from moju_core.priors.signal_fit import signal_fit
from moju_core.priors.smoothness import choose_smoothness
from moju_core.result import (
    Diagnostics,
    Progress,
    Result,
    RotationRigidity,
)
from moju_core.solve_plan import SolvePlan
from moju_core.spectrum import Spectrum, noise_variance, significant_rank, spectrum
from moju_core.validation import check_observations, check_rotations, warn_if_transposed

#: ``callback(progress) -> bool | None``; returning True asks the solver to stop (it then
#: raises :class:`moju_core.errors.Cancelled`).
ProgressCallback = Callable[[Progress], "bool | None"]


class _Reporter:
    """Turns solver events into :class:`Progress` reports and honours cancellation."""

    def __init__(self, callback: ProgressCallback | None, max_iter: int) -> None:
        self.callback = callback
        self.start = time.perf_counter()
        self.loop_start: float | None = None
        self.max_iter = max_iter
        self.expected = max_iter
        self.reported = 0.0  # the fraction never goes back (a second loop extends expected)

    def __call__(
        self, stage: str, iteration: int = 0, gap: float = float("nan"), rho: float = float("nan")
    ) -> None:
        if self.callback is None:
            return
        now = time.perf_counter()
        eta = None
        fraction = {"validating": 0.0, "rotations": 0.01, "initialising": 0.03}.get(stage, 1.0)
        if stage == "iterating":
            if self.loop_start is None:
                self.loop_start = now
            done = min(iteration / self.expected, 1.0)
            fraction = 0.05 + 0.9 * done
            if iteration:
                eta = (now - self.loop_start) / iteration * max(self.expected - iteration, 0)
        fraction = self.reported = max(fraction, self.reported)
        progress = Progress(
            stage=stage,
            iteration=iteration,
            max_iter=self.max_iter,
            gap=gap,
            rho=rho,
            fraction=fraction,
            elapsed=now - self.start,
            eta=eta,
        )
        if self.callback(progress):
            raise Cancelled(f"stopped by the progress callback at stage {stage!r}")


def reconstruct(
    W: np.ndarray,
    params: SolverParams | Mapping[str, Any] | None = None,
    *,
    rotations: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
    intrinsics: Intrinsics | None = None,
    callback: ProgressCallback | None = None,
    threads: int | None = None,
) -> Result:
    """Recover camera rotations and per-frame 3D shapes from dense 2D tracks.

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Measurement matrix: rows ``2f`` and ``2f + 1`` are the x and y image coordinates of
        frame f, column j is point j (any unit, e.g. pixels). NaN (x and y together) where a
        point is not observed in a frame.
    params : SolverParams or mapping, optional
        Solver parameters; ``None`` means all defaults (every ``None`` field is derived from
        the data, see :mod:`moju_core.defaults`). A mapping such as ``{"max_iter": 5}`` is
        validated as :class:`SolverParams`.
    rotations : array_like of shape (F, 2, 3), optional
        Known camera rotations. Used exactly when ``params.rotations`` is ``"known"`` or unset
        (``None``, the default: ``"known"`` when rotations are given, else ``"auto"``; see
        :func:`moju_core.params.rotation_method`). ``"known"`` without them, or an estimating
        method (``"auto"``, ``"intersection"``, ...) with them, raises MeasurementError.
    visibility : array_like of shape (F, P), bool, optional
        True where point j is observed in frame f; it must agree with the NaN of W. The data
        term then runs over the observed entries only, and the shapes of every point in every
        frame are returned (see docs/solver.md, "Missing data").
    intrinsics : Intrinsics, optional
        The camera of W's pixels (:class:`moju_core.cameras.intrinsics.Intrinsics`). With it
        (and ``params.surface_prior`` ``"auto"`` or ``"isometric"``) the solve is
        perspective (:mod:`moju_core.perspective`): the shapes are then in each image's
        camera frame (x right, y down, z along the optical axis), one scale for the sequence
        (the mean depth is 1), not centred, and the rotations are ``[I_2 0]``. Without it the
        tracks are orthographic, any unit.
    callback : callable, optional
        ``callback(progress: Progress) -> bool | None``, called at every stage change and
        every iteration; returning True stops the solver, which raises
        :class:`~moju_core.errors.Cancelled`.
    threads : int or None, default None
        BLAS/OpenMP threads of the solve. ``None`` leaves the caller's setting alone: the solve
        runs on whatever limit is in force where it is called (``threadpoolctl``'s
        ``threadpool_limits`` around the call, ``OPENBLAS_NUM_THREADS``, or the library's
        default of one thread per core). An int sets that limit for the duration of the call
        only. The ``moju`` CLI (``--threads``, default 1) and the service's workers
        (``MOJU_WORKER_THREADS``, default 1) pass theirs: the loop is many medium-sized
        products and memory-bound passes, and on a 2-core machine two OpenBLAS threads made
        it 4-10 times slower as soon as any other process was busy (``benchmarks/speed.py``
        measures both).

    Returns
    -------
    Result
        Shapes (F, P, 3) in the input's units with every frame centred, rotations (F, 2, 3),
        labels (P,), history, timings and the resolved parameters.

    Raises
    ------
    MeasurementError
        When the input cannot be used (with a message saying why and how to fix it).
    Cancelled
        When the callback asks to stop.
    """
    params = as_params(params)
    if threads is None:
        return _reconstruct(W, params, rotations, visibility, intrinsics, callback)
    with threadpool_limits(limits=threads):
        return _reconstruct(W, params, rotations, visibility, intrinsics, callback)


def _reconstruct(
    W: np.ndarray,
    params: SolverParams | None,
    rotations: np.ndarray | None,
    visibility: np.ndarray | None,
    intrinsics: Intrinsics | None,
    callback: ProgressCallback | None,
) -> Result:
    """Validate, complete, estimate the cameras, plan, run the loop, package the result."""
    params = params if params is not None else SolverParams()
    params = _resolve_rotation_method(params, rotations is not None)
    report = _Reporter(callback, params.max_iter)
    start = time.perf_counter()
    report("validating")
    W, visibility, rotations = _validate(W, visibility, rotations, params)
    if perspective.uses_surface_prior(params, intrinsics):
        return _perspective_reconstruct(W, visibility, intrinsics, params, report, start)
    observed = None if visibility.all() else visibility
    completed = None if observed is None else complete_tracks(W, observed)
    measured_tracks = W
    if completed is not None:
        W = completed.W
    centred, scale = normalise(W)

    report("rotations")
    tic = time.perf_counter()
    tracks = _Tracks.measure(centred, scale, completed)
    estimate = _estimate_cameras(tracks, completed, measured_tracks, rotations, params)
    params = params.model_copy(update={"rotations": estimate.source})
    timings = {"rotations": time.perf_counter() - tic}

    report("initialising")
    tic = time.perf_counter()
    solve = _plan(tracks, completed, estimate, params, report)
    report.expected = defaults.expected_iterations(solve.params)
    timings["initialise"] = time.perf_counter() - tic

    tic = time.perf_counter()
    out = _run(solve, estimate, report)
    timings["iterate"] = time.perf_counter() - tic
    report("finishing", out.n_iter)
    timings["total"] = time.perf_counter() - start
    return _package(out, solve, estimate, tracks, completed, visibility, timings)


def _validate(
    W: np.ndarray,
    visibility: np.ndarray | None,
    rotations: np.ndarray | None,
    params: SolverParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """W (2F, P) and visibility (F, P) checked, known rotations (F, 2, 3) checked, and the
    parameters checked against the sizes (with the messages the service gives at
    submission, :mod:`moju_core.feasibility`)."""
    W, visibility = check_observations(W, visibility)
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    warn_if_transposed(n_frames, n_points)
    if params.rotations == "known":
        if rotations is None:
            raise MeasurementError(
                "rotations='known' needs the camera rotations: pass rotations of shape "
                f"({n_frames}, 2, 3), or choose rotations='auto' to estimate them"
            )
        rotations = check_rotations(rotations, n_frames)
    feasibility.check_fit(params, n_frames, n_points, has_rotations=rotations is not None)
    return W, visibility, rotations


@dataclass(eq=False)
class _Tracks:
    """The centred, scale-normalised tracks and what the solve measures on them.

    ``centred`` (2F, P) and ``per_frame`` (F, 2, P) share memory until a signal fit
    replaces them; ``noise`` is relative to the tracks' mean square (1).
    """

    centred: np.ndarray
    scale: float
    decomposition: Spectrum
    signal_basis: np.ndarray
    noise: float
    per_frame: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        n_frames = self.centred.shape[0] // 2
        self.per_frame = self.centred.reshape(n_frames, 2, self.centred.shape[1])

    @classmethod
    def measure(
        cls, centred: np.ndarray, scale: float, completed: CompletedTracks | None
    ) -> _Tracks:
        """Spectrum, signal subspace and noise; O(F P min(F, P)) through the smaller Gram
        matrix. With missing data the noise of the fully observed blocks: the filled entries'
        errors would count as noise."""
        decomposition = spectrum(centred)
        singular = decomposition.singular
        basis = decomposition.left[:, : significant_rank(singular, centred.shape)]
        noise = noise_variance(singular, centred.shape)
        if completed is not None and completed.noise is not None:
            noise = completed.noise / scale**2
        return cls(centred, scale, decomposition, basis, noise)


def _estimate_cameras(
    tracks: _Tracks,
    completed: CompletedTracks | None,
    measured_tracks: np.ndarray,
    rotations: np.ndarray | None,
    params: SolverParams,
) -> cameras.CameraEstimate:
    """The known rotations, or an estimate (:func:`moju_core.cameras.estimate_cameras`).

    Known rotations lose the frame-to-frame jitter that cross-validation finds in them
    (:func:`moju_core.cameras.smoothing.smooth_rotations`); smooth ones are used as given.
    With missing data the estimator sees the points of
    :func:`moju_core.completion.completed.camera_tracks`.
    """
    if params.rotations == "known":
        smoothed, weight = smooth_rotations(rotations)
        return cameras.CameraEstimate(smoothed, "known", smoothing=weight)
    camera_input, decomposition = tracks.centred, tracks.decomposition
    if completed is not None:
        noisy = tracks.noise > defaults.EXACT_DATA_NOISE
        camera_input, decomposition = camera_tracks(completed, measured_tracks, tracks.scale, noisy)
    return cameras.estimate_cameras(
        camera_input,
        params.rotations,
        n_bases=params.n_bases,
        seed=params.seed,
        decomposition=decomposition,
    )


@dataclass(eq=False)
class _Solve:
    """What the loop runs: the plan, the resolved parameters, the tracks it fits (F, 2, P),
    the entries it fits (F, P) bool or None, its data term, the soft term to fall back to, and
    the smoothness trials made."""

    plan: SolvePlan
    params: SolverParams
    tracks: np.ndarray
    fitted: np.ndarray | None
    term: DataTerm | None
    fallback: DataTerm | None
    trials: list[tuple[float, float]]
    features: np.ndarray | None
    weigh_by_discrepancy: bool = False


def _plan(
    tracks: _Tracks,
    completed: CompletedTracks | None,
    estimate: cameras.CameraEstimate,
    params: SolverParams,
    report: _Reporter,
) -> _Solve:
    """Resolve the parameters, choose the prior's weight and the data term: the plan."""
    n_frames, _, n_points = tracks.per_frame.shape
    user_beta2 = params.beta2
    rotations = estimate.rotations
    derive_unshrunk = params.unshrunk_values is None
    signal_rank = tracks.signal_basis.shape[1]
    params = _resolved_params(tracks, estimate, params)
    completion = _completion_kind(completed)
    exact_data = solve_plan.exact_data(tracks.noise, completion, params.rotations)
    fitted = None if completed is None else completed.fitted
    fitted_tracks = tracks.per_frame
    trials: list[tuple[float, float]] = []
    signal_fitted = False
    if params.smoothness is None:
        choice, fit = _choose_prior(tracks, completed, estimate, params, exact_data, report)
        trials = choice.trials
        exact = fits_exactly(exact_data, estimate.refine, defaults.MIN_DEPTH_PRIOR)
        params = params.model_copy(
            update={"smoothness": choice.exact_weight if exact else choice.weight}
        )
        if fit is not None:
            # Noisy tracks the soft rule kept at a weak prior: fitted exactly once projected
            # onto their signal subspace, every entry (hidden ones at their completion).
            fitted_tracks, exact_data, trials, fitted = fit.tracks, True, fit.trials, None
            tracks.per_frame = fit.tracks
            tracks.centred = fit.tracks.reshape(2 * n_frames, n_points)
            params = params.model_copy(update={"smoothness": fit.smoothness})
            if derive_unshrunk and params.free_mean_shape:
                unshrunk = defaults.unshrunk_values(rotations, signal_rank)
                params = params.model_copy(update={"unshrunk_values": unshrunk})
        signal_fitted = fit is not None
    exact = fits_exactly(exact_data, estimate.refine, params.smoothness)
    masked = (
        exact
        and not signal_fitted
        and completed is not None
        and (completed.fitted is not None or completed.borrowed)
    )
    term_name = solve_plan.data_term_name(
        params.method, exact, masked, estimate.refine, params.smoothness
    )
    plan = SolvePlan(
        method=params.method,
        n_frames=n_frames,
        n_points=n_points,
        observed_fraction=1.0 if completed is None else float(completed.observed.mean()),
        noise=float(tracks.noise),
        completion=completion,
        camera_source=estimate.source,
        rotation_smoothing=estimate.smoothing,
        refine_rotations=estimate.refine and params.method != "pta",
        smoothness=float(params.smoothness),
        signal_fit=signal_fitted,
        data_term=term_name,
    )
    term, fallback = _terms(plan, fitted, completed, fitted_tracks, exact)
    features = None
    if params.method not in ("bmm", "pta") and params.n_groups > 1:
        features = clustering.track_features(tracks.centred)
    weigh = _discrepancy_weighs(user_beta2, term_name, completed, plan, params, tracks.noise)
    return _Solve(plan, params, fitted_tracks, fitted, term, fallback, trials, features, weigh)


def _resolved_params(
    tracks: _Tracks, estimate: cameras.CameraEstimate, params: SolverParams
) -> SolverParams:
    """:func:`moju_core.defaults.resolve` for the tracks (F, 2, P) under the estimated
    rotations (F, 2, 3), with the estimate's number of bases where it has one."""
    n_frames, _, n_points = tracks.per_frame.shape
    initial = np.einsum("fji,fjp->fip", estimate.rotations, tracks.per_frame)
    top = lrr.top_singular_value(initial.reshape(n_frames, 3 * n_points))
    del initial  # (F, 3P): do not hold it through the loop
    n_bases = estimate.n_bases if estimate.n_bases is not None else params.n_bases
    params = defaults.resolve(
        params,
        n_frames,
        n_points,
        top,
        rotations=estimate.rotations,
        noise=tracks.noise,
        signal_rank=tracks.signal_basis.shape[1],
    )
    return params.model_copy(update={"n_bases": n_bases})


def _discrepancy_weighs(
    user_beta2: float | None,
    term_name: str,
    completed: CompletedTracks | None,
    plan: SolvePlan,
    params: SolverParams,
    noise: float,
) -> bool:
    """Whether the discrepancy principle sets beta2 (:func:`_weigh_by_discrepancy`).

    It sets the weight of a soft fit of noisy (``noise``: variance of the scale-normalised
    tracks), complete tracks under fixed cameras, unless the user set it (moju and sdg; bmm
    stays Dai et al.'s method). Refined cameras take part of the residual, so it no longer
    measures the noise alone.
    """
    return (
        user_beta2 is None and term_name == "soft" and completed is None
        and not plan.refine_rotations and params.method in ("moju", "sdg")
        and noise > defaults.EXACT_DATA_NOISE
    )  # fmt: skip


def _completion_kind(completed: CompletedTracks | None) -> solve_plan.Completion:
    if completed is None:
        return "none"
    return "exact" if completed.exact else "approximate"


def _choose_prior(
    tracks: _Tracks,
    completed: CompletedTracks | None,
    estimate: cameras.CameraEstimate,
    params: SolverParams,
    exact_data: bool,
    report: _Reporter,
):
    """The temporal prior's weight from trial solves
    (:func:`moju_core.priors.smoothness.choose_smoothness`), and the signal fit of noisy
    tracks when the plan tries it (:func:`moju_core.priors.signal_fit.signal_fit`)."""

    def trial_hook(iteration: int, gap: float, rho: float) -> bool:
        report("initialising")  # raises Cancelled when the callback asks to stop
        return False

    observed = None if completed is None else completed.observed
    exact_entries = None if completed is None else completed.exact_entries
    fitted, fitted_observed = trial_tracks(tracks.per_frame, observed, exact_entries)
    choice = choose_smoothness(
        fitted,
        estimate.rotations,
        params,
        tracks.signal_basis,
        refine_rotations=estimate.refine,
        hook=trial_hook,
        observed=fitted_observed,
    )
    del fitted
    exact = fits_exactly(exact_data, estimate.refine, defaults.MIN_DEPTH_PRIOR)
    weight = choice.exact_weight if exact else choice.weight
    fit = None
    if solve_plan.tries_signal_fit(
        params.method, tracks.noise, estimate.source, weight, choice.exact_weight
    ):
        # With missing data the trials fitted the observed entries only: the projected
        # completed tracks need their own.
        reuse = choice if completed is None else None
        fit = signal_fit(
            tracks.per_frame,
            estimate.rotations,
            params.model_copy(update={"smoothness": weight}),
            tracks.signal_basis,
            choice=reuse,
            hook=trial_hook,
        )
    return choice, fit


#: A reconstructed point further from its frame's centroid than this many times the largest
#: distance of an observed track from the image centroid is off the object: the masked exact
#: fit has gone astray (it does not come back) and the solve falls back to the soft fit.
#: Solves that stay on the object stay within about 2.4 times it.
FLUNG_FACTOR = 5.0


def _terms(
    plan: SolvePlan,
    fitted: np.ndarray | None,
    completed: CompletedTracks | None,
    tracks: np.ndarray,
    exact: bool,
) -> tuple[DataTerm | None, DataTerm | None]:
    """The loop's data term and, for the masked exact fit, the soft term it falls back to."""
    if plan.method == "pta":
        return None, None
    n_frames, n_points = plan.n_frames, plan.n_points
    banded = plan.refine_rotations and plan.smoothness > 0
    if plan.data_term != "masked-exact":
        term = choose_term(n_frames, n_points, fitted, exact=exact, banded_prior=banded)
        return term, None
    limit = FLUNG_FACTOR * _image_reach(tracks, completed.observed)
    term = choose_term(
        n_frames, n_points, fitted, exact=True, measured=completed.exact_entries, limit=limit
    )
    return term, choose_term(n_frames, n_points, fitted, banded_prior=banded)


def _image_reach(tracks: np.ndarray, observed: np.ndarray | None) -> float:
    """The largest distance of an observed track (F, 2, P), centred, from its image's centre."""
    image = np.linalg.norm(tracks, axis=1)  # (F, P)
    return float(image.max() if observed is None else image[observed].max())


def _run(solve: _Solve, estimate: cameras.CameraEstimate, report: _Reporter) -> admm.LoopOutput:
    """The loop (or method ``pta``'s closed form); a masked exact fit that goes astray is
    solved again with the soft term, its progress continuing from the first loop's."""
    done = 0

    def hook(iteration: int, gap: float, rho: float) -> bool:
        report("iterating", done + iteration, gap, rho)
        return False

    if solve.plan.method == "pta":
        return closed_form.solve_pta(
            solve.tracks, estimate.rotations, solve.params.trajectory_bases, hook, solve.fitted
        )
    loop_cameras = admm.LoopCameras(estimate.rotations, estimate.refine)

    def again(params: SolverParams, term: DataTerm, previous: admm.LoopOutput | None):
        """One more loop, its progress counted on from the previous loop's."""
        nonlocal done
        if previous is not None:
            done += previous.n_iter
            report.expected = done + defaults.expected_iterations(params)
        return admm.run(
            solve.tracks, loop_cameras, params, term, features=solve.features, hook=hook
        )

    out = again(solve.params, solve.term, None)
    if solve.weigh_by_discrepancy:
        out = _weigh_by_discrepancy(
            out, solve, lambda params, last: again(params, solve.term, last)
        )
    if solve.fallback is not None and beyond(out.shapes, solve.term.limit):
        warnings.warn(
            "the exact fit of the observed entries threw hidden entries far off the "
            f"object (more than {FLUNG_FACTOR:g} times the largest image distance from "
            "its centre): solved again with the observed entries fitted softly",
            RuntimeWarning,
            stacklevel=4,
        )
        out = again(solve.params, solve.fallback, out)
    return out


def _weigh_by_discrepancy(out: admm.LoopOutput, solve: _Solve, again) -> admm.LoopOutput:
    """Solve again (``again(params, previous)``) with a larger nuclear-norm weight while the
    fit absorbs most of the noise (:mod:`moju_core.priors.discrepancy`)."""
    for _ in range(discrepancy.RESOLVES):
        ratio = discrepancy.discrepancy(solve.tracks, out.rotations, out.shapes, solve.plan.noise)
        if ratio >= discrepancy.ABSORBED:
            break
        beta2 = discrepancy.next_weight(solve.params.beta2, ratio)
        solve.params = solve.params.model_copy(update={"beta2": beta2})
        out = again(solve.params, out)
    return out


def _package(
    out: admm.LoopOutput,
    solve: _Solve,
    estimate: cameras.CameraEstimate,
    tracks: _Tracks,
    completed: CompletedTracks | None,
    visibility: np.ndarray,
    timings: dict[str, float],
) -> Result:
    """The public :class:`Result`: shapes back in the input's units, each frame centred."""
    scale = tracks.scale
    shapes = out.shapes * scale
    shapes -= shapes.mean(axis=2, keepdims=True)
    return Result(
        shapes=np.ascontiguousarray(shapes.transpose(0, 2, 1)),
        rotations=out.rotations,
        labels=out.labels,
        history={
            **out.history,
            "reprojection": out.history["reprojection"] * scale,
            "nuclear_norm": out.history["nuclear_norm"] * scale,
        },
        timings=timings,
        params=solve.params,
        n_iter=out.n_iter,
        stop_reason=out.stop_reason,
        scale=scale,
        visibility=visibility,
        diagnostics=Diagnostics(
            n_groups_used=out.n_groups,
            rotation_source=estimate.source,
            rotation_window=estimate.window,
            rotations_refined=solve.plan.refine_rotations,
            rotation_rigidity=None
            if estimate.rigidity is None
            else RotationRigidity(**estimate.rigidity),
            noise_variance=float(tracks.noise * scale**2),
            observed_fraction=float(visibility.mean()),
            smoothness_trials=tuple(solve.trials),
            signal_fit=solve.plan.signal_fit,
            trajectory_basis=out.trajectory_basis,
            completion_rank=None if completed is None else completed.rank,
            exact_completion=completed is not None and completed.exact,
            completion_unexplained=None if completed is None else completed.unexplained,
            exact_fit=out.exact_fit,
            plan=solve.plan,
        ),
    )


def _perspective_reconstruct(
    W: np.ndarray,
    visibility: np.ndarray,
    intrinsics: Intrinsics,
    params: SolverParams,
    report: _Reporter,
    start: float,
) -> Result:
    """The perspective path (:mod:`moju_core.perspective`): positions that leave their
    neighbours' motion set aside (:mod:`moju_core.neighbour_check`), a default camera's focal
    length estimated, the isometric prior's shapes, then the loop anchored to them."""
    report("initialising")
    tic = time.perf_counter()
    visibility = neighbour_check.trusted(W, visibility)
    timings = {"neighbour_check": time.perf_counter() - tic}
    tic = time.perf_counter()
    intrinsics = perspective.solving_camera(W, visibility, intrinsics, params.seed)
    timings["focal_length"] = time.perf_counter() - tic
    tic = time.perf_counter()
    prior, fit = perspective.prior_shapes(W, visibility, intrinsics, params.seed)
    timings["surface_prior"] = time.perf_counter() - tic
    params = params.model_copy(update={"surface_prior": "isometric"})
    report.expected = defaults.expected_iterations(params)

    def hook(iteration: int, gap: float, rho: float) -> bool:
        report("iterating", iteration, gap, rho)
        return False

    tic = time.perf_counter()
    shapes, out, params, noise = perspective.refine_on_prior(prior, visibility, params, hook)
    timings["iterate"] = time.perf_counter() - tic
    report("finishing", out.n_iter)
    timings["total"] = time.perf_counter() - start
    n_frames, n_points = visibility.shape
    plan = SolvePlan(
        method=params.method,
        n_frames=n_frames,
        n_points=n_points,
        observed_fraction=float(visibility.mean()),
        noise=noise,
        completion="none" if visibility.all() else "approximate",
        camera_source="known",
        refine_rotations=False,
        smoothness=float(params.smoothness),
        signal_fit=False,
        data_term="anchored",
        camera_model="perspective",
        surface_prior="isometric",
        focal_px=intrinsics.fx,
        focal_origin=intrinsics.origin,
    )
    return Result(
        shapes=np.ascontiguousarray(shapes),
        rotations=out.rotations,
        labels=out.labels,
        history=out.history,
        timings=timings,
        params=params,
        n_iter=out.n_iter,
        stop_reason=out.stop_reason,
        scale=1.0,
        visibility=visibility,
        diagnostics=Diagnostics(
            n_groups_used=out.n_groups,
            rotation_source="known",
            observed_fraction=float(visibility.mean()),
            plan=plan,
        ),
    )


def _resolve_rotation_method(params: SolverParams, given: bool) -> SolverParams:
    """``params`` with the rotation method resolved; refuse rotations an estimator would ignore."""
    method = rotation_method(params.rotations, given)
    if given and method != "known":
        raise MeasurementError(
            f"rotations were given but params.rotations is {method!r}, which estimates them: "
            "set rotations='known' (or leave it unset) to use them, or do not pass them"
        )
    return params.model_copy(update={"rotations": method})
