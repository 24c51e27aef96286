"""Measurements with unobserved entries: a low-rank model of W for the steps that need every entry.

The ADMM loop's data term runs over the observed entries only (:mod:`moju_core.cameras.projection`,
:mod:`moju_core.loop.admm`), but three steps before it want a complete ``W``: the per-frame
translation (the image of the centroid), the camera estimate (a factorisation of W) and the
spatial features of the initial groups. The centroid of the *visible* points is biased when
the hidden ones are not a random subset (an occluder sweeping across the object hides one side
at a time), so each of these uses a low-rank model of W instead, ``W ~ A B + t 1^T`` fitted on
the observed entries only (:class:`LowRank`):

* a warm start by EM for low-rank approximation with missing entries (Srebro and Jaakkola
  2003, "hard impute"): the unobserved entries are replaced by their values in the best
  rank-r approximation of the current filled matrix, repeatedly;
* then a few sweeps of alternating least squares on the observed entries (every row's
  ``(a_i, t_i)`` and every column's ``b_j`` solved exactly, vectorised), which converge much
  faster than EM where many entries are hidden;
* the rank chosen by the error on held-out observed entries, both random single entries and
  runs of consecutive frames of some points (they mimic tracks that end and occluders; random
  entries alone choose ranks too high for those patterns).

The solver also uses the model beyond the filled W: the camera step factorises the model values
of the well-seen points whose entries are all reliable
(:func:`moju_core.completion.completed.camera_points`), the noise level is read from the fully
observed blocks (:func:`observed_noise_variance`), and the loop fits the hidden entries whose
prediction is reliable (:meth:`LowRank.leverage`, :func:`trusted_entries`) as if they were
observed.

Cost: O(F P r^2) per ALS sweep and for the leverage, O(F P r) per EM sweep; nothing F x F or
P x P is formed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from moju_core.completion import gaps
from moju_core.completion.least_squares import (
    frame_normals,
    point_normals,
    solve_frames,
    solve_points,
)
from moju_core.spectrum import noise_variance, spectrum

#: EM sweeps of the warm start (each cannot increase the misfit on the observed entries).
COMPLETION_SWEEPS = 15
#: The second fit of the chosen rank, which :func:`complete` keeps when its misfit is lower
#: by more than the noise variance: the short fit can stop far from the minimum, the long one
#: can end in a worse one, and under noise a slightly lower misfit is no better model.
LONG_EM_SWEEPS, LONG_ALS_SWEEPS = 60, 18
#: Alternating least squares sweeps after the warm start.
ALS_SWEEPS = 6
#: Ranks tried for the completion, in order until the held-out error exceeds twice the best
#: (:func:`choose_rank`): a rank too high for the pattern of hidden entries overfits (a
#: sweeping occluder supports lower ranks than random dropout), so the rank is chosen per
#: input by the error on held-out observed entries, not capped by the zero-filled W's rank.
CANDIDATE_RANKS = (1, 2, 3, 4, 6, 9, 12, 16, 20)
#: Consecutive candidate ranks with more than twice the best held-out error after which
#: :func:`choose_rank` stops: one rank can miss the held-out entries badly where the next
#: fits them (held-out check and guard: benchmarks/notes/2026-12-06-rule-ablation.md,
#: tests/moju_core/completion/test_missing_rules.py).
OVERFIT_PATIENCE = 2
#: Observed entries held out at random to choose the rank, and the points used for the choice.
HOLD_OUT_FRACTION = 0.05
RANK_SELECTION_POINTS = 1000
#: Points (among those seen in enough frames) that lose a run of consecutive observed frames
#: for the rank choice, and the run's length as a fraction of the frames.
HOLD_OUT_RUN_POINTS = 0.1
HOLD_OUT_RUN_LENGTH = 0.25
#: Hidden entries whose leverage (:meth:`LowRank.leverage`) is at most this are predicted well
#: enough by the model to be used as data (:func:`trusted_entries`); entries of higher leverage
#: are determined by too few observations, and trusting them lets badly determined completions
#: into the loop as data (held-out check and guard:
#: benchmarks/notes/2026-12-06-rule-ablation.md, tests/moju_core/completion/test_missing_rules.py).
TRUSTED_LEVERAGE = 1000.0
#: A completion that is not exact is trusted at no hidden entry when the rank it generalises
#: best at leaves more than this of the held-out error of rank one (beyond the noise:
#: :attr:`RankChoice.unexplained`): its values there would carry the deformation it misses
#: into the loop as data. Smooth surfaces leave a few hundredths, an articulated body's
#: markers more (held-out check and guard: as for :data:`TRUSTED_LEVERAGE`).
MAX_UNEXPLAINED = 0.05
#: A point seen in at least this fraction of the frames is well seen: its column of the model
#: is fitted on as many frames as it predicts. The camera step uses these points
#: (:func:`moju_core.completion.completed.camera_points`), and the entries the model does not
#: determine are taken from them (:mod:`moju_core.completion.neighbours`). Held-out check:
#: benchmarks/notes/2026-12-06-rule-ablation.md.
WELL_SEEN = 0.5
#: Frames per block of the noise estimate with missing data (:func:`observed_noise_variance`),
#: the shorter only where no block of the longer qualifies: within 10 frames the deformations
#: have a rank below the block's 20 rows, and sparse markers hidden at random leave too few
#: points seen in all of 10 frames for a block, so the filled tracks' completion errors would
#: count as noise. Held-out check: benchmarks/notes/2026-12-06-rule-ablation.md.
NOISE_WINDOWS = (10, 5)


@dataclass(frozen=True)
class LowRank:
    """``W ~ left @ right + translation[:, None]``, fitted on the observed entries.

    left : ndarray of shape (2F, r)
    right : ndarray of shape (r, P)
    translation : ndarray of shape (2F,)
    exact : bool
        Whether W is exactly of rank r (:func:`exact_model`): its predictions at entries of
        low leverage are then as exact as measurements of noise-free tracks.
    unexplained : float
        The held-out error of rank r beyond the noise, relative to rank one's
        (:class:`RankChoice`); 0 for an exact model or one not chosen by held-out error.
    gap : GapFill
        The correction from the tracks that :meth:`fill` applies
        (:func:`moju_core.completion.gaps.correction`, :attr:`RankChoice.gap`); none by default.
    reach : int
        Hidden entries at most this many frames from an observed frame of their point are
        predicted by :meth:`fill` well enough to be used as data (:attr:`RankChoice.reach`).
    """

    left: np.ndarray
    right: np.ndarray
    translation: np.ndarray
    exact: bool = False
    unexplained: float = 0.0
    gap: gaps.GapFill = gaps.GapFill()
    reach: int = 0

    @property
    def rank(self) -> int:
        return int(self.left.shape[1])

    def values(self, columns: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The model's W at the given columns (all by default), shape (2F, n)."""
        return self.left @ self.right[:, columns] + self.translation[:, None]

    def fill(self, W: np.ndarray, visibility: np.ndarray) -> np.ndarray:
        """W at the observed entries, the model elsewhere, corrected from each point's track
        near its observed frames (:func:`moju_core.completion.gaps.filled`, :attr:`gap`)."""
        return gaps.filled(self.values(), W, visibility, self.gap)

    def centroid(self) -> np.ndarray:
        """Row means of the model (the image of the object's centroid per frame), (2F,)."""
        return self.left @ self.right.mean(axis=1) + self.translation

    def leverage(self, visibility: np.ndarray) -> np.ndarray:
        """How much less certain each entry's prediction is than with complete data, (F, P).

        For entry (f, j) the variance of the model's prediction from point j's observed
        frames, ``a_f^T (sum_{i seen} a_i a_i^T)^{-1} a_f``, divided by its value had every
        frame been seen; the same for frame f's observed points; the larger of the two (x and
        y rows: the larger). About 1 / (observed fraction) for dropout at random, large for a
        point seen in a few frames only or outside the frames it was seen in.
        """
        return self.variance_factors(visibility)[0]

    def variance_factors(self, visibility: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`leverage` and the prediction variance in units of the noise variance.

        The second, (F, P), is the leverage's numerator not divided by its complete-data
        value: the variance that white noise of variance 1 in the observed entries puts into
        the prediction from the point's observed frames and from the frame's observed points
        (the larger; x and y rows: the larger). Below 1 the prediction is as precise as a
        measurement.
        """
        left = np.hstack([self.left, self.translation[:, None]])  # (2F, r + 1)
        features = np.vstack([self.right, np.ones((1, self.right.shape[1]))]).T  # (P, r + 1)
        column, column_base = _variance(left, point_normals(left, visibility))  # (2F, P)
        # x and y rows of a frame see the same points: one normal matrix per frame.
        row, row_base = _variance(features, frame_normals(features, visibility))  # (P, F)
        column_relative = column / column_base[:, None]
        relative = np.maximum(column_relative[0::2], column_relative[1::2])
        relative = np.maximum(relative, (row / row_base[:, None]).T)
        return relative, np.maximum(np.maximum(column[0::2], column[1::2]), row.T)


#: Entries of the (n, block, k) products :func:`_variance` forms at a time (8 MB).
VARIANCE_BLOCK = 1_000_000


def _variance(features: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x_i^T G_j^{-1} x_i`` for every i (rows of ``features``, (n, k)) and j (the normal
    matrices G_j, (m, k, k), of the rows some j sees); and ``x_i^T G^{-1} x_i`` (G over all
    rows, floored at 1e-300)."""
    n, k = features.shape
    full = features.T @ features
    ridge = 1e-12 * np.trace(full) * np.eye(k)
    inverse_full = np.linalg.inv(full + ridge)
    base = np.einsum("ia,ab,ib->i", features, inverse_full, features)
    inverses = np.linalg.inv(normals + ridge)  # (m, k, k)
    variance = np.empty((n, inverses.shape[0]))
    # ``features @ G_j^-1`` for a block of j at a time as one (n, k) x (k, block k) product,
    # then the row-wise dot with the features: O(n m k^2) in BLAS, (n, block, k) at a time.
    block = max(1, VARIANCE_BLOCK // max(1, n * k))
    for start in range(0, inverses.shape[0], block):
        chunk = inverses[start : start + block]  # (b, k, k)
        product = features @ chunk.transpose(1, 0, 2).reshape(k, -1)  # (n, b k)
        product = product.reshape(n, chunk.shape[0], k)
        variance[:, start : start + block] = np.einsum("ibk,ik->ib", product, features)
    return variance, np.maximum(base, 1e-300)


def well_seen(visibility: np.ndarray) -> np.ndarray:
    """The points seen in at least :data:`WELL_SEEN` of the frames, (P,) bool."""
    return visibility.mean(axis=0) >= WELL_SEEN


def observed_noise_variance(W: np.ndarray, visibility: np.ndarray) -> float | None:
    """Variance of white noise in the entries of W, from its fully observed blocks only.

    The frames are cut into runs of the first length of :data:`NOISE_WINDOWS` that gives a
    block; in each run, the points seen in all its frames form a block when they are at least
    as many as its rows. Each block's noise (:func:`moju_core.spectrum.noise_variance` of its
    row-centred singular values) is estimated, and the median returned; None when no block
    qualifies at any length (fewer frames than a run, or no run with enough fully seen
    points).

    The spectrum of the filled W would count the completion's errors as noise: noise-free
    tracks of the bumpy sheet under the combined occlusion read 1.1e-5 to 2.0e-5 there (seeds
    1-3, 2,000 points; below 1e-12 on the blocks and on the complete tracks), and noisy tracks
    less than their noise (face3 at 3 % noise: 4.3e-3 filled, 5.5e-3 on the blocks and 5.6e-3
    complete).

    W : (2F, P), the values at unobserved entries ignored; visibility : (F, P) bool.
    Cost: O(F P w) for runs of w frames.
    """
    for window in NOISE_WINDOWS:
        estimates = _block_noise(W, visibility, window)
        if estimates:
            return float(np.median(estimates))
    return None


def _block_noise(W: np.ndarray, visibility: np.ndarray, window: int) -> list[float]:
    """The noise estimates of the fully observed blocks of ``window`` frames."""
    estimates = []
    for start in range(0, visibility.shape[0] - window + 1, window):
        frames = slice(start, start + window)
        points = visibility[frames].all(axis=0)
        if points.sum() < 2 * window:
            continue
        block = W[2 * start : 2 * (start + window), points]
        block = block - block.mean(axis=1, keepdims=True)
        estimates.append(noise_variance(spectrum(block).singular, block.shape))
    return estimates


def expand_mask(visibility: np.ndarray) -> np.ndarray:
    """The (F, P) visibility as a (2F, P) mask of the rows of W (x and y together)."""
    return np.repeat(visibility, 2, axis=0)


def complete(W: np.ndarray, visibility: np.ndarray, noise: float | None = None) -> LowRank:
    """Low-rank model of W fitted on its observed entries, at the rank chosen by held-out error.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Measurements with arbitrary (e.g. 0.0) values at the unobserved entries.
    visibility : ndarray of shape (F, P), bool
        True where the point is observed.
    noise : float, optional
        Variance of the noise in an entry of W (:func:`observed_noise_variance`), for
        :attr:`LowRank.unexplained`; None or 0 for none.

    Returns
    -------
    LowRank
        ``.fill(W, visibility)`` is the completed W. The exact model of :func:`exact_model`
        when W is exactly of low rank.
    """
    # Imported here: the exact model builds on this module's LowRank and masks.
    from moju_core.completion.exact_model import exact_model

    model = exact_model(W, visibility)
    if model is not None:
        return model
    choice = choose_rank(W, visibility, noise or 0.0)
    model = complete_at_rank(W, visibility, choice.rank)
    longer = complete_at_rank(W, visibility, choice.rank, LONG_EM_SWEEPS, LONG_ALS_SWEEPS)
    gain = observed_misfit(model, W, visibility) - observed_misfit(longer, W, visibility)
    if gain > (noise or 0.0):
        model = longer
    return replace(model, unexplained=choice.unexplained, gap=choice.gap, reach=choice.reach)


def observed_misfit(model: LowRank, W: np.ndarray, visibility: np.ndarray) -> float:
    """Mean squared error of the model at the observed entries of W (the fit's objective)."""
    mask = expand_mask(visibility)
    return float(np.mean((model.values() - W)[mask] ** 2))


def hold_out(visibility: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Observed entries to hold out for the rank choice: random ones and runs of frames.

    A tenth of the points seen in at least half the frames lose a run of a quarter of the
    frames (within their observed frames, at a random start); then a twentieth of the
    remaining observed entries at random. No point keeps fewer than 2 training frames.
    """
    n_frames, n_points = visibility.shape
    held = visibility & (rng.random(visibility.shape) < HOLD_OUT_FRACTION)
    length = max(1, int(round(HOLD_OUT_RUN_LENGTH * n_frames)))
    counts = visibility.sum(axis=0)
    candidates = np.flatnonzero(counts >= max(n_frames // 2, length + 2))
    n_runs = int(round(HOLD_OUT_RUN_POINTS * candidates.size))
    if n_runs and length < n_frames:
        chosen = rng.choice(candidates, n_runs, replace=False)
        starts = rng.integers(0, n_frames - length + 1, size=n_runs)
        frames = starts[:, None] + np.arange(length)[None, :]
        held[frames, chosen[:, None]] |= visibility[frames, chosen[:, None]]
    training = visibility & ~held
    short = training.sum(axis=0) < 2
    held[:, short] = False
    return held


@dataclass(frozen=True)
class RankChoice:
    """The completion rank chosen by :func:`choose_rank`, and how much it leaves unexplained.

    rank : int
    unexplained : float
        The held-out error at ``rank`` over rank one's, each less the noise variance of the
        held-out entries (runs and single entries alike); 0 when nothing was held out. Small
        where the tracks are close to low rank (faces and sheets, noise-free and at 1-3 %
        noise: at most 0.03), large where the rank that generalises leaves much of the
        deformation out (an articulated body's markers: mostly 0.07-0.33).
    gap : GapFill
        The correction from the tracks (:data:`moju_core.completion.gaps.CANDIDATES`) with the
        smallest held-out error at ``rank``, the groups weighted as for the rank; none on
        ties.
    reach : int
        The largest distance (frames) to the nearest training frame of the point up to which
        the held-out entries, with the gap correction, leave at most :data:`MAX_UNEXPLAINED`
        of rank one's held-out error unexplained, in every band of distances
        (:data:`REACH_BANDS`); 0 when the nearest band does not.
    """

    rank: int
    unexplained: float
    gap: gaps.GapFill = gaps.GapFill()
    reach: int = 0


def choose_rank(W: np.ndarray, visibility: np.ndarray, noise: float = 0.0) -> RankChoice:
    """The completion rank with the smallest error on held-out observed entries
    (:func:`hold_out`), the random entries and the runs weighted equally.

    ``noise``: the noise variance of an entry of W, taken off the held-out errors for
    :attr:`RankChoice.unexplained` only.
    """
    rng = np.random.default_rng(0)
    n_points = W.shape[1]
    if n_points > RANK_SELECTION_POINTS:
        points = np.sort(rng.choice(n_points, RANK_SELECTION_POINTS, replace=False))
        W, visibility = W[:, points], visibility[:, points]
    held = hold_out(visibility, rng)
    if not held.any():
        return RankChoice(1, 0.0)
    training = visibility & ~held
    # Split the held-out entries into the runs and the single entries for equal weights.
    in_run = held & (np.roll(held, 1, axis=0) | np.roll(held, -1, axis=0))
    groups = [m for m in (expand_mask(in_run), expand_mask(held & ~in_run)) if m.any()]
    errors: dict[int, list[float]] = {}  # per rank: the runs' and the single entries'
    best, best_error, worse, best_values = 1, np.inf, 0, None
    for rank in CANDIDATE_RANKS:
        if 2 * rank >= min(W.shape):
            break
        model = complete_at_rank(W, training, rank).values()
        residual = (model - W) ** 2
        errors[rank] = [float(np.mean(residual[m])) for m in groups]
        error = sum(errors[rank])
        if error < best_error:
            best, best_error, worse, best_values = rank, error, 0, model
        elif error > 2 * best_error:
            worse += 1
            if worse == OVERFIT_PATIENCE:
                break  # overfitting grows with the rank
    if not errors:
        return RankChoice(1, 0.0)

    def beyond_noise(rank: int) -> float:
        return sum(max(error - noise, 0.0) for error in errors[rank])

    baseline = beyond_noise(1)
    unexplained = beyond_noise(best) / baseline if baseline > 0 else 0.0
    rows = expand_mask(held)
    gap, squared = _choose_gap(W, training, best_values, rows, groups)
    held_squared = np.zeros(W.shape)
    held_squared[rows] = squared
    # Per entry, like one group's mean: rank one's error over the groups' average.
    allowed = MAX_UNEXPLAINED * baseline / len(groups)
    reach = _reach(held_squared, training, held, noise, allowed)
    return RankChoice(best, unexplained, gap, reach)


#: Bands of distances (frames, inclusive) to the nearest training frame in which
#: :func:`choose_rank` compares the held-out error for :attr:`RankChoice.reach`, and the fewest
#: held-out entries a band needs to count.
REACH_BANDS = ((1, 1), (2, 3), (4, 7), (8, 15), (16, 31), (32, 63), (64, 127))
REACH_MIN_ENTRIES = 20


def _reach(
    squared: np.ndarray, training: np.ndarray, held: np.ndarray, noise: float, allowed: float
) -> int:
    """:attr:`RankChoice.reach` from the corrected values' squared errors (2F, n) at the
    held-out entries (``held``, (F, n) bool)."""
    distance = gaps.distance_to_observed(training)
    squared = squared.reshape(training.shape[0], 2, -1).mean(axis=1)
    reach = 0
    for low, high in REACH_BANDS:
        band = held & (distance >= low) & (distance <= high)
        if band.sum() < REACH_MIN_ENTRIES or np.mean(squared[band]) - noise > allowed:
            break
        reach = high
    return reach


def _choose_gap(
    W: np.ndarray,
    training: np.ndarray,
    values: np.ndarray,
    held: np.ndarray,
    groups: list[np.ndarray],
) -> tuple[gaps.GapFill, np.ndarray]:
    """The correction from the tracks with the smallest held-out error (summed over the
    groups of held-out entries, (2F, n) masks whose union is ``held``) of ``values``, a fit
    on ``training``; none unless it is lower than the completion's own. Also the corrected
    values' squared errors at ``held``. O(F n) once, then
    O(held-out entries) per candidate."""
    parts = gaps.pieces(W, values, training).at(held)
    error = (values - W)[held]
    members = [m[held] for m in groups]
    plain = error**2
    best, best_error, best_squared = gaps.GapFill(), np.inf, plain
    for gap in gaps.CANDIDATES:
        squared = (error + parts.correction(gap)) ** 2
        total = sum(float(np.mean(squared[m])) for m in members)
        if total < best_error:
            best, best_error, best_squared = gap, total, squared
    gain = plain - best_squared
    if sum(float(np.mean(gain[m])) for m in members) > 0:
        return best, best_squared
    return gaps.GapFill(), plain


def complete_at_rank(
    W: np.ndarray,
    visibility: np.ndarray,
    rank: int,
    em_sweeps: int = COMPLETION_SWEEPS,
    als_sweeps: int = ALS_SWEEPS,
) -> LowRank:
    """Rank-r model of W: EM warm start, then ALS sweeps (see the module docstring)."""
    mask = expand_mask(visibility)
    counts = mask.sum(axis=1)
    translation = np.where(mask, W, 0.0).sum(axis=1) / np.maximum(counts, 1)
    filled = np.where(mask, W, translation[:, None])
    centred = filled - translation[:, None]
    rank = max(1, min(rank, min(W.shape) - 1))
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(centred @ rng.standard_normal((centred.shape[1], rank)))[0]
    coefficients = basis.T @ centred
    for _ in range(em_sweeps):
        # One subspace-iteration step of the centred filled matrix, then refill.
        model = basis @ coefficients + translation[:, None]
        filled = np.where(mask, W, model)
        translation = filled.mean(axis=1)
        centred = filled - translation[:, None]
        basis = np.linalg.qr(centred @ coefficients.T)[0]
        coefficients = basis.T @ centred  # (r, P)
    left, right = basis, coefficients
    data = np.where(mask, W, 0.0)
    for _ in range(als_sweeps):
        right = solve_points(left, data - translation[:, None] * mask, visibility)
        augmented = solve_frames(
            np.vstack([right, np.ones((1, right.shape[1]))]).T, data, visibility
        )  # (r + 1, 2F)
        left, translation = augmented[:-1].T, augmented[-1].copy()
    return LowRank(left=np.ascontiguousarray(left), right=right, translation=translation)


def trusted_entries(model: LowRank, visibility: np.ndarray, *, noisy: bool = False) -> np.ndarray:
    """The observed entries and the hidden ones the model predicts well enough to use as data.

    A hidden entry is trusted when its :meth:`LowRank.leverage` is at most
    :data:`TRUSTED_LEVERAGE`; a point seen in a few frames only is not. No hidden entry is
    when a model that is not exact leaves more than :data:`MAX_UNEXPLAINED` of the held-out
    error unexplained (:attr:`LowRank.unexplained`), except, where :meth:`LowRank.fill`
    corrects the model from the tracks (:attr:`LowRank.gap`), those of noise-free tracks
    within :attr:`LowRank.reach` frames of an observed frame of their point: the held-out
    entries at those distances were predicted that well. Of noisy tracks (``noisy``), only
    where the model's prediction is also as precise as a measurement (the second of
    :meth:`LowRank.variance_factors` at most 1): a less precise completion fitted as data adds
    more noise than the measurements carry, and so would the correction from the neighbouring
    frames. Noise-free tracks have no such bound (the model's error there is not noise; see
    :data:`TRUSTED_LEVERAGE`).
    """
    if model.unexplained > MAX_UNEXPLAINED and (noisy or not model.gap.corrects):
        return visibility.copy()  # (unexplained is 0 for an exact model)
    leverage, variance = model.variance_factors(visibility)
    trusted = leverage <= TRUSTED_LEVERAGE
    if noisy:
        trusted &= variance <= 1.0
    if model.unexplained > MAX_UNEXPLAINED:
        trusted &= gaps.distance_to_observed(visibility) <= model.reach
    return visibility | trusted
