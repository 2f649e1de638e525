"""Built-in associators. Importing this package registers every method by name."""

import mlkm_core.associators.assignment  # noqa: F401  (BEYOND: issue 4)
import mlkm_core.associators.mlkm_robust  # noqa: F401  (BEYOND: issue 4)
import mlkm_core.associators.multiframe  # noqa: F401  (BEYOND: issue 4)
from mlkm_core.associators import kmeans, mlkm  # noqa: F401,E402  (CORE: paper methods)
from mlkm_core.associators.base import (  # noqa: F401
    Associator,
    AssociatorConfig,
    Session,
    available_methods,
    make_associator,
    register,
)
