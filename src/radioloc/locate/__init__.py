"""``radioloc locate``: estimators applied to a user's measurement log."""

from radioloc.locate.base import LocateRequest, locate_method, methods, run_method

__all__ = ["LocateRequest", "locate_method", "methods", "run_method"]
