"""The temporal smoothness prior on the shapes, and the two ways the loop applies it.

A point on a deforming surface moves smoothly between frames when the video is sampled fast
enough. The prior ``gamma / 2 ||D S||_F^2`` penalises the second differences along the frames
(D is the (F - 2) x F second-difference matrix, ``(D S)_f = S_f - 2 S_{f+1} + S_{f+2}``,
applied to every coordinate of every point): it costs nothing for a point that moves at
constant velocity and lets a frame's unseen depth borrow from the neighbouring frames, which
see that direction in their image plane when the camera turns (the trajectory-space argument
of Akhter et al., NIPS 2008, without a fixed basis). With ``gamma = 0`` the loop is the paper's.

``D^T D`` is pentadiagonal, and everything here uses that structure: no F x F matrix is ever
formed, and every operation costs O(F) per column.

**Fixed cameras: a filter after the S# step.** After the singular value threshold
(Algorithm 1, step 10) the result is passed through the proximal operator of the prior at the
current penalty,

    S# <- G_rho SVT(f(S) - L1 / rho),   G_rho = (I + (gamma / rho) D^T D)^{-1}   (F x F),

a splitting of the step's two terms (each proximal operator in turn). ``G_rho`` acts on the
frames only, so it filters the temporal factor of the thresholded S#: with ``S# = U Sigma V^T``
of rank r the result is ``(G_rho U) Sigma V^T``, one pentadiagonal solve with r right-hand
sides (:class:`FrameFilter`), O(F r).

**Cameras refined in the loop: the exact S-update.** When the loop also re-fits the rotations
to S# (windowed cameras, :mod:`moju_core.cameras`), the splitting is not enough: measured at
2,000 points with the cloth, e3D 0.115 for every weight from 1 to 100 against 0.04 with the
prior solved exactly. The S-update (step 1) then couples the frames:

    (R^T R + rho I + gamma (D^T D kron I_3)) S = R^T W + rho T

for every point (one 3F x 3F system shared by all columns). In the interleaved order of the
trajectory form (row ``3f + c``) its matrix is symmetric positive definite and banded with 8
off-diagonals: ``R_f^T R_f = I - n_f n_f^T`` couples the three coordinates of a frame, and
``D^T D`` couples frame f to frames f +- 1 and f +- 2 (rows 3 and 6 apart). One banded Cholesky
factorisation (O(F)) and a banded solve for the P columns (O(F P)) replace the dense system
(:func:`smooth_data_step`).

**Tracks without measurable noise: the depth step.** With fixed cameras and tracks whose
noise is negligible (:data:`moju_core.defaults.EXACT_DATA_NOISE`), the S-update fits them
exactly: ``S_f = R_f^T W_f + n_f d_f^T`` and the prior chooses only the depths d, by one
pentadiagonal F x F system for all P points (:func:`depth_step`). It never pulls against the
motion the camera sees in the image plane, so a weight that is strong for the depth costs
nothing in the fit. With hidden entries the observed ones are fitted exactly and the hidden
ones placed in the image first (:func:`masked_depth_step`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded, solveh_banded

#: Off-diagonals of the S-update's banded matrix in the interleaved (3f + c) order: frame f is
#: coupled to frame f + 2, six rows further, and a frame's own 3 x 3 block adds two more.
S_UPDATE_BANDS = 8


class TemporalPrior(NamedTuple):
    """The second-difference penalty ``D^T D`` in banded form, and its weight.

    bands : ndarray of shape (3, F)
        Upper banded storage of the pentadiagonal ``D^T D`` (the layout of
        :func:`scipy.linalg.solveh_banded`): ``bands[2 + i - j, j] = (D^T D)[i, j]``.
    weight : float
        gamma, the weight of the prior relative to the data term (scale-normalised tracks).
    """

    bands: np.ndarray
    weight: float

    @property
    def n_frames(self) -> int:
        return self.bands.shape[1]


def second_differences(n_frames: int) -> np.ndarray:
    """The second-difference matrix D along the frames, shape (max(F - 2, 0), F), dense.

    Row f is ``e_f - 2 e_{f+1} + e_{f+2}``; with fewer than three frames it has no rows (no
    acceleration to penalise). For tests and small examples: the solver uses
    :func:`penalty_bands`.
    """
    return np.diff(np.eye(n_frames), n=2, axis=0)


def penalty_bands(n_frames: int) -> np.ndarray:
    """``D^T D`` for F frames in upper banded storage, shape (3, F), built in O(F).

    Each row ``(1, -2, 1)`` of D at frames (r, r + 1, r + 2) adds its outer product: 1, 4, 1 on
    the diagonal, -2, -2 on the first off-diagonal and 1 on the second.
    """
    bands = np.zeros((3, n_frames))
    rows = np.arange(max(n_frames - 2, 0))
    for offset, weight in ((0, 1.0), (1, 4.0), (2, 1.0)):
        np.add.at(bands[2], rows + offset, weight)
    for offset in (1, 2):
        np.add.at(bands[1], rows + offset, -2.0)  # entry (r + offset - 1, r + offset)
    bands[0, rows + 2] += 1.0  # entry (r, r + 2)
    return bands


def temporal_prior(n_frames: int, weight: float) -> TemporalPrior:
    """The prior ``weight / 2 ||D S#||^2`` for F frames, ready for :func:`smoothing_filter` or
    :func:`smooth_data_step`."""
    if weight < 0 or not np.isfinite(weight):
        raise ValueError(f"the smoothness weight must be a finite number >= 0, got {weight!r}")
    return TemporalPrior(penalty_bands(n_frames), float(weight))


class FrameFilter:
    """The proximal operator of the prior at penalty rho, ``G_rho = (I + (gamma/rho) D^T D)^-1``.

    ``argmin_Y gamma/2 ||D Y||^2 + rho/2 ||Y - X||^2 = G_rho X``. Calling it on an (F, r)
    array applies ``G_rho`` by a pentadiagonal solve, O(F r); constant and linear motion pass
    unchanged and every other direction is damped (eigenvalues in (0, 1]).
    """

    def __init__(self, prior: TemporalPrior, rho: float) -> None:
        self.bands = (prior.weight / rho) * prior.bands
        self.bands[2] += 1.0

    def __call__(self, columns: np.ndarray) -> np.ndarray:
        """``G_rho @ columns`` for columns of shape (F,) or (F, r)."""
        if columns.shape[0] < 3:
            return columns.copy()  # no second differences: G_rho = I
        return solveh_banded(self.bands, columns, check_finite=False)

    def matrix(self) -> np.ndarray:
        """``G_rho`` as a dense (F, F) matrix (for tests and small examples only)."""
        return self(np.eye(self.bands.shape[1]))


def smoothing_filter(prior: TemporalPrior, rho: float) -> FrameFilter:
    """The filter that follows the S# step when the cameras are fixed (:class:`FrameFilter`)."""
    return FrameFilter(prior, rho)


def s_update_bands(normals: np.ndarray, rho: float, prior: TemporalPrior) -> np.ndarray:
    """The exact S-update's matrix ``R^T R + rho I + gamma D^T D kron I_3``, banded.

    Parameters
    ----------
    normals : ndarray of shape (F, 3)
        Unit viewing directions (``R_f^T R_f = I - n_f n_f^T``).
    rho : float
        Penalty, > 0.
    prior : TemporalPrior

    Returns
    -------
    ndarray of shape (S_UPDATE_BANDS + 1, 3F)
        Upper banded storage, ``bands[8 + i - j, j] = A[i, j]`` in the order ``3f + c``.
    """
    n_frames = normals.shape[0]
    top = S_UPDATE_BANDS
    bands = np.zeros((top + 1, 3 * n_frames))
    frames = 3 * np.arange(n_frames)
    for c in range(3):
        bands[top, frames + c] = 1.0 + rho - normals[:, c] ** 2
        # Frame f with frames f - 1 and f - 2, same coordinate: rows 3 and 6 apart.
        bands[top - 3, frames + c] = prior.weight * prior.bands[1]
        bands[top - 6, frames + c] = prior.weight * prior.bands[0]
        bands[top, frames + c] += prior.weight * prior.bands[2]
    for a, b in ((0, 1), (0, 2), (1, 2)):  # within a frame: -n_a n_b at (3f + a, 3f + b)
        bands[top - (b - a), frames + b] = -normals[:, a] * normals[:, b]
    return bands


def smooth_data_step(
    back_projected: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    rho: float,
    prior: TemporalPrior,
    out: np.ndarray,
) -> np.ndarray:
    """S-update with the temporal prior (see the module docstring).

    Solves ``(R^T R + rho I + gamma D^T D kron I_3) S = R^T W + rho T`` for every point by one
    banded Cholesky factorisation, O(F), and a banded solve of the P columns, O(F P).

    Parameters
    ----------
    back_projected : ndarray of shape (F, 3, P)
        ``R_f^T W_f`` (:func:`moju_core.cameras.projection.back_project`).
    normals : ndarray of shape (F, 3)
        Unit viewing directions (:func:`moju_core.cameras.projection.viewing_directions`).
    target : ndarray of shape (F, 3, P), C-contiguous
        ``finv(S# + L1 / rho)``. It is used as scratch space and overwritten.
    rho : float
        Penalty parameter, > 0.
    prior : TemporalPrior
        The second-difference penalty and its weight (:func:`temporal_prior`).
    out : ndarray of shape (F, 3, P), C-contiguous
        Where the solution is written (must not share memory with the inputs).

    Returns
    -------
    ndarray of shape (F, 3, P)
        ``out``.
    """
    n_frames, _, n_points = out.shape
    factor = cholesky_banded(s_update_bands(normals, rho, prior), check_finite=False)
    np.multiply(target, rho, out=target)
    target += back_projected
    # LAPACK wants each right-hand side (a point's 3F-vector) contiguous: one transposing copy.
    rhs = np.asfortranarray(target.reshape(3 * n_frames, n_points))
    solution = cho_solve_banded((factor, False), rhs, overwrite_b=True, check_finite=False)
    out.reshape(3 * n_frames, n_points)[...] = solution
    return out


def depth_bands(normals: np.ndarray, rho: float, prior: TemporalPrior) -> np.ndarray:
    """The depth step's matrix ``gamma N^T (D^T D kron I_3) N + rho I`` (F x F), banded.

    ``N = blockdiag(n_f)`` (3F x F) puts a depth along each frame's viewing direction, so
    entry (f, g) is ``gamma (D^T D)[f, g] n_f . n_g``: pentadiagonal like ``D^T D``.

    Returns
    -------
    ndarray of shape (3, F)
        Upper banded storage (the layout of :attr:`TemporalPrior.bands`).
    """
    bands = prior.weight * prior.bands.copy()
    bands[1, 1:] *= np.einsum("fc,fc->f", normals[:-1], normals[1:])
    bands[0, 2:] *= np.einsum("fc,fc->f", normals[:-2], normals[2:])
    bands[2] += rho
    return bands


def penalty_times(shapes: np.ndarray) -> np.ndarray:
    """``(D^T D kron I_3) S`` for shapes of shape (F, 3, P), O(F P): second differences of the
    second differences along the frames."""
    differences = np.diff(shapes, n=2, axis=0)
    out = np.zeros_like(shapes)
    out[:-2] += differences
    out[1:-1] -= 2.0 * differences
    out[2:] += differences
    return out


#: Right-hand sides from which :func:`solve_factored_bands` substitutes row by row across all
#: of them instead of calling LAPACK, which solves one right-hand side at a time: the row
#: sweep costs about 5 us per row plus 0.6 ns per entry, LAPACK about 25 ns per entry, so
#: the sweep wins from about 200-330 columns whatever the number of rows (F = 99: 396
#: columns 0.56 ms against 0.67 ms; F = 350: 350 columns 2.0 ms against 3.1 ms).
ROW_SWEEP_MIN_COLUMNS = 300


def solve_factored_bands(factor: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``U^T U x = rhs`` for the upper banded Cholesky factor of a pentadiagonal matrix.

    Parameters
    ----------
    factor : ndarray of shape (3, F)
        :func:`scipy.linalg.cholesky_banded` of the matrix (upper form, 2 off-diagonals).
    rhs : ndarray of shape (F, P)
        Right-hand sides (overwritten).

    Returns
    -------
    ndarray of shape (F, P)
    """
    n_rows, n_columns = rhs.shape
    if n_columns < ROW_SWEEP_MIN_COLUMNS:
        return cho_solve_banded((factor, False), rhs, overwrite_b=True, check_finite=False)
    # U has the diagonal factor[2], U[r, r + 1] = factor[1, r + 1], U[r, r + 2] = factor[0, r + 2].
    # Each row takes its two neighbours as one (2,) x (2, P) product: fewer calls per row.
    scale = 1.0 / factor[2]
    below = np.stack([factor[0], factor[1]], axis=1)  # row r: (U[r-2, r], U[r-1, r])
    above = np.zeros((n_rows, 2))  # row r: (U[r, r+1], U[r, r+2])
    above[:-1, 0] = factor[1, 1:]
    above[:-2, 1] = factor[0, 2:]
    rhs[0] *= scale[0]  # U^T y = rhs, in place
    if n_rows > 1:
        rhs[1] -= factor[1, 1] * rhs[0]
        rhs[1] *= scale[1]
    for row in range(2, n_rows):
        rhs[row] -= below[row] @ rhs[row - 2 : row]
        rhs[row] *= scale[row]
    rhs[n_rows - 1] *= scale[n_rows - 1]  # U x = y, in place
    if n_rows > 1:
        rhs[n_rows - 2] -= above[n_rows - 2, 0] * rhs[n_rows - 1]
        rhs[n_rows - 2] *= scale[n_rows - 2]
    for row in range(n_rows - 3, -1, -1):
        rhs[row] -= above[row] @ rhs[row + 1 : row + 3]
        rhs[row] *= scale[row]
    return rhs


def depth_pull(back_projected: np.ndarray, normals: np.ndarray, prior: TemporalPrior) -> np.ndarray:
    """``gamma N^T (D^T D kron I_3) S0``, the depth step's constant part, (F, P).

    It depends on the tracks and the cameras only, so the loop computes it once per solve.
    """
    return prior.weight * np.einsum("fc,fcp->fp", normals, penalty_times(back_projected))


def depth_step(
    back_projected: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    rho: float,
    prior: TemporalPrior,
    out: np.ndarray,
    pull: np.ndarray | None = None,
) -> np.ndarray:
    """S-update with the temporal prior and the tracks fitted exactly (near noise-free tracks).

    Every shape that reprojects the tracks exactly is ``S = S0 + N d``: the zero-depth start
    ``S0_f = R_f^T W_f`` plus one depth per frame and point along the viewing direction
    ``n_f``. The step minimises ``gamma/2 ||D S||^2 + rho/2 ||S - T||^2`` over the depths:

        (gamma N^T (D^T D kron I_3) N + rho I) d = rho N^T T - gamma N^T (D^T D kron I_3) S0,

    one pentadiagonal F x F factorisation and a banded solve of the P columns, O(F P), cheaper
    than :func:`smooth_data_step`. The prior then acts on the unseen depth only, never against
    the observed motion in the image plane.

    Parameters
    ----------
    back_projected : ndarray of shape (F, 3, P)
        ``S0 = R_f^T W_f`` (no component along ``n_f``).
    normals : ndarray of shape (F, 3)
        Unit viewing directions.
    target : ndarray of shape (F, 3, P)
        ``finv(S# + L1 / rho)``.
    rho : float
        Penalty parameter, > 0.
    prior : TemporalPrior
    out : ndarray of shape (F, 3, P), C-contiguous
        Where the solution is written (must not share memory with the inputs).
    pull : ndarray of shape (F, P), optional
        :func:`depth_pull` of ``back_projected``, if the caller keeps it.

    Returns
    -------
    ndarray of shape (F, 3, P)
        ``out``.
    """
    if pull is None:
        pull = depth_pull(back_projected, normals, prior)
    return _depth_solution(
        normals, rho, prior, _depth_rhs(normals, target, rho, pull), back_projected, out
    )


def _depth_rhs(normals: np.ndarray, target: np.ndarray, rho: float, pull: np.ndarray) -> np.ndarray:
    """The depth step's right-hand side ``rho N^T T - pull``, (F, P), a new array."""
    rhs = np.einsum("fc,fcp->fp", normals, target)
    rhs *= rho
    rhs -= pull
    return rhs


def _depth_solution(
    normals: np.ndarray,
    rho: float,
    prior: TemporalPrior,
    rhs: np.ndarray,
    back_projected: np.ndarray,
    out: np.ndarray,
) -> np.ndarray:
    """``S0 + N d`` into ``out`` (F, 3, P), the depths d (F, P) solved for the depth step's
    right-hand side ``rhs`` (overwritten), O(F P)."""
    factor = cholesky_banded(depth_bands(normals, rho, prior), check_finite=False)
    depths = solve_factored_bands(factor, rhs)
    np.multiply(normals[:, :, None], depths[:, None, :], out=out)
    out += back_projected
    return out


def masked_depth_step(
    back_projected: np.ndarray,
    measured: np.ndarray,
    anchored: np.ndarray,
    normals: np.ndarray,
    target: np.ndarray,
    rho: float,
    prior: TemporalPrior,
    out: np.ndarray,
    pull: np.ndarray | None = None,
) -> np.ndarray:
    """The depth step of tracks with hidden entries: measured entries fitted exactly.

    A split of the S-update ``gamma/2 ||D S||^2 + rho/2 ||S - T||^2 + 1/2 sum_{anchored}
    ||R_f S_f - W_f||^2`` subject to ``R_f S_f = W_f`` at the measured entries:

    1. the image-plane position of every hidden entry minimises ``rho/2 ||u - P_f G_rho T||^2
       + a/2 ||u - P_f R_f^T W_f||^2`` (``a`` = 1 where anchored, 0 where free; ``P_f`` the
       projection on frame f's image plane): the coupling target passed through the prior's
       proximal operator ``G_rho`` (:class:`FrameFilter`), pulled towards the completion;
    2. :func:`depth_step` on all entries, the measured ones at their tracks.

    Step 1 is one pentadiagonal solve with 3n right-hand sides for the n points with a hidden
    entry that is not measured, step 2 one with P: O(F P).
    The exact minimiser couples every point's hidden entries through the prior, a different
    3F x 3F system for each point; solved by conjugate gradients it gave the same e3D on the
    paper, face3 and bumps-osc (combined occlusion, known cameras) at 10-20 times the cost of
    the S-update. With every entry measured this is :func:`depth_step`.

    Parameters
    ----------
    back_projected : ndarray of shape (F, 3, P)
        ``R_f^T W_f``, with the hidden entries' tracks at their completion where anchored.
    measured, anchored : ndarray of shape (F, P), bool
        Entries fitted exactly, and hidden entries pulled towards their completion (disjoint).
    normals : ndarray of shape (F, 3)
    target : ndarray of shape (F, 3, P)
        ``finv(S# + L1 / rho)``.
    rho : float
    prior : TemporalPrior
    out : ndarray of shape (F, 3, P), C-contiguous
        Where the solution is written (must not share memory with the inputs).
    pull : ndarray of shape (F, P), optional
        :func:`depth_pull` of ``back_projected``, if the caller keeps it.

    Returns
    -------
    ndarray of shape (F, 3, P)
        ``out``.
    """
    if pull is None:
        pull = depth_pull(back_projected, normals, prior)
    # Only the points with an entry that is not measured move off their tracks.
    points = np.flatnonzero(~measured.all(axis=0))
    if points.size == 0:
        return depth_step(back_projected, normals, target, rho, prior, out, pull)
    n_frames, _, n_points = target.shape
    # Where every point has such an entry (a band over most of a sheet, sparse markers), whole
    # arrays in place of gathered and scattered copies: the same values, about half the cost.
    every = points.size == n_points
    columns = slice(None) if every else points
    # The filter G_rho on their 3n coordinates, by the row sweep (faster than LAPACK's per
    # column solve of FrameFilter.__call__ at this many columns); it overwrites its input.
    factor = cholesky_banded(smoothing_filter(prior, rho).bands, check_finite=False)
    moved = target.copy() if every else target[:, :, points]  # a copy either way
    moved = solve_factored_bands(factor, moved.reshape(n_frames, 3 * points.size))
    moved = moved.reshape(n_frames, 3, points.size)
    along = normals[:, None, :] @ moved  # (F, 1, n): the filtered target's depth
    moved -= normals[:, :, None] * along
    # The offset from the tracks: (rho u + a s) / (rho + a) - s = rho / (rho + a) (u - s),
    # and none where measured.
    moved -= back_projected[:, :, columns]
    weights = np.where(anchored[:, columns], rho / (rho + 1.0), 1.0)
    weights[measured[:, columns]] = 0.0
    moved *= weights[:, None, :]
    # The depth step is linear in the fixed part: its pull and its shapes change by the
    # moved points' offset only (column by column).
    rhs = _depth_rhs(normals, target, rho, pull)
    rhs[:, columns] -= depth_pull(moved, normals, prior)
    _depth_solution(normals, rho, prior, rhs, back_projected, out)
    out[:, :, columns] += moved
    return out
