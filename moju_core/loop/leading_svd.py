"""The singular triplets of a matrix above a threshold, by warm-started subspace iteration.

The S# step of the loop (:func:`moju_core.loop.lrr.singular_value_threshold`) needs only the r
singular values above its threshold and their vectors, and r is small (a handful on the
benchmark sequences) while S# is F x 3P. Through the Gram matrix of the shorter side that
costs ``O(m n min(m, n))`` per iteration plus a ``min(m, n)^3`` eigenproblem; here a block
of b = r + a few row-space vectors is iterated instead, ``O(m n b)`` per sweep, started from
the vectors of the previous call (:class:`WarmStart`), which the loop changes little from one
iteration to the next.

One sweep, with Q (m, b) orthonormal:

* ``Z = X^T Q`` and its thin SVD ``Z = V diag(theta) W^T`` (n x b, cheap): the Rayleigh-Ritz
  values theta and vectors ``U = Q W`` of the block, with ``X^T U = V diag(theta)`` exactly;
* ``G = X V`` and the residual of every triplet, ``e_i = ||X v_i - theta_i u_i||``;
* the next block is ``qr(G diag(1 / theta))`` (columns near ``u_i``, so the QR is well
  conditioned whatever the spread of the values).

The triplets are accepted when every value above the threshold (or kept) has a residual below
``RELATIVE_TOLERANCE * theta_1`` and the block also holds one value below the threshold that is
itself settled (``theta + e`` at most the threshold). While every value of the block is above
the threshold, and every ``SLOW_SWEEPS`` sweeps without acceptance, the block widens by random
columns. Since ``U^T e_i = 0``, the accepted triplets are exact singular triplets of
``X - E`` with ``E = sum_i e_i v_i^T`` (over the returned ones), ``||E||_F = sqrt(sum e_i^2)``;
the threshold is non-expansive, so the result differs from the exact one by at most that
(given that no value of ``X - E`` outside the block exceeds the threshold, which the settled
value below it stands for).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Vectors beyond the surviving ones in the block (the values just below the threshold).
GUARD = 4
#: Residual of an accepted triplet, relative to the largest singular value.
RELATIVE_TOLERANCE = 1e-11
#: Sweeps of one call before it gives up (the caller then takes the exact route).
MAX_SWEEPS = 40
#: Sweeps without settling after which the block widens (the values next to the threshold
#: converge like ``(s_{b+1} / s_r)^2`` per sweep: slowly when they are clustered).
SLOW_SWEEPS = 6
#: A block wider than this fraction of the shorter side is given up too: the exact route is
#: then as cheap.
MAX_BLOCK_FRACTION = 0.25


@dataclass
class WarmStart:
    """What one call of :func:`leading_triplets` leaves for the next one.

    Created empty by the caller and passed to every call on matrices of the same number of
    rows; each call reads and replaces ``vectors``. Row-space vectors are kept, so a
    permutation of the columns (the loop regrouping points) does not spoil them.

    vectors : ndarray of shape (m, b) or None
        The Ritz vectors of the last block, by decreasing value.
    surviving : int
        Number of values the last call returned (on either route of
        :func:`moju_core.loop.lrr.singular_value_threshold`).
    seed : int
        Seed of the random columns that start or widen a block.
    sweeps : int
        Sweeps run over all calls (each two products with X).
    calls, fallbacks : int
        Calls, and calls that gave up (:data:`MAX_SWEEPS`, :data:`MAX_BLOCK_FRACTION`).
    too_many_above : float
        A threshold with more values above it than the widest block holds (-1: none yet);
        calls at or below it give up at once.
    """

    vectors: np.ndarray | None = None
    surviving: int = 0
    seed: int = 0
    sweeps: int = 0
    calls: int = 0
    fallbacks: int = 0
    too_many_above: float = -1.0
    rng: np.random.Generator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def width(self, keep: int) -> int:
        """Block width of the next call: the last surviving values, one below and a guard,
        or the last block if it was wider (it had to be, to settle), up to twice that."""
        needed = max(keep, self.surviving) + 1 + GUARD
        last = 0 if self.vectors is None else self.vectors.shape[1]
        return last if needed <= last <= 2 * needed else needed

    def start(self, n_rows: int, width: int) -> np.ndarray:
        """An orthonormal (n_rows, width) block: the kept vectors, then random columns."""
        kept = self.vectors if self.vectors is not None and len(self.vectors) == n_rows else None
        kept = np.empty((n_rows, 0)) if kept is None else kept[:, :width]
        fresh = self.rng.standard_normal((n_rows, width - kept.shape[1]))
        return np.linalg.qr(np.hstack([kept, fresh]))[0]


def leading_triplets(
    x: np.ndarray, tau: float, keep: int, warm: WarmStart
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The singular triplets of x above tau, and the ``keep`` leading ones in any case.

    Parameters
    ----------
    x : ndarray of shape (m, n)
    tau : float
        Threshold, >= 0.
    keep : int
        Leading values returned even when at most tau.
    warm : WarmStart
        The previous call's vectors; updated.

    Returns
    -------
    (u, s, rows) or None
        ``u`` (m, r) orthonormal left vectors, ``s`` (r,) the values in decreasing order,
        ``rows`` (r, n) ``= u^T x = diag(s) V^T``. None when the block would grow wider than
        ``MAX_BLOCK_FRACTION * min(m, n)`` or did not settle in ``MAX_SWEEPS`` sweeps.
    """
    m, n = x.shape
    warm.calls += 1
    if tau <= warm.too_many_above:
        warm.fallbacks += 1
        return None
    limit = max(1, int(MAX_BLOCK_FRACTION * min(m, n)))
    width = min(warm.width(keep), limit)
    q = warm.start(m, width)
    count = 0
    for sweep in range(1, MAX_SWEEPS + 1):
        warm.sweeps += 1
        z = x.T @ q
        v, theta, wt = np.linalg.svd(z, full_matrices=False)
        u = q @ wt.T
        g = x @ v
        residual = np.linalg.norm(g - u * theta, axis=0)
        count = _surviving(theta, tau, keep)
        tolerance = RELATIVE_TOLERANCE * theta[0]
        full = count == width  # no value below the threshold in the block: it must widen
        if not full:
            settled = residual[:count].max(initial=0.0) <= tolerance
            if settled and theta[count] + residual[count] <= tau + tolerance:
                warm.vectors, warm.surviving = u, count
                return u[:, :count], theta[:count], (v[:, :count] * theta[:count]).T
        # The next block: one power step (columns near u_i, well conditioned), widened by
        # random columns when it is full or converges slowly (a cluster of values at tau).
        power = g / np.maximum(theta, tolerance)
        grow = full or sweep % SLOW_SWEEPS == 0
        if grow and width >= limit:
            if full:
                # More values above tau than the widest block: also above any smaller tau.
                warm.too_many_above = tau
            break
        if grow:
            width = min(width + GUARD + width // 2, limit)
        extra = warm.rng.standard_normal((m, width - power.shape[1]))
        q = np.linalg.qr(np.hstack([power, extra]))[0]
    warm.fallbacks += 1
    warm.vectors, warm.surviving = u, min(count, width - 1)
    return None


def _surviving(theta: np.ndarray, tau: float, keep: int) -> int:
    """How many of the decreasing values theta survive: those above tau, at least ``keep``
    (positive ones only)."""
    above = int(np.count_nonzero(theta > tau))
    return max(above, min(keep, int(np.count_nonzero(theta > 0))))
