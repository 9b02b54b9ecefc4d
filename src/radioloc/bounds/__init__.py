"""Cramer-Rao bounds."""

from radioloc.bounds.anchors import range_crb, range_fisher_information

__all__ = ["range_crb", "range_fisher_information"]
