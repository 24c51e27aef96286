"""Orthographic camera algebra and the closed-form S-update."""

import subprocess
import sys

import numpy as np
from numpy.testing import assert_allclose

from moju_core.cameras import projection
from moju_core.cameras.refinement import project_to_stiefel


def _rotations(rng, n_frames):
    return project_to_stiefel(rng.standard_normal((n_frames, 2, 3)))


def test_data_step_solves_the_block_diagonal_system():
    rng = np.random.default_rng(0)
    rotations = _rotations(rng, 4)
    tracks = rng.standard_normal((4, 2, 7))
    target = rng.standard_normal((4, 3, 7))
    rho = 0.37
    out = projection.data_step(
        projection.back_project(rotations, tracks),
        projection.viewing_directions(rotations),
        target,
        rho,
    )
    for f in range(4):
        lhs = rotations[f].T @ rotations[f] + rho * np.eye(3)
        rhs = rotations[f].T @ tracks[f] + rho * target[f]
        assert_allclose(out[f], np.linalg.solve(lhs, rhs), atol=1e-12)


def test_back_projection_reprojects_exactly_and_has_no_depth():
    rng = np.random.default_rng(1)
    rotations = _rotations(rng, 5)
    tracks = rng.standard_normal((5, 2, 9))
    shapes = projection.back_project(rotations, tracks)
    assert_allclose(projection.project(rotations, shapes), tracks, atol=1e-12)
    depth = np.einsum("fi,fip->fp", projection.viewing_directions(rotations), shapes)
    assert_allclose(depth, 0.0, atol=1e-12)


def test_projection_loads_without_the_estimators():
    # datasets and metrics import cameras.projection and cameras.refinement; the package
    # loads the estimators (and SciPy's optimisers) only for estimate_cameras.
    code = (
        "import sys, moju_core.datasets, moju_core.metrics\n"
        "assert 'moju_core.cameras.estimate' not in sys.modules\n"
        "assert 'scipy.optimize' not in sys.modules\n"
        "from moju_core.cameras import estimate_cameras\n"
        "assert 'moju_core.cameras.estimate' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
