"""The one setting that chooses between an algorithm's NumPy definition and its compiled kernel.

Every algorithm that has a compiled kernel is defined once in NumPy, readable beside its
paper; the kernel (numba, in the family's ``_compiled`` module) computes the same thing
faster. Estimators, models and channel functions that have both take
``backend="numba" | "numpy"``: ``"numba"`` (the default) runs the kernel, ``"numpy"`` the
definition. The two agree to the tolerance stated in ``docs/architecture.md`` ("Kernels"),
which the backend-equivalence tests hold.
"""

from __future__ import annotations

from radioloc.core.errors import ConfigError

#: The accepted values of every ``backend=`` setting.
BACKENDS = ("numba", "numpy")

#: The default backend.
DEFAULT_BACKEND = "numba"


def check_backend(backend, name: str = "backend") -> str:
    """Validate a ``backend=`` setting.

    Parameters
    ----------
    backend : str
        ``"numba"`` or ``"numpy"``.
    name : str, optional
        The setting's name, for the message.

    Returns
    -------
    str
        ``backend``.

    Raises
    ------
    ConfigError
        Any other value, naming the setting and the accepted values.
    """
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise ConfigError(f"{name}: expected one of {', '.join(map(repr, BACKENDS))}, "
                          f"got {backend!r}")
    return backend
