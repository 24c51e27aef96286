"""The one entry point: :func:`reconstruct`."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from moju_core import (
    admm,
    cameras,
    clustering,
    defaults,
    feasibility,
    gaps,
    lrr,
    missing,
    neighbours,
    pta,
)
from moju_core.cameras import projection
from moju_core.errors import Cancelled, MeasurementError
from moju_core.loop_state import fits_exactly
from moju_core.params import SolverParams, rotation_method
from moju_core.preprocessing import normalise
from moju_core.result import (
    Diagnostics,
    Progress,
    Result,
    RotationRigidity,
    StopReason,
    TrajectoryBasisFit,
)
from moju_core.signal_fit import signal_fit
from moju_core.smoothness import choose_smoothness
from moju_core.spectrum import Spectrum, noise_variance, significant_rank, spectrum
from moju_core.validation import check_observations, check_rotations

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
    params = _as_params(params)
    if threads is None:
        return _reconstruct(W, params, rotations, visibility, callback)
    with threadpool_limits(limits=threads):
        return _reconstruct(W, params, rotations, visibility, callback)


#: More frames than this many times the points reads like a transposed W (P x 2F): dense
#: tracks have far more points than frames.
_TRANSPOSED_RATIO = 10


def _as_params(params: object) -> SolverParams | None:
    """``params`` as SolverParams: None stays None, a mapping is validated, others refused."""
    if params is None or isinstance(params, SolverParams):
        return params
    if isinstance(params, Mapping):
        return SolverParams.model_validate(dict(params))
    raise TypeError(
        f"params must be a SolverParams or a mapping such as {{'max_iter': 100}}, not "
        f"{type(params).__name__}"
    )


def _warn_if_transposed(n_frames: int, n_points: int) -> None:
    if n_frames > _TRANSPOSED_RATIO * n_points:
        warnings.warn(
            f"W has {2 * n_frames} rows and {n_points} columns, so it is read as {n_frames} "
            f"frames of {n_points} points; dense tracks have far more points than frames. If "
            f"the rows are the points (W of shape (P, 2F)), pass W.T",
            UserWarning,
            stacklevel=4,
        )


def _reconstruct(
    W: np.ndarray,
    params: SolverParams | None,
    rotations: np.ndarray | None,
    visibility: np.ndarray | None,
    callback: ProgressCallback | None,
) -> Result:
    params = params if params is not None else SolverParams()
    params = _resolve_rotation_method(params, rotations is not None)
    report = _Reporter(callback, params.max_iter)
    timings: dict[str, float] = {}
    start = time.perf_counter()

    report("validating")
    W, visibility = check_observations(W, visibility)
    observed = None if visibility.all() else visibility
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    _warn_if_transposed(n_frames, n_points)
    if params.rotations == "known":
        if rotations is None:
            raise MeasurementError(
                "rotations='known' needs the camera rotations: pass rotations of shape "
                f"({n_frames}, 2, 3), or choose rotations='auto' to estimate them"
            )
        rotations = check_rotations(rotations, n_frames)
    # Sizes first, with the messages the service gives at submission (moju_core.feasibility).
    feasibility.check_fit(params, n_frames, n_points, has_rotations=rotations is not None)
    values, fitted, borrowed, exact_entries = None, observed, False, observed
    completion_rank, exact_completion, unexplained = None, False, None
    if observed is not None:
        # Translation, cameras, the smoothness trials and the initial groups see a low-rank
        # completion of W (moju_core.missing), with the entries it does not determine filled
        # from the points' neighbours (moju_core.neighbours).
        # The noise from the fully observed blocks, relative to the completed tracks' mean
        # square; a completion less precise than a measurement of noisy tracks is not data.
        block_noise = missing.observed_noise_variance(W, observed)
        model = missing.complete(W, observed, noise=block_noise)
        completion_rank, exact_completion = model.rank, model.exact
        unexplained = None if model.exact else model.unexplained
        noisy = block_noise is not None and (
            block_noise / normalise(model.fill(W, observed))[1] ** 2 > defaults.EXACT_DATA_NOISE
        )
        reliable = missing.trusted_entries(model, observed, noisy=noisy)
        values, borrowed_points = neighbours.borrow_values(
            model, W, observed, reliable, noise=block_noise or 0.0
        )
        borrowed = bool(borrowed_points.any())
        # Hidden entries near observed frames of their track corrected by it (moju_core.gaps).
        W = gaps.filled(values, W, observed, model.gap)
        # The entries the loop fits: the observed ones, the hidden ones the low-rank model
        # predicts well and those of the borrowed points, at their model values. The
        # smoothness trials fit the observed ones only: their rule compares misfits of ~1e-4
        # of the tracks' energy, and the model's errors at trusted entries (rolling sheet,
        # 10 % dropout: 0.004 of the RMS) would count as misfit (it chose 0.1 instead of 100).
        fitted = reliable | borrowed_points[None, :]
        fitted = None if fitted.all() else fitted
        # An exact model predicts its trusted entries as exactly as they would be measured.
        exact_entries = reliable if exact_completion else observed
    centred, scale = normalise(W)

    report("rotations")
    tic = time.perf_counter()
    # Through the smaller of W W^T (2F x 2F) and W^T W (P x P): O(F P min(F, P)).
    decomposition = spectrum(centred)
    singular = decomposition.singular
    signal_basis = decomposition.left[:, : significant_rank(singular, centred.shape)]
    # Relative to the mean square of the normalised tracks, which is 1.
    noise = noise_variance(singular, centred.shape)
    if observed is not None:
        # The filled entries' errors would count as noise (moju_core.missing).
        noise = noise if block_noise is None else block_noise / scale**2
    exact_data = noise <= defaults.EXACT_DATA_NOISE
    if observed is not None and params.rotations != "known":
        # An exact fit trusts the cameras. Those estimated from an exact model are as good as
        # from complete tracks; from another completion they are degrees off (face4's 41
        # markers: 2.7-5.8), and an exact fit puts that error into the depths even where
        # every hidden entry is trusted (e3D 0.11-0.33 against 0.024-0.072 soft), as it did
        # with only the observed entries fitted exactly (face3, combined occlusion, seeds
        # 2 / 3: 0.0215 / 0.0170 -> 0.109 / diverged; docs/solver.md, "Missing data").
        exact_data = exact_data and exact_completion
    if params.rotations == "known":
        estimate = cameras.CameraEstimate(rotations, "known")
    else:
        camera_tracks, camera_decomposition = centred, decomposition
        if values is not None:
            filled = None
            if noise > defaults.EXACT_DATA_NOISE:
                # With the model's values at the hidden entries, not the gap-corrected ones.
                filled = np.where(missing.expand_mask(observed), W, values) / scale
            camera_tracks, camera_decomposition = _camera_tracks(
                values, observed, reliable, scale, filled
            )
        estimate = cameras.estimate_cameras(
            camera_tracks,
            params.rotations,
            n_bases=params.n_bases,
            seed=params.seed,
            decomposition=camera_decomposition,
        )
        rotations = estimate.rotations
        # Result.params records what "auto" chose, so that it can be run again as it ran.
        params = params.model_copy(update={"rotations": estimate.source})
        camera_tracks = None
    # The loop does not read the model's values: a (2F, P) copy fewer while it runs.
    values = None
    n_bases = estimate.n_bases if estimate.n_bases is not None else params.n_bases
    timings["rotations"] = time.perf_counter() - tic

    report("initialising")
    tic = time.perf_counter()
    tracks = centred.reshape(n_frames, 2, n_points)
    initial = np.einsum("fji,fjp->fip", rotations, tracks).reshape(n_frames, 3 * n_points)
    top = lrr.top_singular_value(initial)
    del initial  # (F, 3P): do not hold it through the loop
    derive_unshrunk = params.unshrunk_values is None
    signal_rank = signal_basis.shape[1]
    params = defaults.resolve(
        params, n_frames, n_points, top, rotations=rotations, noise=noise, signal_rank=signal_rank
    )
    params = params.model_copy(update={"n_bases": n_bases})
    # Again with the values derived from the data.
    feasibility.check_fit(params, n_frames, n_points, has_rotations=True)
    smoothness_trials: list[tuple[float, float]] = []
    signal_fitted = False
    if params.smoothness is None:

        def trial_hook(iteration: int, gap: float, rho: float) -> bool:
            report("initialising")  # raises Cancelled when the callback asks to stop
            return False

        trial_tracks, trial_observed = _trial_tracks(tracks, observed, exact_entries)
        choice = choose_smoothness(
            trial_tracks,
            rotations,
            params,
            signal_basis,
            refine_rotations=estimate.refine,
            hook=trial_hook,
            observed=trial_observed,
        )
        del trial_tracks
        exact = fits_exactly(exact_data, estimate.refine, defaults.MIN_DEPTH_PRIOR)
        smoothness_trials = choice.trials
        weight = choice.exact_weight if exact else choice.weight
        params = params.model_copy(update={"smoothness": weight})
        fit = None
        if _tries_signal_fit(params, noise, estimate.source, choice.exact_weight):
            # With missing data the trials fitted the observed entries only: the projected
            # completed tracks need their own.
            reuse = choice if observed is None else None
            fit = signal_fit(tracks, rotations, params, signal_basis, choice=reuse, hook=trial_hook)
        if fit is not None:
            # Noisy tracks the soft rule kept at a weak prior: fitted exactly once projected
            # onto their signal subspace (moju_core/signal_fit.py).
            tracks, exact_data, smoothness_trials = fit.tracks, True, fit.trials
            fitted = None  # every entry, hidden ones at their completion, projected
            centred = tracks.reshape(2 * n_frames, n_points)
            params = params.model_copy(update={"smoothness": fit.smoothness})
            if derive_unshrunk and params.free_mean_shape:
                unshrunk = defaults.unshrunk_values(rotations, signal_rank)
                params = params.model_copy(update={"unshrunk_values": unshrunk})
        signal_fitted = fit is not None
    measured = None
    if (fitted is not None or borrowed) and not signal_fitted:
        if fits_exactly(exact_data, estimate.refine, params.smoothness or 0.0):
            # Known cameras or an exact model (exact_data above): the observed entries
            # exactly (and the trusted ones of an exact model), the other trusted and the
            # borrowed hidden ones softly at their completion, the rest free
            # (temporal_prior.masked_depth_step). Where every hidden entry is trusted and
            # none borrowed, all are fitted exactly as data.
            measured = exact_entries
    if derive_unshrunk:
        unshrunk = defaults.unshrunk_with_prior(params.unshrunk_values, params.smoothness)
        params = params.model_copy(update={"unshrunk_values": unshrunk})
    features = None
    if params.method not in ("bmm", "pta") and params.n_groups > 1:
        features = clustering.track_features(centred)
    report.expected = defaults.expected_iterations(params)
    timings["initialise"] = time.perf_counter() - tic

    tic = time.perf_counter()

    # Iterations of loops already run: a second loop's progress continues from the first's.
    done = 0

    def hook(iteration: int, gap: float, rho: float) -> bool:
        report("iterating", done + iteration, gap, rho)
        return False

    # A masked exact fit that throws hidden entries off the object is abandoned as soon as it
    # does (it does not come back: face3 seed 92 grew twofold per iteration to 1e5 times the
    # object and ran to max_iter), and solved again softly below.
    limit = FLUNG_FACTOR * _image_reach(tracks, observed)

    def loop(exact: bool, held: np.ndarray | None) -> admm.LoopOutput:
        return admm.run(
            tracks,
            rotations,
            params,
            features=features,
            hook=hook,
            refine_rotations=estimate.refine,
            observed=fitted,
            exact_data=exact,
            measured=held,
            abandon=None if held is None else (lambda shapes: _beyond(shapes, limit)),
        )

    if params.method == "pta":
        out = _trajectory_basis(tracks, rotations, params, hook, fitted)
    else:
        out = loop(exact_data, measured)
        if measured is not None and _beyond(out.shapes, limit):
            warnings.warn(
                "the exact fit of the observed entries threw hidden entries far off the "
                f"object (more than {FLUNG_FACTOR:g} times the largest image distance from "
                "its centre): solved again with the observed entries fitted softly",
                RuntimeWarning,
                stacklevel=3,
            )
            done = out.n_iter
            report.expected = done + defaults.expected_iterations(params)
            out = loop(False, None)
    timings["iterate"] = time.perf_counter() - tic

    report("finishing", out.n_iter)
    shapes = out.shapes * scale
    shapes -= shapes.mean(axis=2, keepdims=True)
    timings["total"] = time.perf_counter() - start
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
        params=params,
        n_iter=out.n_iter,
        stop_reason=out.stop_reason,
        scale=scale,
        visibility=visibility,
        diagnostics=Diagnostics(
            n_groups_used=out.n_groups,
            rotation_source=estimate.source,
            rotation_window=estimate.window,
            rotations_refined=estimate.refine and params.method != "pta",
            rotation_rigidity=None
            if estimate.rigidity is None
            else RotationRigidity(**estimate.rigidity),
            noise_variance=float(noise * scale**2),
            observed_fraction=float(visibility.mean()),
            smoothness_trials=tuple(smoothness_trials),
            signal_fit=signal_fitted,
            trajectory_basis=out.trajectory_basis,
            completion_rank=completion_rank,
            exact_completion=exact_completion,
            completion_unexplained=unexplained,
            exact_fit=out.exact_fit,
        ),
    )


#: :func:`_beyond`: a reconstructed point further from its frame's centroid than this many times
#: the largest distance of an observed track from the image centroid is off the object. On
#: the articulated body under its oscillating camera (`body-osc`, prior weight 1,000), with
#: 10 % of the tracks lost from a random frame on, the masked exact fit's loop threw a lost
#: stretch to 6.8 (seed 0, converged, e3D 0.498) and 1e8 (seed 2, diverged, e3D 2.7e6) times
#: that distance; fitted softly they give 0.404 and 0.068. Every other masked exact solve
#: measured (face3, face4, paper, cloth, bumps-osc, body-osc, body-turn; seeds 20-21; the
#: combined occlusion, lost tracks alone, a band over 30 % of the width) stayed within 1.33
#: times it but one body-osc solve at 2.4 (e3D 0.315), which the soft fit does not improve
#: (0.357): the factor catches the loop going astray, not every poor solve.
FLUNG_FACTOR = 5.0


def _image_reach(tracks: np.ndarray, observed: np.ndarray | None) -> float:
    """The largest distance of an observed track (F, 2, P), centred, from its image's centre."""
    image = np.linalg.norm(tracks, axis=1)  # (F, P)
    return float(image.max() if observed is None else image[observed].max())


def _beyond(shapes: np.ndarray, limit: float) -> bool:
    """Whether shapes (F, 3, P) put a point further than ``limit`` from its frame's centroid.

    A first look at the largest coordinate (one pass) rules most cases out: no point is
    further than ``2 sqrt(3)`` times it from a centroid.
    """
    if 2.0 * math.sqrt(3.0) * float(np.abs(shapes).max()) <= limit:
        return False
    centred = shapes - shapes.mean(axis=2, keepdims=True)
    return bool(np.linalg.norm(centred, axis=1).max() > limit)


def _tries_signal_fit(
    params: SolverParams, noise: float, rotation_source: str, exact_weight: float
) -> bool:
    """Whether the solve tries the exact fit of the projected tracks (moju_core/signal_fit.py).

    Noisy tracks (complete, or completed where points are hidden), known cameras, a
    local-model method (moju, sdg), a soft rule that chose a weight of at most the
    depth-setting one, and an exact rule on the same trials (``exact_weight``) that accepts
    the depth-setting weight. Estimated cameras are left out: an exact fit trusts them, and on
    the noisy oscillating sheets, whose estimates are 20-30 degrees off, it raised e3D
    (bumps-osc, 1 % noise, seed 5: 0.171 -> 0.323). With missing data the trials fitted the
    observed entries only and the projected tracks get trials of their own (4 solves); where
    the observed entries' exact rule rejected the depth-setting weight, those rejected it too
    on every solve measured (docs/solver.md, "Noisy tracks: the signal fit").
    """
    return (
        params.method in ("moju", "sdg")
        and noise > defaults.EXACT_DATA_NOISE
        and rotation_source == "known"
        and params.smoothness is not None
        and params.smoothness <= defaults.MIN_DEPTH_PRIOR
        and exact_weight >= defaults.MIN_DEPTH_PRIOR
    )


#: With missing data the cameras are estimated from the well-seen points whose entries are all
#: reliable; from all well-seen points when fewer than this are, and from all points when
#: fewer than this are well seen.
CAMERA_MIN_POINTS = 20


def _camera_points(observed: np.ndarray, reliable: np.ndarray) -> np.ndarray:
    """The points the camera step sees with missing data, (P,) bool (:data:`CAMERA_MIN_POINTS`).

    Points with an unreliable entry are left out: their values there come from their
    neighbours (:func:`moju_core.neighbours.borrow_values`) and are not of the model's rank.
    With them the camera step read the mixture as motion a single camera fit cannot explain
    and chose the windowed cameras (face3 seed 3, 2,000 points, combined occlusion: 12.0 s
    against 5.7 s, 2.9 times the complete tracks' time; e3D 0.0165, 0.0170 without them).
    """
    seen = missing.well_seen(observed)
    for points in (seen & reliable.all(axis=0), seen):
        if points.sum() >= CAMERA_MIN_POINTS:
            return points
    return np.ones_like(seen)


def _camera_tracks(
    values: np.ndarray,
    observed: np.ndarray,
    reliable: np.ndarray,
    scale: float,
    filled: np.ndarray | None,
) -> tuple[np.ndarray, Spectrum]:
    """Centred, normalised tracks for the camera step with missing data, and their spectrum.

    The points of :func:`_camera_points` (``observed``, ``reliable``: (F, P) bool).
    Noise-free tracks (``filled`` None) give their ``values`` (2F, P: the low-rank model's,
    with the unreliable entries from the neighbours); noisy ones their filled tracks
    ``filled`` (2F, P; centred, normalised): observed values, ``values`` at the hidden entries.

    * Noise-free, the filled tracks mix exact observed values with the model's errors at the
      hidden entries, whose spectrum has no floor (face3, 2,000 points, combined occlusion:
      significant rank 59 against 13 complete); the intersection method's joint fit then took
      5-6 s against 0.3 s on the model values, and the model values' rotations (0.8-1.0
      degrees off) cost no accuracy: with the true rotations e3D was the same to 1-6 %.
    * Noisy, the held-out error chooses a lower rank (face3 at 3 % noise: 4, against 6
      noise-free), whose model values lose what the cameras need: rotations 4.8-5.5 degrees
      off, against 1.4 on the filled tracks (0.9-1.2 on complete tracks).
    """
    columns = np.flatnonzero(_camera_points(observed, reliable))
    if filled is not None:
        tracks = filled[:, columns]
        tracks = tracks - tracks.mean(axis=1, keepdims=True)
    else:
        tracks = values[:, columns]
        tracks = (tracks - tracks.mean(axis=1, keepdims=True)) / scale
    return tracks, spectrum(tracks)


def _trial_tracks(
    tracks: np.ndarray, observed: np.ndarray | None, exact_entries: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The tracks (F, 2, n) and visibility the smoothness trials fit.

    With missing data, the observed entries only (:func:`moju_core.smoothness.choose_smoothness`),
    unless an exact model predicts the hidden ones (``exact_entries`` is not ``observed``):
    then the points all of whose entries it predicts or observes, complete, as on complete
    tracks (at :data:`CAMERA_MIN_POINTS` or more; the trials' masked loop cost 1.3 times the
    unmasked one on face3).
    """
    if observed is None or exact_entries is observed:
        return tracks, observed
    points = exact_entries.all(axis=0)
    if points.sum() < CAMERA_MIN_POINTS:
        return tracks, exact_entries
    return np.ascontiguousarray(tracks[:, :, points]), None


def _resolve_rotation_method(params: SolverParams, given: bool) -> SolverParams:
    """``params`` with the rotation method resolved; refuse rotations an estimator would ignore."""
    method = rotation_method(params.rotations, given)
    if given and method != "known":
        raise MeasurementError(
            f"rotations were given but params.rotations is {method!r}, which estimates them: "
            "set rotations='known' (or leave it unset) to use them, or do not pass them"
        )
    return params.model_copy(update={"rotations": method})


def _trajectory_basis(
    tracks: np.ndarray,
    rotations: np.ndarray,
    params: SolverParams,
    hook: admm.IterationHook,
    observed: np.ndarray | None = None,
) -> admm.LoopOutput:
    """Method ``pta``: one closed-form solve, reported as a single converged iteration.

    The :class:`Result` contract holds as for the iterative methods: labels are all 0 (no
    local groups), ``history`` has one entry per key (gap 0: there is no split to close; rho 0:
    no penalty; the reprojection error and nuclear norm of the solution; 0 relabelled) and the
    stop reason is ``"converged"``.
    """
    n_frames, _, n_points = tracks.shape
    shapes, fit = pta.solve(tracks, rotations, params.trajectory_bases, observed)
    residual = projection.project(rotations, shapes) - tracks
    if observed is not None:
        residual = residual[np.broadcast_to(observed[:, None, :], residual.shape)]
    nuclear = float(np.linalg.svd(shapes.reshape(n_frames, 3 * n_points), compute_uv=False).sum())
    hook(1, 0.0, 0.0)
    history = {
        "gap": 0.0,
        "gap_shape": 0.0,
        "gap_coefficients": 0.0,
        "rho": 0.0,
        "reprojection": float(np.sqrt(np.mean(residual**2))),
        "nuclear_norm": nuclear,
        "relabelled": 0.0,
    }
    return admm.LoopOutput(
        shapes=shapes,
        rotations=rotations,
        labels=np.zeros(n_points, dtype=np.int64),
        history={key: np.array([value]) for key, value in history.items()},
        n_iter=1,
        stop_reason=StopReason.CONVERGED,
        n_groups=1,
        trajectory_basis=TrajectoryBasisFit(rank=int(fit["rank"]), condition=fit["condition"]),
    )
