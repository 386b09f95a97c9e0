"""Spectral clustering of the four clusters' tracklets, the baseline of the CVMHAT paper (Sec. 4.1).

The tracklets of the four clusters are the nodes of one graph whose affinities are the edge
weights of Eqs. 17-18 (zero between tracklets of the same cluster and between clusters that no
edge set joins); normalised spectral clustering (Ng, Jordan and Weiss) splits them into as many
groups as the largest cluster has tracklets. Two tracklets of adjacent clusters in one group are
then joined (one-to-one, by a Hungarian assignment on their weights inside the group), which
gives edges in the same form as the MIP's, for the same stitching.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.optimize import linear_sum_assignment

from xvmatch.inference.tracks.track_mip import ClusterSolution, _dummies, _sizes, check_weights

__all__ = ["spectral_groups", "spectral_solution"]


def spectral_groups(affinity: np.ndarray, n_groups: int, seed: int = 0) -> np.ndarray:
    """(N,) group of each node: k-means (seeded, k-means++ start) on the row-normalised top
    ``n_groups`` eigenvectors of ``D^-1/2 W D^-1/2``."""
    w = np.asarray(affinity, dtype=float)
    n = w.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    k = max(1, min(int(n_groups), n))
    if k == 1:
        return np.zeros(n, dtype=np.int64)
    degree = w.sum(axis=1)
    inv = np.where(degree > 0, 1.0 / np.sqrt(np.where(degree > 0, degree, 1.0)), 0.0)
    m = inv[:, None] * w * inv[None, :]
    _, vectors = np.linalg.eigh(m)
    u = vectors[:, -k:]
    norms = np.linalg.norm(u, axis=1, keepdims=True)
    u = u / np.where(norms > 0, norms, 1.0)
    with warnings.catch_warnings():  # an empty cluster is a valid answer here, not a problem
        warnings.simplefilter("ignore", UserWarning)
        _, labels = kmeans2(u, k, minit="++", seed=np.random.default_rng(seed))
    return labels.astype(np.int64)


def spectral_solution(
    weights: Sequence[np.ndarray], c0: float = 0.2, seed: int = 0
) -> ClusterSolution:
    """Edges of one window from spectral clustering on the same weights as the MIP."""
    mats = check_weights(weights)
    sizes = _sizes(mats)
    start = np.r_[0, np.cumsum(sizes)]
    n = int(start[-1])
    affinity = np.zeros((n, n))
    for i, w in enumerate(mats):
        j = (i + 1) % 4
        block = (slice(start[i], start[i + 1]), slice(start[j], start[j + 1]))
        affinity[block] = w
        affinity[block[1], block[0]] = w.T
    groups = spectral_groups(affinity, max(sizes) if sizes else 0, seed)
    edges = []
    for i, w in enumerate(mats):
        j = (i + 1) % 4
        same = groups[start[i]:start[i + 1], None] == groups[None, start[j]:start[j + 1]]
        e = np.zeros(w.shape, dtype=np.int8)
        if w.size:
            score = np.where(same, w, 0.0)
            r, c = linear_sum_assignment(-score)
            keep = score[r, c] > 0
            e[r[keep], c[keep]] = 1
        edges.append(e)
    return ClusterSolution(tuple(edges), _dummies(edges, sizes), "spectral", 0)
