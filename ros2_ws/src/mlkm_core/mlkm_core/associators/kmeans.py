"""K-means and K-means++ baselines of the paper, on raw (UP) and preprocessed (P) data.

Each detection is the point (v, t) for UP or (v, t') for P, where t' is the paper's
back-projection to the first sensor (``mlkm_core.preprocess``). Features are the raw values in
their own units (m/s and s), exactly as the paper clusters them; no scaling. The number of
clusters is the number of targets (capped by the number of detections).

K-means and K-means++ are scikit-learn's ``KMeans`` with ``init='random'`` and
``init='k-means++'``; both run once (``n_init=1``) with ``random_state = config.seed``, so the
initialisation is the only difference between them, as the paper describes.

Registered methods: ``kmeans_up``, ``kmeans_p``, ``kmeans_pp_up``, ``kmeans_pp`` (K-means++ on
preprocessed data, the paper's "P: K-means++").
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from mlkm_core.associators.base import Associator, canonical_order, register
from mlkm_core.preprocess import preprocess
from mlkm_core.types import Detections, Layout


def kmeans_labels(
    points: np.ndarray, k: int, init: str, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """scikit-learn K-means, one run; returns (labels, centers). Handles tiny inputs."""
    n = points.shape[0]
    if n == 0:
        return np.zeros(0, np.int64), np.zeros((0, points.shape[1]))
    k = max(1, min(int(k), n))
    if k == n:
        return np.arange(n, dtype=np.int64), points.copy()
    from sklearn.cluster import KMeans  # scikit-learn takes a second to import: on first use

    km = KMeans(n_clusters=k, init=init, n_init=1, random_state=seed).fit(points)
    return km.labels_.astype(np.int64), km.cluster_centers_


class _KMeansAssociator(Associator):
    init: ClassVar[str]
    preprocessed: ClassVar[bool]

    def associate(self, layout: Layout, detections: Detections, n_targets: int) -> np.ndarray:
        order = canonical_order(detections)
        d = detections.subset(order)
        t = preprocess(layout, d) if self.preprocessed else d.stamp
        labels, _ = kmeans_labels(
            np.column_stack([d.velocity, t]), n_targets, self.init, self.config.seed
        )
        out = np.empty(len(detections), np.int64)
        out[order] = labels
        return out


@register
class KMeansUP(_KMeansAssociator):
    """K-means (random init) on raw (v, t)."""

    name = 'kmeans_up'
    init = 'random'
    preprocessed = False


@register
class KMeansP(_KMeansAssociator):
    """K-means (random init) on preprocessed (v, t')."""

    name = 'kmeans_p'
    init = 'random'
    preprocessed = True


@register
class KMeansPPUP(_KMeansAssociator):
    """K-means++ on raw (v, t)."""

    name = 'kmeans_pp_up'
    init = 'k-means++'
    preprocessed = False


@register
class KMeansPP(_KMeansAssociator):
    """K-means++ on preprocessed (v, t'): the paper's "P: K-means++"."""

    name = 'kmeans_pp'
    init = 'k-means++'
    preprocessed = True
