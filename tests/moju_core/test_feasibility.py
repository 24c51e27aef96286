"""Tests of moju_core.feasibility: size checks and the memory estimate shared by the solver,
the upload validation and the worker."""

from __future__ import annotations

import pytest

from moju_core import feasibility
from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.feasibility import (
    check_fit,
    check_memory,
    estimate_memory_bytes,
    memory_problem,
    min_frames_for_bases,
)
from moju_core.params import SolverParams


def test_min_frames_for_bases_follows_the_count_of_constraints():
    assert [min_frames_for_bases(k) for k in (1, 2, 3, 4, 5)] == [3, 8, 15, 25, 38]


@pytest.mark.parametrize(
    ("params", "n_frames", "n_points", "has_rotations", "message"),
    [
        (SolverParams(), 2, 50, False, "needs at least 3 frames"),
        (SolverParams(rotations="rigid"), 2, 50, True, "needs at least 3 frames"),
        (SolverParams(n_bases=3), 10, 50, False, "n_bases=3 needs at least 15 frames"),
        (SolverParams(n_bases=2), 10, 6, False, "at least 7 tracked points, got 6"),
        (SolverParams(subspace_dim=12), 4, 50, False, "3F = 12"),
        (SolverParams(n_groups=50), 4, 40, False, "n_groups=50 needs at least 400 points"),
        (
            SolverParams(method="pta", trajectory_bases=7, rotations="known"),
            10,
            50,
            True,
            "trajectory_bases=7 needs 3k <= 2F",
        ),
    ],
)
def test_check_fit_refuses_parameters_the_sizes_cannot_carry(
    params, n_frames, n_points, has_rotations, message
):
    with pytest.raises(MeasurementError, match=message):
        check_fit(params, n_frames, n_points, has_rotations=has_rotations)


@pytest.mark.parametrize(
    ("params", "n_frames", "n_points", "has_rotations"),
    [
        (SolverParams(), 2, 50, True),  # unset with rotations: known, two frames are enough
        (SolverParams(n_bases=3), 15, 10, False),
        (SolverParams(method="bmm", n_groups=50), 4, 40, False),  # bmm has one group
        (SolverParams(subspace_dim=12), 5, 100, False),
        (SolverParams(rotations="windowed", n_bases=9), 10, 50, False),  # no intersection
    ],
)
def test_check_fit_accepts_parameters_that_fit(params, n_frames, n_points, has_rotations):
    check_fit(params, n_frames, n_points, has_rotations=has_rotations)


def test_check_n_bases_wants_a_positive_integer():
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match="n_bases must be a positive integer"):
            feasibility.check_n_bases(bad, 100, 100)


def test_estimate_memory_bytes_follows_the_documented_formula():
    base = estimate_memory_bytes(0, 0)
    assert base == 128 * 2**20
    assert estimate_memory_bytes(99, 28_880) - base == 256 * 99 * 28_880
    # At least the eight (3F, P) float64 arrays the solver keeps.
    assert estimate_memory_bytes(10, 1000) >= 8 * 3 * 10 * 1000 * 8
    assert estimate_memory_bytes(20, 1000) > estimate_memory_bytes(10, 1000)


def test_estimate_memory_bytes_rejects_negative_sizes():
    with pytest.raises(ValueError, match="n_frames=-1"):
        estimate_memory_bytes(-1, 10)


def test_memory_problem_names_the_sizes_the_need_and_the_limit():
    assert memory_problem(10, 300, 2**30) is None
    assert memory_problem(10, 300, 100 * 2**20, limit_name="LIMIT") == (
        "10 frames x 300 points would need about 129 MiB to solve; the limit is 100 MiB per "
        "job (LIMIT): subsample the points or frames"
    )
    with pytest.raises(MeasurementTooLarge, match="would need about 129 MiB"):
        check_memory(10, 300, 100 * 2**20)
