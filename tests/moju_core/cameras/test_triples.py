"""Cost of the joint fit of the corrective triples (:func:`moju_core.cameras.triples.fit_triples`).

The multi-start search runs one L-BFGS fit per starting point. A continued fit that is already
exact (its misfit at most ``_LINEAGE_EXACT`` of the next eigenvalue) is not searched: other
starts could only reach another exact fit. These tests count the search's runs, with the
skip and with it switched off (``_LINEAGE_EXACT = 0``), and check that the rotations are the
same either way.
"""

from __future__ import annotations

import numpy as np
import pytest
from low_rank_sequences import make_sequence
from numpy.testing import assert_allclose

from moju_core import datasets
from moju_core.cameras import estimate_cameras, triples
from moju_core.preprocessing import normalise


def _rotations_and_search_runs(monkeypatch, W: np.ndarray) -> tuple[np.ndarray, int]:
    """Intersection rotations of W and how many L-BFGS runs the multi-start search made."""
    runs = []
    refine = triples._refine_rotations

    def counting_refine(fit, start, *, tol, max_iter):
        if tol == triples._SEARCH_TOL:
            runs.append(fit.n_triples)
        return refine(fit, start, tol=tol, max_iter=max_iter)

    with monkeypatch.context() as patch:
        patch.setattr(triples, "_refine_rotations", counting_refine)
        rotations = estimate_cameras(W, "intersection").rotations
    return rotations, len(runs)


def _always_searched(monkeypatch, W: np.ndarray) -> tuple[np.ndarray, int]:
    with monkeypatch.context() as patch:
        patch.setattr(triples, "_LINEAGE_EXACT", 0.0)
        return _rotations_and_search_runs(monkeypatch, W)


def _short_face(noise: float) -> np.ndarray:
    W, _ = normalise(datasets.make_sequence("face3", n_frames=15, n_points=400, noise=noise).W)
    return W


def test_an_exact_low_rank_fit_is_not_searched(monkeypatch):
    # Three exact triples and nothing inexact: the continued fit is final. Searched anyway
    # it costs one run per start and ends at the same rotations.
    W, _, _ = make_sequence(n_bases=3, seed=0)
    rotations, runs = _rotations_and_search_runs(monkeypatch, W)
    searched_rotations, searched_runs = _always_searched(monkeypatch, W)
    assert runs == 0
    assert searched_runs > 0
    assert_allclose(rotations, searched_rotations, atol=1e-12)


def test_a_noise_free_short_face_skips_the_search_of_its_exact_fit(monkeypatch):
    # Fifteen frames of a face: its inexact third triple is searched either way; the fit of
    # the two exact ones is searched only with the skip switched off, to the same rotations.
    W = _short_face(0.0)
    rotations, runs = _rotations_and_search_runs(monkeypatch, W)
    searched_rotations, searched_runs = _always_searched(monkeypatch, W)
    assert 0 < runs < searched_runs
    assert_allclose(rotations, searched_rotations, atol=1e-12)


@pytest.mark.parametrize(
    "build",
    [lambda: make_sequence(n_bases=3, seed=0, noise=0.01)[0], lambda: _short_face(0.01)],
    ids=["low-rank", "face3-15"],
)
def test_fits_at_the_noise_level_are_searched(monkeypatch, build):
    # 1 % noise: no fit is exact to rounding, so the skip saves nothing.
    W = build()
    rotations, runs = _rotations_and_search_runs(monkeypatch, W)
    searched_rotations, searched_runs = _always_searched(monkeypatch, W)
    assert runs == searched_runs > 0
    assert_allclose(rotations, searched_rotations, atol=1e-12)
