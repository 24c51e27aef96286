import numpy as np
import pytest

from moju_core.completion import window_subspace
from moju_core.datasets import make_sequence, occlusion_mask


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Principal angles (radians) between the column spaces of a and b (resolved to ~1e-8)."""
    cosines = np.linalg.svd(np.linalg.qr(a)[0].T @ np.linalg.qr(b)[0], compute_uv=False)
    return np.arccos(np.clip(cosines, -1.0, 1.0))


@pytest.fixture(scope="module")
def visibility():
    # A band sweeping across, lost tracks and dropout: no point is seen in every frame.
    face = make_sequence("face3", n_points=400, n_frames=60, seed=0)
    seen = occlusion_mask(face, band=0.2, lost=0.1, dropout=0.02, seed=0)
    assert not seen.all(axis=0).any()
    return seen


def _low_rank(rng, rank=5):
    motion = np.hstack([rng.standard_normal((120, rank)), rng.standard_normal((120, 1)) * 5.0])
    coefficients = np.vstack([rng.standard_normal((rank, 400)), np.ones((1, 400))])
    return motion, motion @ coefficients


def test_the_windows_give_the_column_space_of_an_exactly_low_rank_w(visibility):
    rng = np.random.default_rng(0)
    motion, W = _low_rank(rng)
    garbage = np.where(np.repeat(visibility, 2, axis=0), W, 1e3)  # any values where hidden
    candidates = list(window_subspace.column_spaces(garbage, visibility))
    assert len(candidates) >= 2
    for basis, rank in candidates:
        assert rank == 6  # the deformation's 5 directions and the translation
        assert basis.shape == (120, 6 + window_subspace.EXTRA_DIRECTIONS)
        assert np.allclose(basis.T @ basis, np.eye(basis.shape[1]), atol=1e-10)
        # The most consistent directions first: here W's column space exactly.
        assert _angles(basis[:, :6], motion).max() < 1e-6


def test_the_banded_eigenproblem_equals_the_dense_one(visibility):
    rng = np.random.default_rng(1)
    _, W = _low_rank(rng, rank=3)
    lengths = window_subspace.WINDOW_LENGTHS
    length = next(n for n in lengths if window_subspace._windows(W, visibility, n) is not None)
    bases = window_subspace._windows(W, visibility, length)
    dense = np.zeros((120, 120))
    for start, basis in zip(window_subspace._window_starts(60, length), bases, strict=True):
        rows = slice(2 * start, 2 * (start + length))
        dense[rows, rows] += np.eye(2 * length) - basis @ basis.T
    values, vectors = np.linalg.eigh(dense)
    stitched = window_subspace._stitch(bases, 120, length)
    assert stitched.shape[1] == 4 + window_subspace.EXTRA_DIRECTIONS
    # The exact directions (eigenvalue 0) as a subspace, the next ones one by one.
    assert _angles(stitched[:, :4], vectors[:, :4]).max() < 1e-6
    extra = np.abs(np.sum(stitched[:, 4:] * vectors[:, 4:7], axis=0))
    assert np.all(values[4:8] > 1e-3) and np.allclose(extra, 1.0, atol=1e-8)


@pytest.mark.parametrize("noise", [1e-3, None])
def test_tracks_that_are_not_exactly_low_rank_give_no_candidate(visibility, noise):
    rng = np.random.default_rng(2)
    _, W = _low_rank(rng)
    if noise is None:
        W = rng.standard_normal(W.shape)  # full rank
    else:
        W = W + noise * rng.standard_normal(W.shape)
    assert list(window_subspace.column_spaces(W, visibility)) == []


def test_too_few_frames_for_any_window_give_no_candidate():
    rng = np.random.default_rng(3)
    W = rng.standard_normal((20, 3)) @ rng.standard_normal((3, 100))
    assert list(window_subspace.column_spaces(W, np.ones((10, 100), bool))) == []
