"""The MAVLink bridge's configuration error: a leaf module, so that the endpoint settings
(:mod:`bridges.mavlink.config`) and the geodetic origin they check
(:mod:`bridges.mavlink.geodesy`) both raise it without importing each other."""

from __future__ import annotations

from ftcap_hil.core.errors import ConfigError


class LinkConfigError(ConfigError):
    """A MAVLink endpoint is misconfigured (raised at start-up, names the key and value)."""
