"""Built-in associators. Importing this package registers every method by name."""

from mlkm_core.associators.base import (  # noqa: F401
    Associator,
    AssociatorConfig,
    Session,
    available_methods,
    make_associator,
    register,
)
