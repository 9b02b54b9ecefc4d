"""Cramer-Rao bounds: anchors (multilateration), cooperative networks (paper 000) and the
single moving sensor (paper 002), and any Gaussian measurement model (:mod:`radioloc.bounds.fisher`)."""

from radioloc.bounds.anchors import range_crb, range_fisher_information
from radioloc.bounds.fisher import Bound, crb, fisher_information, tracking_crb
from radioloc.bounds.cooperative import network_crb, network_range_information
from radioloc.bounds.single_sensor import differenced_crb, raw_range_crb

__all__ = ["range_crb", "range_fisher_information", "network_crb", "network_range_information",
           "differenced_crb", "raw_range_crb", "fisher_information", "crb", "tracking_crb", "Bound"]
