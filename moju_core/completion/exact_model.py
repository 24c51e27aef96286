"""The exact low-rank model of noise-free tracks with hidden entries.

Noise-free tracks of a few-basis deformation are exactly of low rank, and then their hidden
entries can be predicted as exactly as they would be measured: :func:`exact_model` looks for
such a model (column spaces from windows of frames, alternating least squares until the
observed entries are fitted to rounding, tested on held-out points) and returns None when W
is not exactly of low rank. :func:`moju_core.completion.missing.complete` tries it first.
"""

from __future__ import annotations

import itertools

import numpy as np

from moju_core.completion import window_subspace
from moju_core.completion.least_squares import (
    centred_part,
    exact_span,
    point_normals,
    solve_frames,
    solve_points,
)
from moju_core.completion.missing import LowRank, expand_mask, hold_out, well_seen

#: Sweeps of alternating least squares (at most) in :func:`exact_model`, and their ridge (as
#: :data:`ALS_RIDGE`; an exact fit needs next to none).
EXACT_SWEEPS = 100
EXACT_RIDGE = 1e-9
#: Sweeps between the checks of :func:`_alternate`, and how many sweeps without the misfit
#: halving make a stall: one check for every rank tried but the last, 20 sweeps for the last,
#: since ALS can sit on a plateau for tens of sweeps at the right rank before it falls to
#: round-off.
EXACT_CHECK_EVERY = 5
EXACT_PATIENCE = 20
#: Misfit (relative to the entries' mean square) at which :func:`_alternate` takes the fit as
#: exact: above the rounding level ALS reaches on exactly low-rank tracks, below the misfit
#: of tracks off a low-rank model by 1e-6 of their RMS (1e-12), which are not exact.
EXACT_FIT_MISFIT = 1e-13
#: Fraction of the selected points set aside to test :func:`exact_model`, and the largest
#: mean squared error at their held-out entries, relative to the tracks' mean square, for
#: which the model is taken as exact (1e-5 of the RMS): a model whose hidden entries are
#: fitted as data must predict them as closely as rounding allows exactly low-rank tracks.
EXACT_TEST_FRACTION = 0.1
EXACT_MODEL_ERROR = 1e-10
#: Well-seen points (at most) on which :func:`exact_model` fits and tests the model, and the
#: candidate column spaces it tries (:func:`moju_core.completion.window_subspace.column_spaces`):
#: a cost bound; the first candidate almost always holds, and tracks that are not exactly of
#: low rank pay 20-100 sweeps per candidate for nothing.
EXACT_POINTS = 500
EXACT_CANDIDATES = 2
#: :func:`_trimmed`: a point sees every direction of an orthonormal basis on its observed rows
#: when their smallest singular value is at least this, far above the square root of
#: :data:`EXACT_RIDGE` (3e-5), below which the ridge, not the data, sets a coefficient; and a
#: drop of the coefficients' singular values by :data:`SPARE_GAP` marks where the spare
#: directions begin (between a W's own directions the steps are 0.1-1, to its spare ones
#: 1e-3 and less; each size is kept only if ALS then fits exactly). SPARE_GAP at 0 changed no
#: held-out solve (benchmarks/notes/2026-12-06-rule-ablation.md): its test guards it.
VISIBLE_DIRECTIONS = 1e-2
SPARE_GAP = 0.1
#: Fewer well-seen points than this many test points' worth (sparse markers: 41 on face4) do
#: not test a model: :func:`exact_model` does not try.
EXACT_MIN_TEST_POINTS = 10


def exact_model(W: np.ndarray, visibility: np.ndarray) -> LowRank | None:
    """The model of an exactly low-rank W (noise-free tracks of a few-basis deformation), or None.

    1. Of the well-seen points (at most :data:`EXACT_POINTS`, chosen at random), a tenth are
       set aside to test the model (:data:`EXACT_TEST_FRACTION`; None if that is fewer than
       :data:`EXACT_MIN_TEST_POINTS`); they lose entries as in the rank choice
       (:func:`hold_out`: runs of frames and single entries).
    2. Candidate column spaces of the other points, uncentred, from windows of frames
       (:func:`moju_core.completion.window_subspace.column_spaces`); none if W is not exactly of low
       rank in them.
    3. From each candidate in turn (at most :data:`EXACT_CANDIDATES`): alternating least
       squares on those points' observed entries (ridge :data:`EXACT_RIDGE`), from the
       windows' rank, one stitched direction more each time it stalls (:func:`_alternate`),
       until the fit is exact; the model's rank is then that of its fitted values. It is
       kept if its prediction of the test points' held-out entries (their coefficients from
       the rest) has a mean squared error of at most :data:`EXACT_MODEL_ERROR` of the
       tracks' mean square. None if no candidate is kept.
    4. Every point's coefficients are solved on its observed entries, and the model is
       written with its translation apart, at the rank of its centred part.

    The EM and ALS fit of :func:`complete_at_rank` converges slowly in the weak directions of
    such a W (faces: singular values down to 2e-4 of the largest): on face3 with the combined
    occlusion its rank-13 fit stayed 80 degrees off in the weakest direction after 300 sweeps,
    so the rank choice preferred rank 6, whose errors at hidden entries (about 1 % of the
    tracks' RMS) put the cameras estimated from it 0.8-1.8 degrees off. Here the trusted
    hidden entries are predicted to 2e-5 to 5e-5 of the RMS on faces (seeds 0-3), 1e-7 to 1e-6
    on the cloth and the flag.

    Cost: the windows (:mod:`moju_core.completion.window_subspace`), then O(F n k^2) per sweep on
    the n
    selected points and O(F P k^2) for the coefficients of all points.
    """
    rng = np.random.default_rng(0)
    points = np.flatnonzero(well_seen(visibility))
    if points.size > EXACT_POINTS:
        points = np.sort(rng.choice(points, EXACT_POINTS, replace=False))
    if points.size * EXACT_TEST_FRACTION < EXACT_MIN_TEST_POINTS:
        return None
    testing = rng.random(points.size) < EXACT_TEST_FRACTION
    fitting, tested = points[~testing], points[testing]
    sample, seen = W[:, tested], visibility[:, tested]
    held = hold_out(seen, rng)
    if not held.any():
        return None
    training, held_rows = seen & ~held, expand_mask(held)
    energy = _centred_energy(sample, expand_mask(seen))
    candidates = window_subspace.column_spaces(W[:, fitting], visibility[:, fitting])
    for basis, rank in itertools.islice(candidates, EXACT_CANDIDATES):
        # The windows' rank first, then more of the stitched directions while ALS stalls.
        for size in range(rank, basis.shape[1] + 1):
            # ALS can sit on a plateau for tens of sweeps before it converges: the last size
            # gets the longer patience.
            patience = EXACT_PATIENCE if size == basis.shape[1] else EXACT_CHECK_EVERY
            left = _alternate(W[:, fitting], visibility[:, fitting], basis[:, :size], patience)
            if left is not None:
                break
        else:
            continue
        if size > rank:
            left = _trimmed(W[:, fitting], visibility[:, fitting], left, rank)
        left = exact_span(left, solve_points(left, *_masked(W, visibility, fitting)))
        right = solve_points(left, np.where(expand_mask(training), sample, 0.0), training,
                              EXACT_RIDGE)  # fmt: skip
        error = float(np.mean((left @ right - sample)[held_rows] ** 2))
        if error <= EXACT_MODEL_ERROR * energy:
            break
    else:
        return None
    # The translation apart, from the fitting points (their coefficients are exact); then
    # every point's coefficients in the centred part, of one dimension fewer than ``left``.
    left, translation = centred_part(left, solve_points(left, *_masked(W, visibility, fitting)))
    data = np.where(expand_mask(visibility), W - translation[:, None], 0.0)
    right = solve_points(left, data, visibility, EXACT_RIDGE)
    return LowRank(left=left, right=right, translation=translation, exact=True)


def _centred_energy(values: np.ndarray, mask: np.ndarray) -> float:
    """Mean square of the masked entries of ``values`` less their row means (rows with no
    entry in ``mask`` count for nothing)."""
    counts = mask.sum(axis=1, keepdims=True)
    means = np.where(mask, values, 0.0).sum(axis=1, keepdims=True) / np.maximum(counts, 1)
    centred = np.where(mask, values - means, 0.0)
    return float(np.vdot(centred, centred) / max(1, mask.sum()))


def _masked(
    W: np.ndarray, visibility: np.ndarray, columns: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The arguments of :func:`solve_points` for the given columns of W, exact ridge."""
    seen = visibility[:, columns]
    return np.where(expand_mask(seen), W[:, columns], 0.0), seen, EXACT_RIDGE


def _alternate(
    W: np.ndarray, visibility: np.ndarray, left: np.ndarray, patience: int
) -> np.ndarray | None:
    """``left`` (2F, k) after sweeps of ALS for ``W ~ left @ right`` on the observed entries
    (no separate translation: W is not centred), or None if the fit does not become exact.

    At most :data:`EXACT_SWEEPS` sweeps; every :data:`EXACT_CHECK_EVERY` the misfit (relative
    to the entries' mean square) is checked: at most :data:`EXACT_FIT_MISFIT` the fit is
    exact; if it has not halved within ``patience`` sweeps, ALS has stalled.
    """
    mask = expand_mask(visibility)
    data = np.where(mask, W, 0.0)
    energy = float(np.mean(data[mask] ** 2))
    best, since = np.inf, 0
    for sweep in range(1, EXACT_SWEEPS + 1):
        right = solve_points(left, data, visibility, EXACT_RIDGE)
        if sweep % EXACT_CHECK_EVERY == 0:
            misfit = float(np.mean((left @ right - data)[mask] ** 2)) / energy
            if misfit <= EXACT_FIT_MISFIT:
                return left
            since += EXACT_CHECK_EVERY
            if misfit <= 0.5 * best:
                best, since = misfit, 0
            elif since >= patience:
                return None
        left = solve_frames(right.T, data, visibility, EXACT_RIDGE).T
    return None


def _trimmed(W: np.ndarray, visibility: np.ndarray, left: np.ndarray, smallest: int) -> np.ndarray:
    """An exact fit ``left`` (2F, k) of more directions than W has, cut to W's column space.

    ALS fits the observed entries exactly with spare directions that are next to zero on the
    observed rows of some points, and those points' coefficients carry them at their hidden
    entries (face3, combined occlusion: errors there up to 0.25 of the largest track value). The
    other points (the smallest singular value of ``left``'s orthonormal basis on their
    observed rows at least :data:`VISIBLE_DIRECTIONS`) determine their coefficients, which
    then span W's directions only: the leading ``k'`` of them, for each ``k'`` from
    ``smallest`` up at which the coefficients' singular values drop by :data:`SPARE_GAP`,
    start ALS (:func:`_alternate`); the first exact fit is returned, else ``left``.
    O(F n k^2) for the n points and each ALS sweep.
    """
    basis = np.linalg.qr(left)[0]
    visible = np.linalg.eigvalsh(point_normals(basis, visibility))[:, 0] >= VISIBLE_DIRECTIONS**2
    if not visible.any():
        return left
    coefficients = solve_points(basis, *_masked(W, visibility, np.flatnonzero(visible)))
    directions, values, _ = np.linalg.svd(coefficients, full_matrices=False)
    for size in range(smallest, basis.shape[1]):
        if values[size] > SPARE_GAP * values[size - 1]:
            continue
        fitted = _alternate(W, visibility, basis @ directions[:, :size], EXACT_PATIENCE)
        if fitted is not None:
            return fitted
    return left
