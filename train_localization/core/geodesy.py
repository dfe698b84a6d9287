"""The map frame's place on the Earth: a track's or network's WGS-84 anchor (``geodetic:`` block).

A track file places its alignment in ``map`` (x east, y north, metres: REP-103/105). With a
``geodetic`` block the map frame is tied to WGS-84: its origin (x, y) = (0, 0) is the point
``latitude``/``longitude`` [deg], and map coordinates are those of a transverse Mercator
projection centred there (scale 1 on its central meridian: within 10 km of the anchor the
map's metres differ from the ground's by less than 1.3e-6). A GNSS fix (sensor_msgs/NavSatFix,
an NMEA GGA) then lies in the map frame of the track, and a track imported from OSM or railML
keeps its coordinates. pyproj does the geodesy::

    geodetic: {latitude: 48.1402, longitude: 11.5600}

Without the block the track has no place on the Earth: a geodetic fix cannot be placed on it
(``to_map`` is unavailable, the GNSS input says so in one line).
"""
from __future__ import annotations

import math
from dataclasses import dataclass


class GeodesyError(ValueError):
    """A geodetic block or a coordinate that cannot be used, with the reason in one line."""


@dataclass(frozen=True)
class GeodeticAnchor:
    """WGS-84 latitude and longitude [deg] of the map frame's origin."""

    latitude: float
    longitude: float

    def __post_init__(self):
        if not (math.isfinite(self.latitude) and -85.0 <= self.latitude <= 85.0):
            raise GeodesyError(f"geodetic latitude {self.latitude!r} must lie in -85 .. 85 deg")
        if not (math.isfinite(self.longitude) and -180.0 <= self.longitude <= 180.0):
            raise GeodesyError(f"geodetic longitude {self.longitude!r} must lie in -180 .. 180 deg")

    @classmethod
    def from_dict(cls, data) -> "GeodeticAnchor | None":
        """The anchor of a track file's ``geodetic`` block (None without one)."""
        if data is None:
            return None
        if not isinstance(data, dict) or not {"latitude", "longitude"} <= set(data):
            raise GeodesyError("geodetic block needs latitude and longitude [deg]")
        try:
            return cls(float(data["latitude"]), float(data["longitude"]))
        except (TypeError, ValueError) as exc:
            raise GeodesyError(f"geodetic block: {exc}") from None

    def to_dict(self) -> dict:
        return {"latitude": self.latitude, "longitude": self.longitude}

    def projection(self) -> "MapProjection":
        return MapProjection(self)


class MapProjection:
    """WGS-84 <-> map coordinates of one anchor (a pyproj transverse Mercator centred on it)."""

    def __init__(self, anchor: GeodeticAnchor):
        from pyproj import CRS, Transformer
        self.anchor = anchor
        local = CRS.from_proj4(f"+proj=tmerc +lat_0={anchor.latitude!r} +lon_0={anchor.longitude!r} +k=1 "
                               "+x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs")
        self._forward = Transformer.from_crs(CRS.from_epsg(4326), local, always_xy=True)
        self._inverse = Transformer.from_crs(local, CRS.from_epsg(4326), always_xy=True)

    def to_map(self, latitude: float, longitude: float) -> tuple[float, float]:
        """Map (x east, y north) [m] of a WGS-84 point [deg]."""
        x, y = self._forward.transform(longitude, latitude)
        return float(x), float(y)

    def to_geodetic(self, x: float, y: float) -> tuple[float, float]:
        """WGS-84 (latitude, longitude) [deg] of a map point [m]."""
        lon, lat = self._inverse.transform(x, y)
        return float(lat), float(lon)
