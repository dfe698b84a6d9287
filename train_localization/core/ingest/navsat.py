"""A GNSS receiver's sensor_msgs/NavSatFix as the DGPS receiver's fix (core/sensors/dgps.py).

The fix's WGS-84 point goes into the track's map frame through its geodetic anchor
(core/geodesy.py, pyproj) and is map-matched by the DGPS decoder's own ``locate``: projected
onto the track (on a network onto the nearest section, keeping its lateral offset, which the
track-selective fusion ranks parallel tracks by), withheld and counted beyond its lateral gate,
where another part of the alignment passes as close, or under a structure. So a receiver's
standard messages and the DGPS raw blocks give the same fixes, against the same error model.

1-sigma: the message's horizontal covariance (its larger axis), floored by the receiver model
where the antenna is (the DGPS parameters: ``fix_sigma`` at HDOP 0, the multipath 1-sigma in
the open or near a structure, which is the error model's ``min_stddev`` in the open); without a
covariance (COVARIANCE_TYPE_UNKNOWN) the model's 1-sigma at its nominal HDOP. A fix whose
status is below ``min_status`` (an autonomous fix, STATUS_FIX, where the error model is that of
differential fixes) is counted ``autonomous`` and withheld, as the decoder does with GGA quality
1; a STATUS_NO_FIX message is counted ``no_fix``, a STATUS_UNKNOWN one ``status_unknown``.
"""
from __future__ import annotations

from ..geodesy import GeodeticAnchor
from ..measurements import PositionFix
from ..sensors.dgps import DgpsDecoder, fix_sigma
from .records import STATUS_GBAS_FIX, STATUS_NO_FIX, STATUS_UNKNOWN, GnssFix


def anchor_of(track) -> GeodeticAnchor:
    """The geodetic anchor of a track (or of the network a route line runs on); ValueError in
    one line without one."""
    network = getattr(track, "network", None)
    anchor = network.geodetic if network is not None else track.geodetic
    if anchor is None:
        name = network.network_id if network is not None else track.track_id
        raise ValueError(f"track {name!r} has no geodetic block (latitude/longitude of its map origin, "
                         "core/geodesy.py): a GNSS fix cannot be placed on it")
    return anchor


class NavSatIngest:
    """GnssFix records -> DGPS PositionFixes (module docstring). ``params``: the DGPS receiver's
    resolved parameters (its error model, the fusion's too); ``stats``: the decoder's counts."""

    def __init__(self, params: dict, track, min_status: int = 1):
        if not 0 <= min_status <= STATUS_GBAS_FIX:
            raise ValueError(f"min_status {min_status} must be 0 (FIX), 1 (SBAS) or 2 (GBAS)")
        self.params = params
        self.projection = anchor_of(track).projection()
        self.min_status = min_status
        self.decoder = DgpsDecoder(params, track)
        self.stats = self.decoder.stats

    def fix(self, g: GnssFix) -> PositionFix | None:
        """The fix of one message, or None (withheld: counted in ``stats``)."""
        self.stats["epochs"] += 1
        if g.status == STATUS_NO_FIX:
            self.stats["no_fix"] += 1
            return None
        if g.status == STATUS_UNKNOWN:   # a driver that does not say what kind of fix: not rated
            self.stats["status_unknown"] = self.stats.get("status_unknown", 0) + 1
            return None
        if g.status < self.min_status:
            self.stats["autonomous"] += 1
            return None
        x, y = self.projection.to_map(g.latitude, g.longitude)
        reported, p = g.horizontal_sigma, self.params

        def sigma_at(near: bool) -> float:
            if reported is None:
                return fix_sigma(p, p["hdop_nominal"], near)
            return max(reported, fix_sigma(p, 0.0, near))
        return self.decoder.locate(g.stamp, x, y, sigma_at)
