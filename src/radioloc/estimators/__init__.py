"""Estimators: functions and small classes that take measurements and return estimates."""

from radioloc.estimators.multilateration import Multilateration

__all__ = ["Multilateration"]
