"""Built-in associators. Importing this package registers every method by name.

The paper's methods: ``kmeans`` (K-means and K-means++ on raw or preprocessed data) and
``mlkm`` (Multi-Layer K-means, with and without error correction). Stronger associators:
``mlkm_robust`` (MLKM with optimal, clutter-tolerant correction and matching), ``assignment``
(sequential sensor-to-sensor assignment) and ``multiframe`` (Kalman tracks and a multi-frame
local search).
"""

from mlkm_core.associators import (  # noqa: F401  (registers the methods)
    assignment,
    kmeans,
    mlkm,
    mlkm_robust,
    multiframe,
)
from mlkm_core.associators.base import (  # noqa: F401
    Associator,
    AssociatorConfig,
    DegradedResultWarning,
    Session,
    available_methods,
    canonical_order,
    make_associator,
    register,
)
