"""Physical constants shared across the toolkit."""

from __future__ import annotations

#: Speed of light in vacuum, m/s (exact, SI).
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
