"""Measurement and motion models: objects with ``logpdf`` and ``sample`` (and what a
Kalman filter needs: ``F(dt)``/``Q(dt)`` for motion, ``moments()`` and
:func:`range_geometry` for ranges) that any estimator they fit takes as arguments."""

from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain
from radioloc.models.fingerprint_mixture import FingerprintMixture, zone_posterior
from radioloc.models.mixture import (REDUCTIONS, DiagMixture, linear_predict, merge_groups, outer,
                                     product, product_on, reduce)
from radioloc.models.mixture_calibration import em_calibration, progressive_calibration
from radioloc.models.motion import (
    BoundedSpeedCV,
    ConstantAcceleration,
    ConstantVelocity,
    InputDriven,
    RandomWalk,
    UniformDisk,
    WhiteAccelerationCV,
)
from radioloc.models.measurement import Context, MeasurementModel, Observation, StateLayout
from radioloc.models.ranging import GaussianRange, RangeModel, range_geometry
from radioloc.models.bearing import BearingModel
from radioloc.models.clock import ClockModel
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.rss_model import RssModel, TrapezoidRssModel
from radioloc.models.tdoa import TdoaModel
from radioloc.models.progressive_bayes import ProgressionInfo, isd, progressive_reduce
from radioloc.models.rssi_logdistance import LogDistanceGaussian, device_offset
from radioloc.models.rssi_trapezoid import TrapezoidModel, dbm_to_rssi100, fit_trapezoid_model
from radioloc.models.single_sensor import SquaredRangeModel

__all__ = [
    "RandomWalk", "ConstantVelocity", "WhiteAccelerationCV", "ConstantAcceleration", "InputDriven", "UniformDisk",
    "GaussianRange", "RangeModel", "range_geometry", "MeasurementModel", "StateLayout", "Context", "Observation", "LosNlosRange", "StickyLinkChain",
    "LogDistanceGaussian", "TrapezoidModel", "fit_trapezoid_model", "dbm_to_rssi100",
    "DiagMixture", "em_calibration", "progressive_calibration", "SquaredRangeModel",
    "BoundedSpeedCV", "FingerprintMixture", "zone_posterior", "device_offset",
    "product", "product_on", "outer", "linear_predict", "reduce", "REDUCTIONS", "merge_groups",
    "progressive_reduce", "isd", "ProgressionInfo",
    "TdoaModel", "BearingModel", "PseudorangeModel", "ClockModel", "RssModel", "TrapezoidRssModel",
]
