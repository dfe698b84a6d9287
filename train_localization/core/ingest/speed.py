"""A speed odometer's nav_msgs/Odometry or geometry_msgs/TwistWithCovarianceStamped as the
Doppler radar's speed or the wheel pulse generator's distance increments.

The body's forward speed (base_link x), signed by ``direction`` (+1: base_link x points towards
increasing chainage, along the route on a network), is taken as the configured sensor kind's
measurement, so that the fusion applies that kind's error model and fault modes (a radar's
scale faults and dropouts, a wheel's slip, slide and wear):

  * ``doppler`` (measures speed): one SpeedMeasurement per message;
  * ``wheel`` (measures distance): one DistanceIncrement from each message to the next, the
    trapezoid of their speeds; two messages further apart than ``max_gap`` give none (counted
    ``gaps``), the next increment starts at the later one.

1-sigma: the message's variance (the white part) with the parts the sensor's error model
expects inside a reported stddev (ErrorModel.reported_scale x |speed|, reported_bias), no less
than the model's ``min_stddev`` (per second of an increment's duration for its distance). A
message stamped at or before the previous one is refused (``out_of_order``).
"""
from __future__ import annotations

import math

from ..measurements import DistanceIncrement, SpeedMeasurement
from ..sensors.base import ErrorModel
from ..signals import InputRejected
from .records import BodyTwist

KINDS = ("speed", "distance")   # ErrorModel.measures of the sensor kinds a speed input can be


def reported_sigma(model: ErrorModel, value: float, white_variance: float) -> float:
    """1-sigma of a ``value`` (a speed [m/s] or a distance [m]) with a white variance from the
    message: that, the model's reported scale on |value| and its reported bias."""
    return math.sqrt(white_variance + (model.reported_scale * value) ** 2 + model.reported_bias ** 2)


class SpeedIngest:
    """BodyTwist records -> the measurements of a speed or distance sensor (module docstring)."""

    def __init__(self, model: ErrorModel, unit_id: str, direction: int = 1, max_gap: float = 1.0):
        if model.measures not in KINDS:
            raise ValueError(f"sensor {model.sensor!r} measures {model.measures}; a speed input needs one that "
                             f"measures {' or '.join(KINDS)} (doppler_radar, wheel_sensor)")
        if direction not in (-1, 1):
            raise ValueError(f"direction must be +1 or -1, not {direction!r}")
        self.model = model
        self.unit_id = unit_id
        self.direction = direction
        self.max_gap = max_gap
        self._prev: BodyTwist | None = None
        self.stats = {"messages": 0, "gaps": 0}

    def add(self, tw: BodyTwist) -> list:
        if self._prev is not None and not tw.stamp > self._prev.stamp:
            raise InputRejected("out_of_order", f"speed message stamped {tw.stamp - self._prev.stamp:+.6f} s after "
                                                "the previous one")
        tw = BodyTwist(tw.stamp, self.direction * tw.speed, tw.speed_variance)
        prev, self._prev = self._prev, tw
        self.stats["messages"] += 1
        m = self.model
        if m.measures == "speed":
            sigma = max(reported_sigma(m, tw.speed, tw.speed_variance), m.min_stddev)
            return [SpeedMeasurement(tw.stamp, m.sensor, self.unit_id, tw.speed, sigma)]
        if prev is None:
            return []
        dt = tw.stamp - prev.stamp
        if dt > self.max_gap:
            self.stats["gaps"] += 1
            return []
        speed = 0.5 * (tw.speed + prev.speed)
        variance = 0.25 * (tw.speed_variance + prev.speed_variance)
        speed_sigma = max(reported_sigma(m, speed, variance), m.min_stddev)
        return [DistanceIncrement(tw.stamp, m.sensor, self.unit_id, dt, speed * dt, speed_sigma * dt, speed,
                                  speed_sigma)]
