"""NED around a geodetic origin -> latitude and longitude: the flat-earth approximation.

A ground station draws a vessel from GLOBAL_POSITION_INT (degrees * 1e7), while the
simulation works in a local NED frame. Around a configured origin (lat0, lon0, h0) on the
WGS-84 ellipsoid,

    lat = lat0 + north / R_M(lat0),    lon = lon0 + east / (R_N(lat0) cos lat0),

with the meridian radius R_M = a (1 - e^2) / (1 - e^2 sin^2 lat0)^(3/2) and the prime-vertical
radius R_N = a / sqrt(1 - e^2 sin^2 lat0) (a = 6378137 m, e^2 = 6.69437999014e-3: the
WGS-84 constants). The error grows with the square of the distance
from the origin: well under a metre within a few kilometres, which is the scale of a basin
or a harbour trial.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from bridges.mavlink.errors import LinkConfigError

WGS84_A_M = 6_378_137.0
WGS84_E2 = 6.694_379_990_14e-3  # first eccentricity squared


@dataclass(frozen=True)
class GeodeticOrigin:
    """The geodetic position of the NED origin: latitude and longitude (deg), height (m)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        values = (self.lat_deg, self.lon_deg, self.alt_m)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise LinkConfigError(f"geodetic_origin: expected finite numbers, got {values!r}")
        if not -89.0 <= self.lat_deg <= 89.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise LinkConfigError(
                f"geodetic_origin: latitude in [-89, 89] and longitude in [-180, 180] degrees, "
                f"got {values!r}"
            )

    @classmethod
    def from_value(cls, value: Sequence[float] | None) -> GeodeticOrigin | None:
        """``[lat_deg, lon_deg]`` or ``[lat_deg, lon_deg, alt_m]`` (None: no origin)."""
        if value is None:
            return None
        if isinstance(value, (str, bytes)) or len(value) not in (2, 3):
            raise LinkConfigError(
                f"geodetic_origin: expected [lat_deg, lon_deg] or [lat_deg, lon_deg, alt_m], "
                f"got {value!r}"
            )
        return cls(*(float(v) for v in value))

    def to_geodetic(self, north_m: float, east_m: float) -> tuple[float, float]:
        """(lat_deg, lon_deg) of the point ``north_m``, ``east_m`` from the origin."""
        phi = math.radians(self.lat_deg)
        s2 = math.sin(phi) ** 2
        r_m = WGS84_A_M * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * s2) ** 1.5
        r_n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * s2)
        lat = self.lat_deg + math.degrees(north_m / r_m)
        lon = self.lon_deg + math.degrees(east_m / (r_n * math.cos(phi)))
        return lat, (lon + 180.0) % 360.0 - 180.0
