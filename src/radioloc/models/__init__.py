"""Measurement and motion models: objects with ``logpdf`` and ``sample`` (and what a
Kalman filter needs: ``F(dt)``/``Q(dt)`` for motion, ``moments()`` and
:func:`range_geometry` for ranges) that any estimator they fit takes as arguments."""

from radioloc.core.lazy import lazy_exports

#: public name -> the submodule defining it (imported on first access)
_WHERE = {
    "LosNlosRange": "los_nlos",
    "StickyLinkChain": "los_nlos",
    "FingerprintMixture": "fingerprint_mixture",
    "zone_posterior": "fingerprint_mixture",
    "REDUCTIONS": "mixture",
    "DiagMixture": "mixture",
    "linear_predict": "mixture",
    "merge_groups": "mixture",
    "outer": "mixture",
    "product": "mixture",
    "product_on": "mixture",
    "reduce": "mixture",
    "em_calibration": "mixture_calibration",
    "progressive_calibration": "mixture_calibration",
    "BoundedSpeedCV": "motion",
    "ConstantAcceleration": "motion",
    "ConstantVelocity": "motion",
    "InputDriven": "motion",
    "RandomWalk": "motion",
    "UniformDisk": "motion",
    "WhiteAccelerationCV": "motion",
    "Context": "measurement",
    "MeasurementModel": "measurement",
    "Observation": "measurement",
    "StateLayout": "measurement",
    "GaussianRange": "ranging",
    "RangeModel": "ranging",
    "range_geometry": "ranging",
    "BearingModel": "bearing",
    "HeadingModel": "heading",
    "ClockModel": "clock",
    "PseudorangeModel": "pseudorange",
    "RssModel": "rss_model",
    "TrapezoidRssModel": "rss_model",
    "MixtureRssModel": "mixture_rss",
    "FingerprintScanModel": "fingerprint_scan",
    "TdoaModel": "tdoa",
    "ProgressionInfo": "progressive_bayes",
    "isd": "progressive_bayes",
    "progressive_reduce": "progressive_bayes",
    "LogDistanceGaussian": "rssi_logdistance",
    "device_offset": "rssi_logdistance",
    "TrapezoidModel": "rssi_trapezoid",
    "dbm_to_rssi100": "rssi_trapezoid",
    "fit_trapezoid_model": "rssi_trapezoid",
    "SquaredRangeModel": "single_sensor",
}
__getattr__, __dir__ = lazy_exports(__name__, _WHERE)

__all__ = [
    "RandomWalk", "ConstantVelocity", "WhiteAccelerationCV", "ConstantAcceleration", "InputDriven", "UniformDisk",
    "GaussianRange", "RangeModel", "range_geometry", "MeasurementModel", "StateLayout", "Context", "Observation", "LosNlosRange", "StickyLinkChain",
    "LogDistanceGaussian", "TrapezoidModel", "fit_trapezoid_model", "dbm_to_rssi100",
    "DiagMixture", "em_calibration", "progressive_calibration", "SquaredRangeModel",
    "BoundedSpeedCV", "FingerprintMixture", "zone_posterior", "device_offset",
    "product", "product_on", "outer", "linear_predict", "reduce", "REDUCTIONS", "merge_groups",
    "progressive_reduce", "isd", "ProgressionInfo",
    "TdoaModel", "BearingModel", "HeadingModel", "PseudorangeModel", "ClockModel", "RssModel", "TrapezoidRssModel",
    "MixtureRssModel", "FingerprintScanModel",
]
