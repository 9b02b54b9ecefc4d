"""Estimators: functions and small classes that take measurements and return estimates."""

from radioloc.estimators.multilateration import MultilaterationResult, gauss_newton

__all__ = ["gauss_newton", "MultilaterationResult"]
