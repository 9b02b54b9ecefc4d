"""radioloc: locating and tracking radio nodes from ranges and received signal strength.

Layers (imports point downward only; ``tests/test_library_rules.py`` checks them)::

    cli ─────────────┬──────────────────────┐
    experiments      │                      locate   (a user's log -> estimator -> table)
      │   │   │      │                        │
      │   │   report │                        │
      │   sim ──┐    │                        │
      │   │   channel│                        │
      └───┴──> estimators <───────────────────┘
                  │
               bounds
                  │
               models        motion and measurement models
                  │
                core         Estimate, Track, errors, validation, rng
    io ──> core              logs and data sets

``sim`` never imports ``estimators`` (a tracker under test is injected); ``channel``
imports only ``core``; every estimator follows the contract of
:mod:`radioloc.estimators.base` (``docs/architecture.md``).
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
