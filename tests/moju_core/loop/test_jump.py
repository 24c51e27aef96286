"""The jump to the low-dimensional Grassmann manifold (Eqs. 2-7)."""

import numpy as np
from numpy.testing import assert_allclose

from moju_core.loop import jump
from moju_core.loop.clustering import similarity_graph


def _problem(seed=0, n=30, p=3, k=12, d=8):
    rng = np.random.default_rng(seed)
    # Groups in three families of nearby subspaces, as on a surface with three regions.
    centres = [np.linalg.qr(rng.standard_normal((n, p)))[0] for _ in range(3)]
    bases = []
    for i in range(k):
        q, _ = np.linalg.qr(centres[i % 3] + 0.2 * rng.standard_normal((n, p)))
        bases.append(q)
    bases = np.stack(bases)
    edges = np.array([(i, j) for i in range(k) for j in range(i + 1, k)])
    weights = similarity_graph(bases, edges)
    delta = jump.initial_map(n, d, rng)
    return bases, weights, delta, rng


def _trace_constraint(delta, omegas, weights):
    degrees = weights.sum(axis=1)
    d_matrix = np.einsum("k,knp,kmp->nm", degrees, omegas, omegas)
    return np.trace(delta.T @ d_matrix @ delta)


def test_low_dimensional_points_are_orthonormal_and_consistent():
    bases, _, delta, _ = _problem()
    thetas, omegas = jump.low_dimensional_points(delta, bases)
    eye = np.eye(bases.shape[2])
    assert_allclose(
        np.einsum("kdp,kdq->kpq", thetas, thetas), np.broadcast_to(eye, (12, 3, 3)), atol=1e-10
    )
    # Eq. 3: Theta_i = Delta^T Omega_i, and Omega_i spans the same space as Phi_i.
    assert_allclose(np.einsum("nd,knp->kdp", delta, omegas), thetas, atol=1e-10)
    for phi, omega in zip(bases, omegas, strict=True):
        assert_allclose(phi @ (phi.T @ omega), omega, atol=1e-8)


def test_update_map_satisfies_the_trace_constraint():
    bases, weights, delta, _ = _problem(1)
    _, omegas = jump.low_dimensional_points(delta, bases)
    new = jump.update_map(delta, omegas, weights)
    assert abs(_trace_constraint(new, omegas, weights) - 1.0) < 1e-6


def test_update_map_beats_random_feasible_maps():
    bases, weights, delta, rng = _problem(2)
    _, omegas = jump.low_dimensional_points(delta, bases)
    new = jump.update_map(delta, omegas, weights)
    ours = jump.jump_objective(new, omegas, weights)
    for _ in range(50):
        candidate = rng.standard_normal(delta.shape)
        candidate /= np.sqrt(_trace_constraint(candidate, omegas, weights))  # feasible
        assert jump.jump_objective(candidate, omegas, weights) > ours


def test_jump_objective_matches_its_definition():
    bases, weights, delta, _ = _problem(3, k=5)
    _, omegas = jump.low_dimensional_points(delta, bases)
    expected = 0.0
    for i in range(5):
        for j in range(5):
            lam = omegas[i] @ omegas[i].T - omegas[j] @ omegas[j].T
            expected += weights[i, j] * 0.5 * np.linalg.norm(delta.T @ lam @ delta) ** 2
    assert_allclose(jump.jump_objective(delta, omegas, weights), expected, rtol=1e-9)


def test_jump_keeps_neighbouring_groups_closer_than_others():
    bases, weights, delta, _ = _problem(4)
    _, thetas = jump.jump(delta, bases, weights)
    from moju_core.loop.grassmann import projection_distance_sq

    family = np.arange(12) % 3
    same, other = [], []
    for i in range(12):
        for j in range(i + 1, 12):
            (same if family[i] == family[j] else other).append(
                projection_distance_sq(thetas[i], thetas[j])
            )
    assert np.mean(same) < np.mean(other)


def test_update_map_with_few_groups_solves_the_eigenproblem_in_their_span():
    # K p = 12 directions in R^90 (few groups, a long sequence): the map must lie in the span
    # of the Omega_i and satisfy A x = mu D x there, with mu among the smallest.
    bases, weights, delta, _ = _problem(seed=3, n=90, p=3, k=4, d=5)
    _, omegas = jump.low_dimensional_points(delta, bases)
    new = jump.update_map(delta, omegas, weights)
    assert new.shape == (90, 5)
    assert abs(_trace_constraint(new, omegas, weights) - 1.0) < 1e-8
    span = np.linalg.qr(omegas.transpose(1, 0, 2).reshape(90, -1))[0]
    assert_allclose(span @ (span.T @ new), new, atol=1e-10)
    degrees = weights.sum(axis=1)
    laplacian = np.diag(degrees) - weights
    blocks = omegas @ (np.swapaxes(omegas, 1, 2) @ delta)
    a = np.einsum("ij,ind,jmd->nm", laplacian, blocks, blocks)
    a = 0.5 * (a + a.T)
    b = np.einsum("k,knp,kmp->nm", degrees, omegas, omegas)
    reduced_a, reduced_b = span.T @ a @ span, span.T @ b @ span
    values = np.sort(np.real(np.linalg.eigvals(np.linalg.solve(reduced_b, reduced_a))))
    for column in new.T:
        x = span.T @ column
        mu = (x @ reduced_a @ x) / (x @ reduced_b @ x)
        assert_allclose(reduced_a @ x, mu * (reduced_b @ x), atol=1e-8 * np.abs(reduced_a).max())
        assert mu <= values[4] + 1e-8 * abs(values).max()
