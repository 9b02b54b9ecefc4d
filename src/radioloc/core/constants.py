"""Physical constants shared across the toolkit."""

from __future__ import annotations

#: Speed of light in vacuum, m/s (exact, SI).
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
#: Rotation rate of the Earth (WGS84, as GPS defines it), rad/s.
EARTH_ROTATION_RAD_PER_S = 7.2921151467e-5
