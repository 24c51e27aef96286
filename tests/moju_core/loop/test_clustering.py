"""Initial groups, the neighbour graph, spectral clustering and regrouping."""

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal

from moju_core.loop import clustering


def test_initial_labels_respect_the_minimum_size():
    rng = np.random.default_rng(0)
    features = np.concatenate([rng.normal(0, 1, (200, 3)), rng.normal(20, 0.1, (3, 3))])
    labels = clustering.initial_labels(features, n_groups=8, min_size=10, seed=0)
    sizes = np.bincount(labels)
    assert sizes.min() >= 10
    assert_array_equal(np.unique(labels), np.arange(len(sizes)))


def test_initial_labels_fitted_on_a_sample_still_label_every_track(monkeypatch):
    # 4 well separated blobs of 300 tracks; a sample of 10 per group (40 tracks) fits the
    # centres, and every track must join its own blob's group, the same for the same seed.
    monkeypatch.setattr(clustering, "KMEANS_SAMPLE_PER_GROUP", 10)
    rng = np.random.default_rng(0)
    centres = np.array([[0.0, 0.0], [50.0, 0.0], [0.0, 50.0], [50.0, 50.0]])
    truth = np.repeat(np.arange(4), 300)
    features = centres[truth] + rng.normal(0, 1, (1200, 2))
    labels = clustering.initial_labels(features, n_groups=4, min_size=10, seed=3)
    assert len(labels) == 1200
    # One label per blob and one blob per label (a permutation of the truth).
    pairs = set(zip(truth.tolist(), labels.tolist(), strict=True))
    assert len(pairs) == 4 and len({b for _, b in pairs}) == 4
    assert_array_equal(labels, clustering.initial_labels(features, 4, 10, seed=3))


def test_neighbour_edges_are_symmetric_nearest_neighbours():
    centroids = np.array([[0.0], [1.0], [2.5], [10.0], [11.0]])
    edges = clustering.neighbour_edges(centroids, 1)
    # 0->1, 1->0, 2->1, 3->4, 4->3, as undirected pairs i < j
    assert {tuple(e) for e in edges} == {(0, 1), (1, 2), (3, 4)}


def test_similarity_graph_is_one_for_equal_subspaces_and_small_for_orthogonal():
    eye = np.eye(6)
    bases = np.stack([eye[:, :2], eye[:, :2], eye[:, 2:4]])
    weights = clustering.similarity_graph(bases, np.array([[0, 1], [0, 2]]))
    assert weights[0, 1] == weights[1, 0] == 1.0
    assert np.isclose(weights[0, 2], np.exp(-2.0))
    assert weights[1, 2] == 0.0


def test_cluster_groups_separates_block_diagonal_coefficients():
    c = np.zeros((6, 6))
    c[:3, :3] = 1.0
    c[3:, 3:] = 1.0
    labels = clustering.cluster_groups(c + 0.01, 2, seed=0)
    assert len(set(labels[:3])) == 1 and len(set(labels[3:])) == 1
    assert labels[0] != labels[3]


def _two_subspace_data(rng, n=12, per_group=30):
    eye = np.eye(n)
    bases = np.stack([eye[:, :2], eye[:, 2:4]])
    columns = [bases[i] @ rng.standard_normal((2, per_group)) for i in range(2)]
    return bases, np.concatenate(columns, axis=1)


def test_regroup_moves_misassigned_trajectories_to_their_subspace():
    rng = np.random.default_rng(1)
    bases, trajectories = _two_subspace_data(rng)
    truth = np.repeat([0, 1], 30)
    labels = truth.copy()
    labels[:5] = 1  # five trajectories of subspace 0 sit in group 1
    new = clustering.regroup(trajectories, labels, bases, np.array([0, 0]), min_size=4)
    assert_array_equal(new, truth)


def test_regroup_only_moves_within_a_cluster():
    rng = np.random.default_rng(2)
    bases, trajectories = _two_subspace_data(rng)
    labels = np.repeat([0, 1], 30)
    labels[:5] = 1
    new = clustering.regroup(trajectories, labels, bases, np.array([0, 1]), min_size=4)
    assert_array_equal(new, labels)


def test_regroup_never_leaves_a_group_below_the_minimum_size():
    rng = np.random.default_rng(3)
    bases, trajectories = _two_subspace_data(rng)
    labels = np.repeat([0, 1], 30)
    labels[:25] = 1  # 25 of group 0's trajectories wrongly in group 1; group 0 holds 5
    labels[30:] = 0  # and all of group 1's in group 0
    new = clustering.regroup(trajectories, labels, bases, np.array([0, 0]), min_size=20)
    assert np.bincount(new, minlength=2).min() >= 20


def test_track_features_of_a_long_sequence_keep_the_top_principal_coordinates():
    # Beyond FEATURES_GRAM_MAX_ROWS rows the directions come from a randomized range finder:
    # the features' inner products (sign- and rotation-free) equal those of the exact top 12.
    rng = np.random.default_rng(0)
    rows, n_points, rank = clustering.FEATURES_GRAM_MAX_ROWS + 2, 300, 12
    values = 10.0 ** -np.linspace(0.0, 2.0, rank)
    tracks = (rng.standard_normal((rows, rank)) * values) @ rng.standard_normal((rank, n_points))
    tracks += 1e-6 * rng.standard_normal(tracks.shape)
    features = clustering.track_features(tracks)
    u, s, vt = np.linalg.svd(tracks, full_matrices=False)
    exact = vt[:12].T * s[:12]
    assert features.shape == (n_points, 12)
    assert_allclose(features @ features.T, exact @ exact.T, atol=1e-9 * s[0] ** 2)
