"""m3c.ground.dbscan against scikit-learn's DBSCAN (the independent reference), plus its input checks."""

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from m3c.ground import dbscan


def sklearn_dbscan(points, eps, min_samples):
    model = DBSCAN(eps=eps, min_samples=min_samples).fit(points)
    is_core = np.zeros(len(points), dtype=bool)
    is_core[model.core_sample_indices_] = True
    return model.labels_, is_core


def same_partition(a, b):
    """Labels equal up to a permutation of cluster ids (noise -1 stays -1)."""
    if not np.array_equal(a == -1, b == -1):
        return False
    pairs = {(x, y) for x, y in zip(a[a >= 0], b[b >= 0])}
    return len(pairs) == len({x for x, _ in pairs}) == len({y for _, y in pairs})


def blobs(rng, num_blobs, per_blob, spread, background=0, duplicates=0):
    centres = rng.uniform(-2, 2, size=(num_blobs, 3))
    parts = [c + rng.normal(scale=spread, size=(per_blob, 3)) for c in centres]
    parts.append(rng.uniform(-2, 2, size=(background, 3)))
    x = np.concatenate(parts)
    if duplicates:
        x = np.concatenate([x, x[rng.integers(0, len(x), duplicates)]])
    return x[rng.permutation(len(x))]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("eps,min_samples", [(0.05, 3), (0.1, 5), (0.1, 10), (0.3, 20), (0.2, 1)])
def test_matches_sklearn_on_clustered_data_with_duplicates(seed, eps, min_samples):
    rng = np.random.default_rng(seed)
    x = blobs(rng, num_blobs=5, per_blob=300, spread=0.1, background=400, duplicates=100)
    labels, is_core = dbscan(x, eps, min_samples, return_core=True)
    ref_labels, ref_core = sklearn_dbscan(x, eps, min_samples)
    assert labels.dtype == np.int64 and labels.shape == (len(x),)
    np.testing.assert_array_equal(is_core, ref_core)
    assert same_partition(labels, ref_labels)
    # Stronger than a permutation: the ids and the border points' choices are scikit-learn's exactly.
    np.testing.assert_array_equal(labels, ref_labels)


@pytest.mark.parametrize("seed", range(3))
def test_matches_sklearn_on_uniform_random_data(seed):
    rng = np.random.default_rng(100 + seed)
    x = rng.uniform(0, 1, size=(3000, 3))
    for eps, min_samples in [(0.04, 3), (0.06, 6), (0.1, 15)]:
        np.testing.assert_array_equal(dbscan(x, eps, min_samples), sklearn_dbscan(x, eps, min_samples)[0])


def test_all_duplicates_and_float32_input():
    x = np.tile(np.array([[0.5, -1.0, 2.0]], dtype=np.float32), (25, 1))
    np.testing.assert_array_equal(dbscan(x, 0.01, 25), np.zeros(25, dtype=np.int64))
    np.testing.assert_array_equal(dbscan(x, 0.01, 26), np.full(25, -1))


def test_border_point_reachable_from_two_clusters():
    # Two clusters on a line and a non-core point within eps of a core point of each: it joins the cluster
    # whose lowest-index core point comes first, i.e. the cluster with id 0, exactly as scikit-learn does.
    a = np.array([0.0, 0.02, 0.04, 0.06])
    b = np.array([0.54, 0.56, 0.58, 0.60])
    for first, second in [(a, b), (b, a)]:
        x = np.zeros((9, 3))
        x[:, 0] = np.concatenate([first, second, [0.30]])
        labels, is_core = dbscan(x, 0.25, 4, return_core=True)
        assert not is_core[8]
        assert labels[8] == labels[0] == 0 and labels[4] == 1
        np.testing.assert_array_equal(labels, sklearn_dbscan(x, 0.25, 4)[0])


def test_empty_input():
    labels, is_core = dbscan(np.empty((0, 3)), 0.1, 5, return_core=True)
    assert labels.shape == (0,) and is_core.shape == (0,)


@pytest.mark.parametrize("points,eps,min_samples,message", [
    (np.array([[0.0, 0.0, np.nan]]), 0.1, 5, r"points\[0\].*not finite"),
    (np.array([[0.0, 0.0, 0.0], [np.inf, 0.0, 0.0]]), 0.1, 5, r"points\[1\].*not finite"),
    (np.zeros((4, 3)), 0.0, 5, "eps must be a positive"),
    (np.zeros((4, 3)), -0.1, 5, "eps must be a positive"),
    (np.zeros((4, 3)), np.nan, 5, "eps must be a positive"),
    (np.zeros((4, 3)), 0.1, 0, "min_samples must be >= 1"),
    (np.zeros((4, 2)), 0.1, 5, r"points must have shape \(N, 3\), got \(4, 2\)"),
    (np.zeros(3), 0.1, 5, r"points must have shape \(N, 3\), got \(3,\)"),
    (np.zeros((2, 3, 1)), 0.1, 5, r"points must have shape \(N, 3\)"),
    (np.array([["a", "b", "c"]]), 0.1, 5, "points must be a float array"),
])
def test_bad_input_raises_value_error(points, eps, min_samples, message):
    with pytest.raises(ValueError, match=message):
        dbscan(points, eps, min_samples)
