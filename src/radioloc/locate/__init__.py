"""``radioloc locate``: estimators applied to a user's measurement log."""

from radioloc.locate.base import LocateRequest, locate_method, methods, run_method

__all__ = ["LocateRequest", "Tracker", "locate_method", "methods", "run_method"]


def __getattr__(name: str):
    """:class:`radioloc.locate.stream.Tracker`, imported on first use like the methods."""
    if name == "Tracker":
        from radioloc.locate.stream import Tracker

        return Tracker
    raise AttributeError(f"module 'radioloc.locate' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the ones :func:`__getattr__` imports on first use."""
    return sorted(set(globals()) | set(__all__))
