"""Joint fit of the rotations to several corrective triples of the motion factor.

Dai et al.'s intersection method (:mod:`moju_core.cameras.intersection`) finds one corrective
column triple ``G_k`` of the motion factor, which fixes the rotations only to second order.
Here the rotations are refined so that several triples are scaled copies of the same
rotations, ``Pi_f G_k = c_fk R_f`` (:class:`MotionFit`), by L-BFGS on SO(3)
(:func:`_refine_rotations`). How many triples is decided by the data, not by K
(:func:`fit_triples`): triples are added one at a time as long as the new one fits
*exactly*, with no more misfit than the noise of W explains. Exactly low-rank sequences (K
full xyz bases) have K such triples; realistic deformations have fewer (the synthetic faces
have 2, whatever K), and fitting the inexact ones as well pulled the rotations 4-23 degrees
away from the truth. The fit moves away from its start only for a lower misfit, and a
multi-start search guards against wrong minima under noise.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from scipy.optimize import minimize

from moju_core.cameras.refinement import GENERATORS, exp_so3, project_to_stiefel
from moju_core.spectrum import noise_variance_beyond

__all__ = ["MotionFit", "fit_frames", "fit_triples", "rotations_from_triples"]

# Longer sequences fit the corrective triples on this many frames spread evenly over the
# sequence (the triples do not depend on the frame), and every frame's rotation then follows
# from the fitted triples in closed form (rotations_from_triples): the L-BFGS fit costs
# O(F) per iteration and needs more iterations for more frames.
_MAX_FIT_FRAMES = 100
# L-BFGS fit of the rotations to the motion factor (_refine_rotations): relative decrease of
# the misfit at which to stop, and iteration budget (tens to hundreds are used).
_REFINE_TOL = 1e-10
_REFINE_MAX_ITER = 1000
# The looser tolerance and budget of each run of the multi-start search (fit_triples).
_SEARCH_TOL = 1e-6
_SEARCH_MAX_ITER = 300
# A fitted triple is "exact" when its misfit (with the singular values as weights, so that
# white noise adds the same amount to every triple) is at most this many times the misfit
# that the noise of W alone gives a triple, 2 F sigma^2 (see fit_triples): a margin over
# the scatter of the noise's own misfit (about 0.5-1.1 of it after the fit), below the
# misfit of triples that a deformation holds only approximately, which pull the rotations
# away when they are fitted.
_EXACT_NOISE_RATIO = 1.3
# Without noise the noise floor is a rounding error and L-BFGS does not reach it: a triple is
# also exact when its eigenvalue of H is below this fraction of the largest one: between the
# rounding level of exact triples (1e-16 and below) and the misfit of the nearly exact ones
# of short sequences (1e-7 and above), where the noise test decides.
_EXACT_RELATIVE = 1e-8
# Cost: a continued fit whose misfit is this far below the next eigenvalue of H holds its k
# triples exactly, and other starts can reach at most another exact fit, so the multi-start
# search (one L-BFGS run per start) is skipped for it.
_LINEAGE_EXACT = 1e-4


class MotionFit:
    """Misfit of rotations to a motion factor under the corrective-triple model.

    For a motion factor Pi (2F x n) the model says ``Pi_f G_k = c_fk R_f`` for k column
    triples ``G_k`` (n x 3) and coefficients ``c_fk``. For given rotations the best triples
    and coefficients are found in closed form: with ``g_k = vec(G_k)`` orthonormal (which
    excludes ``G = 0``) and ``c_fk = <Pi_f G_k, R_f> / 2``,

    ``misfit(R) = min sum_fk ||Pi_f G_k - c_fk R_f||_F^2 = sum of the k smallest
    eigenvalues of H(R) = sum_f L_f^T (I - r_f r_f^T) L_f``,

    where ``L_f g = vec(Pi_f G)`` and ``r_f = vec(R_f) / sqrt(2)``. This couples every
    fitted triple to the same rotation, which Dai et al.'s single-triple equations do not:
    those leave the rotations free to first order along ``G_k + sum_j G_j omega_j``
    (omega_j skew), so that even 0.01 % noise gave 5-10 degree errors for K = 3, 4 in our
    measurements. The eigenvalues of H beyond the k-th tell how well further triples would
    fit (see :func:`fit_triples`).
    """

    def __init__(self, Pi: np.ndarray, n_triples: int) -> None:
        n_frames, n = Pi.shape[0] // 2, Pi.shape[1]
        self.n_triples = n_triples
        self.blocks = Pi.reshape(n_frames, 2, n)
        # sum_f L_f^T L_f = I_3 (x) Pi^T Pi in the (m, b) ordering of vec(G).
        self.lifted_gram = np.kron(Pi.T @ Pi, np.eye(3))

    def evaluate(
        self, R: np.ndarray, *, spectrum: bool = True
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """Misfit, its Euclidean gradient with respect to R, and the spectrum of H.

        Parameters
        ----------
        R : ndarray of shape (F, 2, 3)
        spectrum : bool, default True
            Whether all eigenvalues of H are wanted. False computes only the k smallest
            eigenpairs (all the misfit and gradient need; a partial eigensolver, about half
            the cost of the full one at 3n = 90) and returns just those k eigenvalues.

        Returns
        -------
        misfit : float
        gradient : ndarray of shape (F, 2, 3)
            ``-2 sum_k c_fk Pi_f G_k`` (the eigenvectors are stationary, so only the
            explicit dependence on R counts).
        eigenvalues : ndarray of shape (3n,)
            Eigenvalues of H, increasing.
        """
        n_frames, n = self.blocks.shape[0], self.blocks.shape[2]
        r = R / math.sqrt(2.0)
        # L_f^T r_f, i.e. Pi_f^T r_f flattened in the (m, b) order of vec(G).
        projected = np.einsum("fim,fib->fmb", self.blocks, r).reshape(n_frames, 3 * n)
        H = self.lifted_gram - projected.T @ projected
        if spectrum:
            eigenvalues, eigenvectors = np.linalg.eigh(H)
        else:
            eigenvalues, eigenvectors = scipy.linalg.eigh(
                H, subset_by_index=[0, self.n_triples - 1], driver="evr", check_finite=False
            )
        triples = eigenvectors[:, : self.n_triples].reshape(n, 3, -1)
        # Pi_f G_k for every frame and triple, (F, k, 2, 3).
        blocks = np.einsum("fim,mbk->fkib", self.blocks, triples, optimize=True)
        coefficients = np.einsum("fkib,fib->fk", blocks, r) / math.sqrt(2.0)
        gradient = -2.0 * np.einsum("fk,fkib->fib", coefficients, blocks)
        return float(eigenvalues[: self.n_triples].sum()), gradient, eigenvalues

    def triples(self, R: np.ndarray) -> np.ndarray:
        """The best corrective triples for rotations R, shape (n, 3, k) (``G_k = [..., k]``)."""
        n_frames, n = self.blocks.shape[0], self.blocks.shape[2]
        r = R / math.sqrt(2.0)
        projected = np.einsum("fim,fib->fmb", self.blocks, r).reshape(n_frames, 3 * n)
        _, eigenvectors = np.linalg.eigh(self.lifted_gram - projected.T @ projected)
        return eigenvectors[:, : self.n_triples].reshape(n, 3, -1)


def _refine_rotations(
    fit: MotionFit, R: np.ndarray, *, tol: float, max_iter: int
) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimise the misfit of :class:`MotionFit` over the rotations, starting from R.

    The rotations are parametrised around the start as ``R_f exp(skew(w_f))`` (full 3 x 3
    rotations completed by the cross product, of which the first two rows are used), and
    the 3F rotation vectors are optimised by L-BFGS. Alternating between the triples and
    the rotations also decreases the misfit but, being a block coordinate descent on a
    bilinear problem, needed thousands of sweeps; L-BFGS needs tens to a few hundred
    iterations of O(F K^3) each.

    Parameters
    ----------
    fit : MotionFit
    R : ndarray of shape (F, 2, 3)
        Starting rotations.
    tol : float
        Relative decrease of the misfit (from its starting value) at which to stop.
    max_iter : int
        Iteration budget.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    misfit : float
    eigenvalues : ndarray of shape (3n,)
        Spectrum of H at the result; a clear gap after the K-th eigenvalue means the model
        fits.
    """
    start = np.concatenate([R, np.cross(R[:, 0], R[:, 1])[:, None]], axis=1)

    def rotations_at(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        exponential, right_jacobian = exp_so3(x.reshape(-1, 3))
        return (start @ exponential)[:, :2], right_jacobian

    initial_misfit, _, initial_spectrum = fit.evaluate(R)
    if initial_misfit <= 0.0:
        return R, initial_misfit, initial_spectrum

    def misfit_and_gradient(x: np.ndarray) -> tuple[float, np.ndarray]:
        rotations, right_jacobian = rotations_at(x)
        misfit, gradient, _ = fit.evaluate(rotations, spectrum=False)
        # d R / d w_j = R skew(J_r e_j): project the Euclidean gradient on R skew(e_i), then
        # apply J_r^T.
        body = np.einsum(
            "fia,fjia->fj", gradient, np.einsum("fib,jba->fjia", rotations, GENERATORS)
        )
        gradient_w = np.einsum("fij,fi->fj", right_jacobian, body).reshape(-1)
        # L-BFGS-B stops on (f_k - f_k+1) / max(|f_k|, |f_k+1|, 1) <= ftol, an absolute test
        # for f < 1; relative to the starting misfit the test stays relative down to the
        # noise floor (without noise it stopped at 0.2 degrees instead of 1e-4).
        return misfit / initial_misfit, gradient_w / initial_misfit

    result = minimize(
        misfit_and_gradient,
        np.zeros(3 * R.shape[0]),
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": max_iter, "ftol": tol, "gtol": 0.0, "maxcor": 20},
    )
    rotations = project_to_stiefel(rotations_at(result.x)[0])
    misfit, _, eigenvalues = fit.evaluate(rotations)
    return rotations, misfit, eigenvalues


def _noise_floor(shape: tuple[int, int], U: np.ndarray, s: np.ndarray) -> float:
    """Misfit that the noise of W alone gives one triple of the test factor ``U S / s_1``.

    Parameters
    ----------
    shape : (int, int)
        Shape of W.
    U : ndarray of shape (2F, n)
        Leading left singular vectors of W.
    s : ndarray
        All singular values of W, decreasing.

    Returns
    -------
    float
        ``2 F sigma^2 / s_1^2`` (dimensionless: a misfit of the test factor), sigma^2 the
        noise variance of W's entries beyond its n leading singular values.
    """
    n_frames, n = U.shape[0] // 2, U.shape[1]
    sigma2 = noise_variance_beyond(s, shape, n)
    # Misfit of one triple from the noise alone, in the units of the test factor: the 2 x 3
    # block of a unit triple carries noise of total variance 2 sigma^2 / s_1^2 in every frame
    # (fitting c_fk and the rotations absorbs a little of it: 0.6-1.2 times this was measured
    # at the true rotations of exactly low-rank sequences).
    return 2.0 * n_frames * sigma2 / s[0] ** 2


def _is_exact(
    test_motion: np.ndarray,
    noise_floor: float,
    rotations: np.ndarray,
    eigenvalues: np.ndarray,
    k: int,
) -> tuple[bool, float]:
    """Whether the k-th triple of a fit is exact (see :func:`fit_triples`).

    Parameters
    ----------
    test_motion : ndarray of shape (2F, n)
        The test factor ``U S / s_1``.
    noise_floor : float
        Its misfit from the noise alone (:func:`_noise_floor`).
    rotations : ndarray of shape (F, 2, 3)
        Fitted rotations.
    eigenvalues : ndarray of shape (3n,)
        Spectrum of H of the fit (of ``U S^(1/2)``), increasing.
    k : int
        Number of triples fitted.

    Returns
    -------
    exact : bool
    excess : float
        Misfit of the k-th triple under the test factor over the noise floor (0 when the
        triple is exact at rounding level).
    """
    if eigenvalues[k - 1] <= _EXACT_RELATIVE * eigenvalues[-1]:
        return True, 0.0
    excess = MotionFit(test_motion, k).evaluate(rotations)[2][k - 1] / max(noise_floor, 1e-300)
    return excess <= _EXACT_NOISE_RATIO, excess


def _search_starts(
    fit: MotionFit,
    starts: list[np.ndarray],
    rotations: np.ndarray,
    misfit: float,
    eigenvalues: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Replace a fit by the best fit from all starts if its misfit is lower.

    Parameters
    ----------
    fit : MotionFit
    starts : list of ndarray of shape (F, 2, 3)
    rotations : ndarray of shape (F, 2, 3)
        The fit to beat, with its ``misfit`` and its ``eigenvalues`` (shape (3n,)).

    Returns
    -------
    rotations, misfit, eigenvalues
        The refined best start's fit, or the given one.
    """
    candidates = [
        _refine_rotations(fit, start, tol=_SEARCH_TOL, max_iter=_SEARCH_MAX_ITER)
        for start in starts
    ]
    candidate = min(candidates, key=lambda c: c[1])
    # Strictly lower: an equal misfit keeps the continued fit.
    if candidate[1] < misfit:
        return _refine_rotations(fit, candidate[0], tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER)
    return rotations, misfit, eigenvalues


def _add_exact_triples(
    motion: np.ndarray,
    test_motion: np.ndarray,
    noise_floor: float,
    max_triples: int,
    starts: list[np.ndarray],
) -> tuple[tuple[MotionFit, int, bool, np.ndarray, float, np.ndarray], int, float]:
    """Fit k = 1, 2, ..., ``max_triples`` triples until the first inexact one.

    Each k continues from the rotations of k - 1 (k = 1 from ``starts[0]``) and is searched
    from every start when it is not exact and not exact beyond doubt (``_LINEAGE_EXACT``).

    Parameters
    ----------
    motion : ndarray of shape (2F, n)
        The factor fitted, ``U S^(1/2) / s_1^(1/2)``.
    test_motion : ndarray of shape (2F, n)
        The factor of the test, ``U S / s_1``.
    noise_floor : float
        Misfit of one triple of ``test_motion`` from the noise alone (:func:`_noise_floor`).
    max_triples : int
    starts : list of ndarray of shape (F, 2, 3)

    Returns
    -------
    chosen : tuple
        ``(fit, k, searched, rotations, misfit, eigenvalues)`` of the last exact k, or of
        k = 1 when no triple is exact; ``searched`` tells whether the starts were searched.
    n_exact : int
    excess : float
        Misfit of the first inexact triple over the noise floor (``inf`` when all are exact).
    """
    chosen = None
    n_exact, excess, previous = 0, math.inf, starts[0]
    for k in range(1, max_triples + 1):
        fit = MotionFit(motion, k)
        rotations, misfit, eigenvalues = _refine_rotations(
            fit, previous, tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER
        )
        exact, excess = _is_exact(test_motion, noise_floor, rotations, eigenvalues, k)
        searched = not exact and misfit > _LINEAGE_EXACT * eigenvalues[k]
        if searched:
            rotations, misfit, eigenvalues = _search_starts(
                fit, starts, rotations, misfit, eigenvalues
            )
            exact, excess = _is_exact(test_motion, noise_floor, rotations, eigenvalues, k)
        if chosen is None or exact:
            # Without any exact triple, the best single-triple fit is kept.
            chosen = (fit, k, searched, rotations, misfit, eigenvalues)
        if not exact:
            break
        n_exact, previous = k, rotations
    return chosen, n_exact, excess


def _refine_under_test_factor(
    fit: MotionFit, k: int, rotations: np.ndarray, test_motion: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, MotionFit, np.ndarray]:
    """The final fit of k > 1 triples refined under ``U S`` (k = 1 is kept as it is).

    Parameters
    ----------
    fit : MotionFit
        The fit of ``U S^(1/2)`` with k triples.
    k : int
    rotations : ndarray of shape (F, 2, 3)
    test_motion : ndarray of shape (2F, n)
        The factor ``U S / s_1``.
    s : ndarray
        All singular values of W, decreasing.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    fit : MotionFit
        The fit refined (of ``U S / s_1`` when k > 1).
    weights : ndarray of shape (n,)
        The column weights of its motion factor, ``U * weights``.
    """
    n = test_motion.shape[1]
    # Dai et al.'s split weighs the weak directions up against the noise (by (s_1 / s_j)^1/2);
    # the same fit with U S, under which noise adds the same to every triple, was the more
    # accurate one in our tests (1-3.5 against 4-7 degrees at 3-5.5 % noise). Without noise
    # an exact fit is exact under any weighting and stays where it is. A single triple is
    # not refined so: it fixes the rotations only weakly along the other (nearly exact)
    # triples, and U S, which makes the weak directions count less, let them drift (from 0.7
    # to 17 degrees on face4 with 1 % noise).
    weights = np.sqrt(s[:n] / s[0])
    if k > 1:
        fit, weights = MotionFit(test_motion, k), s[:n] / s[0]
        rotations, _, _ = _refine_rotations(
            fit, rotations, tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER
        )
    return rotations, fit, weights


def fit_triples(
    shape: tuple[int, int],
    U: np.ndarray,
    s: np.ndarray,
    max_triples: int,
    starts: list[np.ndarray],
) -> tuple[np.ndarray, int, float, MotionFit, np.ndarray]:
    """Joint fit of as many corrective triples as the data hold exactly.

    For k = 1, 2, ..., ``max_triples`` the rotations are fitted to k triples of the motion
    factor ``U S^(1/2)`` (:class:`MotionFit`), continuing from the fit with k - 1 triples
    (the first from Dai et al.'s estimate, ``starts[0]``). The k-th triple is then tested:
    exact when its misfit under ``U S`` is at most ``_EXACT_NOISE_RATIO`` times what the noise
    of W explains, or at rounding level. If it is not, every start is searched too (unless
    the continued fit is exact beyond doubt, ``_LINEAGE_EXACT``), a lower misfit replaces
    the continued fit, and the test is repeated. The first inexact triple ends the loop:
    fitting a triple that the data hold only approximately pulls the rotations towards it
    (4-23 degrees on the project's faces). The last exact fit is searched once more if it
    was not yet, and refined under ``U S``.

    Parameters
    ----------
    shape : (int, int)
        Shape of W.
    U : ndarray of shape (2F, n)
        Leading left singular vectors of W.
    s : ndarray
        All singular values of W, decreasing.
    max_triples : int
    starts : list of ndarray of shape (F, 2, 3)

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    n_exact : int
        Number of exact triples (0 when not even one triple fits; the rotations are then
        the best fit of one triple).
    excess : float
        Misfit of the first inexact triple over the noise level (huge without noise).
    fit : MotionFit
        The last fit (of the rows of U given).
    weights : ndarray of shape (n,)
        The column weights of its motion factor, ``U * weights``.
    """
    n = U.shape[1]
    noise_floor = _noise_floor(shape, U, s)
    # Dai et al.'s split U S^(1/2) for the fit: its basins of attraction were the widest in
    # our tests (U S and, above all, U alone led the search into wrong minima far more often).
    motion = U * np.sqrt(s[:n] / s[0])
    # White noise adds the same misfit to every triple of U S: the factor for the test.
    test_motion = U * (s[:n] / s[0])
    chosen, n_exact, excess = _add_exact_triples(
        motion, test_motion, noise_floor, max_triples, starts
    )
    fit, k, searched, rotations, misfit, eigenvalues = chosen
    if not searched and misfit > _LINEAGE_EXACT * eigenvalues[k]:
        rotations, _, _ = _search_starts(fit, starts, rotations, misfit, eigenvalues)
    rotations, fit, weights = _refine_under_test_factor(fit, k, rotations, test_motion, s)
    return rotations, n_exact, excess, fit, weights


def fit_frames(n_frames: int) -> np.ndarray:
    """Frames the joint fit of the triples uses: all, or _MAX_FIT_FRAMES spread evenly."""
    if n_frames <= _MAX_FIT_FRAMES:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, _MAX_FIT_FRAMES).round().astype(np.int64))


def rotations_from_triples(triples: np.ndarray, motion: np.ndarray, sweeps: int = 20) -> np.ndarray:
    """Every frame's rotation from corrective triples fitted on a subset of the frames.

    The triples ``G_k`` do not depend on the frame: frame f's rotation maximises
    ``sum_k <Pi_f G_k, R_f>^2`` (the misfit of :class:`MotionFit` for fixed triples), found
    by the fixed-point iteration ``R_f <- polar(sum_k <Pi_f G_k, R_f> Pi_f G_k)`` from the
    polar factor of the frame's strongest block; each sweep increases the objective. O(F k n)
    in all; the sign of each frame is left to
    :func:`moju_core.cameras.intersection._synchronise_signs`.

    Parameters
    ----------
    triples : ndarray of shape (n, 3, k)
        The fitted triples (:meth:`MotionFit.triples`).
    motion : ndarray of shape (2F, n)
        The motion factor of all frames, weighted as the fit's.
    sweeps : int
        Fixed-point iterations.

    Returns
    -------
    ndarray of shape (F, 2, 3)
    """
    n_frames = motion.shape[0] // 2
    blocks = np.einsum(
        "fim,mbk->fkib", motion.reshape(n_frames, 2, -1), triples, optimize=True
    )  # Pi_f G_k, (F, k, 2, 3)
    strongest = np.argmax(np.einsum("fkib,fkib->fk", blocks, blocks), axis=1)
    rotations = project_to_stiefel(blocks[np.arange(n_frames), strongest])
    for _ in range(sweeps):
        coefficients = np.einsum("fkib,fib->fk", blocks, rotations)
        rotations = project_to_stiefel(np.einsum("fk,fkib->fib", coefficients, blocks))
    return rotations
