"""Decoded measurements: what sensor decoders produce and the fusion consumes.

They mirror the messages of train_localization_msgs one to one (field names and
units are the same); ``stamp`` is the time of validity [s].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .signals import MAX_STAMP, InputRejected, require_short


# Physical limits of any measurement (reason "implausible" beyond them): no line is longer
# than MAX_CHAINAGE, no train faster than MAX_SPEED (maglev record 603 km/h); a stddev is
# between STDDEV_RANGE (below: finer than any sensor resolves, which would pin the filter;
# above: no information, and it overflows the filter's arithmetic); an increment lasts
# at most MAX_DURATION; a stamp lies within the reach of a ROS time (signals.MAX_STAMP).
MAX_CHAINAGE = 1.0e7          # [m]
MAX_SPEED = 200.0             # [m/s]
STDDEV_RANGE = (1.0e-6, 1.0e5)   # [m] or [m/s]
MAX_DURATION = 60.0           # [s]


def _require_range(kind: str, name: str, value: float, lo: float, hi: float) -> None:
    if not lo <= value <= hi:
        raise InputRejected("implausible", f"{kind}.{name} = {value!r} outside [{lo:g}, {hi:g}]")


def _require_finite(kind: str, **values: float) -> None:
    """Raises InputRejected("nan") naming the first of ``values`` that is NaN or inf."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise InputRejected("nan", f"{kind}.{name} is {value!r}")


@dataclass(frozen=True)
class PositionFix:
    """Absolute chainage of the train front [m] with 1-sigma [m], valid at ``stamp``."""

    stamp: float
    sensor: str
    unit_id: str
    track_id: str
    reference_id: str
    position: float
    position_stddev: float
    direction: int = 0
    residuals: tuple[float, ...] = field(default=())
    lateral: float = 0.0          # a 2-D fix: signed offset from track_id's alignment [m], + left
    lateral_stddev: float = 0.0   # its 1-sigma [m]; 0: no lateral (track_id is the equipment's track)

    @property
    def is_map_fix(self) -> bool:
        """A 2-D fix (DGPS) placed on the nearest track: it measures a point in the map, not which
        track the train is on (track_id is only the nearest one)."""
        return self.lateral_stddev > 0.0

    def validate(self) -> None:
        require_short("PositionFix", sensor=self.sensor, unit_id=self.unit_id, track_id=self.track_id,
                      reference_id=self.reference_id)
        isfinite = math.isfinite
        if not (isfinite(self.stamp) and isfinite(self.position) and isfinite(self.position_stddev)):
            _require_finite("PositionFix", stamp=self.stamp, position=self.position,
                            position_stddev=self.position_stddev)
        if self.position_stddev <= 0.0:
            raise InputRejected("stddev", f"PositionFix stddev {self.position_stddev} must be > 0")
        _require_range("PositionFix", "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)
        _require_range("PositionFix", "position", self.position, -MAX_CHAINAGE, MAX_CHAINAGE)
        _require_range("PositionFix", "position_stddev", self.position_stddev, *STDDEV_RANGE)
        if self.lateral_stddev != 0.0 or self.lateral != 0.0:
            _require_finite("PositionFix", lateral=self.lateral, lateral_stddev=self.lateral_stddev)
            _require_range("PositionFix", "lateral", self.lateral, -MAX_CHAINAGE, MAX_CHAINAGE)
            _require_range("PositionFix", "lateral_stddev", self.lateral_stddev, *STDDEV_RANGE)


MAX_YAW_RATE = 2.0            # [rad/s]: no rail or guideway vehicle turns faster (R = 10 m at 20 m/s)


@dataclass(frozen=True)
class YawRate:
    """Turn rate of the vehicle body [rad/s] (+ left) with 1-sigma [rad/s], valid at ``stamp``."""

    stamp: float
    sensor: str
    unit_id: str
    yaw_rate: float
    yaw_rate_stddev: float

    def validate(self) -> None:
        require_short("YawRate", sensor=self.sensor, unit_id=self.unit_id)
        _require_finite("YawRate", stamp=self.stamp, yaw_rate=self.yaw_rate, yaw_rate_stddev=self.yaw_rate_stddev)
        if self.yaw_rate_stddev <= 0.0:
            raise InputRejected("stddev", f"YawRate stddev {self.yaw_rate_stddev} must be > 0")
        _require_range("YawRate", "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)
        _require_range("YawRate", "yaw_rate", self.yaw_rate, -MAX_YAW_RATE, MAX_YAW_RATE)
        _require_range("YawRate", "yaw_rate_stddev", self.yaw_rate_stddev, *STDDEV_RANGE)


MAX_ACCELERATION = 20.0       # [m/s^2]: about 2 g, beyond any train's traction, braking or gravity
GRAVITY = 9.80665             # [m/s^2] standard gravity


@dataclass(frozen=True)
class Acceleration:
    """Longitudinal acceleration of the train [m/s^2] (signed like speed: + = towards increasing
    chainage) with 1-sigma [m/s^2], valid at ``stamp``: an accelerometer's specific force less the
    component of gravity along the track (core/sensors/accelerometer.py)."""

    stamp: float
    sensor: str
    unit_id: str
    acceleration: float
    acceleration_stddev: float

    def validate(self) -> None:
        require_short("Acceleration", sensor=self.sensor, unit_id=self.unit_id)
        _require_finite("Acceleration", stamp=self.stamp, acceleration=self.acceleration,
                        acceleration_stddev=self.acceleration_stddev)
        if self.acceleration_stddev <= 0.0:
            raise InputRejected("stddev", f"Acceleration stddev {self.acceleration_stddev} must be > 0")
        _require_range("Acceleration", "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)
        _require_range("Acceleration", "acceleration", self.acceleration, -MAX_ACCELERATION, MAX_ACCELERATION)
        _require_range("Acceleration", "acceleration_stddev", self.acceleration_stddev, *STDDEV_RANGE)


@dataclass(frozen=True)
class SpeedMeasurement:
    """Signed speed [m/s] with 1-sigma [m/s], valid at ``stamp``."""

    stamp: float
    sensor: str
    unit_id: str
    speed: float
    speed_stddev: float

    def validate(self) -> None:
        require_short("SpeedMeasurement", sensor=self.sensor, unit_id=self.unit_id)
        isfinite = math.isfinite
        if not (isfinite(self.stamp) and isfinite(self.speed) and isfinite(self.speed_stddev)):
            _require_finite("SpeedMeasurement", stamp=self.stamp, speed=self.speed,
                            speed_stddev=self.speed_stddev)
        if self.speed_stddev <= 0.0:
            raise InputRejected("stddev", f"SpeedMeasurement stddev {self.speed_stddev} must be > 0")
        _require_range("SpeedMeasurement", "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)
        _require_range("SpeedMeasurement", "speed", self.speed, -MAX_SPEED, MAX_SPEED)
        _require_range("SpeedMeasurement", "speed_stddev", self.speed_stddev, *STDDEV_RANGE)


@dataclass(frozen=True)
class DistanceIncrement:
    """Signed distance [m] over ``duration`` [s] ending at ``stamp``, and mean speed."""

    stamp: float
    sensor: str
    unit_id: str
    duration: float
    distance: float
    distance_stddev: float
    speed: float
    speed_stddev: float

    def validate(self) -> None:
        require_short("DistanceIncrement", sensor=self.sensor, unit_id=self.unit_id)
        _require_finite("DistanceIncrement", stamp=self.stamp, duration=self.duration,
                        distance=self.distance, distance_stddev=self.distance_stddev,
                        speed=self.speed, speed_stddev=self.speed_stddev)
        if self.duration <= 0.0 or self.distance_stddev <= 0.0 or self.speed_stddev <= 0.0:
            raise InputRejected("stddev", "DistanceIncrement duration and stddevs must be > 0")
        kind = "DistanceIncrement"
        _require_range(kind, "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)
        _require_range(kind, "duration", self.duration, 1.0e-6, MAX_DURATION)
        _require_range(kind, "distance", self.distance, -MAX_SPEED * self.duration, MAX_SPEED * self.duration)
        _require_range(kind, "speed", self.speed, -MAX_SPEED, MAX_SPEED)
        _require_range(kind, "distance_stddev", self.distance_stddev, *STDDEV_RANGE)
        _require_range(kind, "speed_stddev", self.speed_stddev, *STDDEV_RANGE)


CLEAR, OCCUPIED, DISTURBED = 0, 1, 2


@dataclass(frozen=True)
class SectionState:
    """Occupancy of one section between two chainages [m]."""

    section_id: str
    start: float
    end: float
    state: int
    axle_count: int
    axles_in: int
    axles_out: int


@dataclass(frozen=True)
class SectionOccupancy:
    """Occupancy of every section of one wayside system at ``stamp``."""

    stamp: float
    source: str
    sections: tuple[SectionState, ...]

    def validate(self) -> None:
        require_short("SectionOccupancy", source=self.source)
        for section in self.sections:
            require_short("SectionOccupancy", section_id=section.section_id)
        _require_finite("SectionOccupancy", stamp=self.stamp)
        _require_range("SectionOccupancy", "stamp", self.stamp, -MAX_STAMP, MAX_STAMP)


Measurement = PositionFix | SpeedMeasurement | DistanceIncrement | SectionOccupancy | YawRate | Acceleration
