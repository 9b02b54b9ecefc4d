"""Array conventions, validation, errors, randomness, geometry and metrics."""

from radioloc.core.errors import (
    ConfigError,
    DataUnavailable,
    GeometryError,
    InputError,
    RadiolocError,
)

__all__ = ["RadiolocError", "InputError", "GeometryError", "ConfigError", "DataUnavailable"]
