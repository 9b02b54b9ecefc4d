"""Measurement and motion models: vectorised ``logpdf`` and ``sample``."""

from radioloc.models.ranging import GaussianRange

__all__ = ["GaussianRange"]
