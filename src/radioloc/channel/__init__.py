"""Radio channels: the 2-D ray tracer and its scene, Sionna RT as a second provider (extra
``rt``, imported lazily), DS-CDMA signals and the time-of-arrival detectors (matched filter
and the OMP-based successive interference canceller)."""

from radioloc.channel.gsic import OMPSICConfig, matched_filter_toa, omp_sic_toa
from radioloc.channel.sionna_rt import SionnaConfig, available as sionna_available

__all__ = ["OMPSICConfig", "omp_sic_toa", "matched_filter_toa", "SionnaConfig",
           "sionna_available"]
