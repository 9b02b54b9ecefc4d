"""radioloc: locating and tracking radio nodes from ranges and received signal strength.

Layers (imports point downward only): ``cli`` > ``experiments`` > ``report`` > ``sim`` >
``channel`` > ``estimators`` > ``bounds`` > ``models`` > ``core``; ``io`` reads logs and
data sets; ``locate`` applies estimators to a user's log.
"""

from radioloc.core.errors import (
    ConfigError,
    DataUnavailable,
    GeometryError,
    InputError,
    RadiolocError,
)

__version__ = "0.1.0"
__all__ = ["RadiolocError", "InputError", "GeometryError", "ConfigError", "DataUnavailable",
           "__version__"]
