"""Typed records of the standard messages a train's drivers publish, and their admission.

Reading uses attribute access only (like core/convert.py): rclpy messages and the objects
rosbags deserialises alike. Each ``*_from_msg`` raises InputRejected with a one-line reason
(core/signals.py) for what no honest driver sends:

  ``nan``          a value or a covariance that is NaN or infinite
  ``implausible``  a latitude beyond +-90 deg, a longitude beyond +-180 deg, an unknown fix
                   status or covariance type
  ``covariance``   a negative variance on the diagonal
  ``missing``      an IMU field its driver marks absent (covariance[0] = -1, REP-145)

Units are REP-103's (m, m/s, rad/s, m/s^2); a stamp is seconds of the driver's clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..convert import stamp_to_sec
from ..signals import InputRejected

# sensor_msgs/NavSatStatus (Jazzy: STATUS_UNKNOWN, its default) and NavSatFix constants
STATUS_UNKNOWN, STATUS_NO_FIX, STATUS_FIX, STATUS_SBAS_FIX, STATUS_GBAS_FIX = -2, -1, 0, 1, 2
COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_APPROXIMATED, COVARIANCE_TYPE_DIAGONAL_KNOWN, COVARIANCE_TYPE_KNOWN = \
    0, 1, 2, 3


@dataclass(frozen=True)
class GnssFix:
    """A receiver's navigation solution (sensor_msgs/NavSatFix): WGS-84 latitude and longitude
    [deg], ``status`` (STATUS_*), the horizontal covariance in east/north [m^2] (``cov_ee``,
    ``cov_en``, ``cov_nn``; meaningless with COVARIANCE_TYPE_UNKNOWN), valid at ``stamp`` [s]."""

    stamp: float
    status: int
    latitude: float
    longitude: float
    cov_ee: float
    cov_en: float
    cov_nn: float
    covariance_type: int

    @property
    def horizontal_sigma(self) -> float | None:
        """1-sigma [m] along the worst horizontal axis (the covariance's larger eigenvalue), None
        when the receiver gives no covariance."""
        if self.covariance_type == COVARIANCE_TYPE_UNKNOWN:
            return None
        mean, half = 0.5 * (self.cov_ee + self.cov_nn), 0.5 * (self.cov_ee - self.cov_nn)
        return math.sqrt(mean + math.hypot(half, self.cov_en))


@dataclass(frozen=True)
class ImuSample:
    """One IMU sample (sensor_msgs/Imu) in the IMU's own frame (REP-145): angular velocity
    [rad/s] and linear acceleration, i.e. specific force, gravity included [m/s^2], with the
    variances of their z and x components [(rad/s)^2, (m/s^2)^2] (0: not given), at ``stamp``
    [s]. A field the driver marks absent is None."""

    stamp: float
    angular_velocity: tuple[float, float, float] | None
    angular_velocity_covariance: tuple[float, ...]
    linear_acceleration: tuple[float, float, float] | None
    linear_acceleration_covariance: tuple[float, ...]


@dataclass(frozen=True)
class BodyTwist:
    """The body's longitudinal speed [m/s] (+ forward along base_link x) with its variance
    [(m/s)^2] (0: not given), at ``stamp`` [s] (nav_msgs/Odometry's twist, or
    geometry_msgs/TwistWithCovarianceStamped)."""

    stamp: float
    speed: float
    speed_variance: float


def _finite(kind: str, **values) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise InputRejected("nan", f"{kind}.{name} is {value!r}")


def _covariance(kind: str, values, size: int) -> tuple[float, ...]:
    cov = tuple(float(v) for v in values)
    if len(cov) != size * size:
        raise InputRejected("implausible", f"{kind} covariance has {len(cov)} entries, not {size * size}")
    if not all(math.isfinite(v) for v in cov):
        raise InputRejected("nan", f"{kind} covariance holds NaN or inf")
    if any(cov[k * (size + 1)] < 0.0 for k in range(size)):
        raise InputRejected("covariance", f"{kind} covariance has a negative variance on its diagonal")
    return cov


def gnss_fix_from_msg(msg) -> GnssFix:
    """A GnssFix of a sensor_msgs/NavSatFix; InputRejected (module docstring)."""
    stamp = stamp_to_sec(msg.header.stamp)
    status = int(msg.status.status)
    lat, lon = float(msg.latitude), float(msg.longitude)
    if status not in (STATUS_UNKNOWN, STATUS_NO_FIX, STATUS_FIX, STATUS_SBAS_FIX, STATUS_GBAS_FIX):
        raise InputRejected("implausible", f"NavSatFix status {status} is none of -2 .. 2")
    kind = int(msg.position_covariance_type)
    if kind not in (COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_APPROXIMATED, COVARIANCE_TYPE_DIAGONAL_KNOWN,
                    COVARIANCE_TYPE_KNOWN):
        raise InputRejected("implausible", f"NavSatFix position_covariance_type {kind} is none of 0..3")
    if status in (STATUS_NO_FIX, STATUS_UNKNOWN):   # no solution we can rate: the coordinates may be NaN
        return GnssFix(stamp, status, math.nan, math.nan, 0.0, 0.0, 0.0, COVARIANCE_TYPE_UNKNOWN)
    _finite("NavSatFix", latitude=lat, longitude=lon)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise InputRejected("implausible", f"NavSatFix at latitude {lat:g}, longitude {lon:g} deg: beyond "
                                           "+-90 / +-180 deg (radians, or no fix)")
    cov = (0.0,) * 9 if kind == COVARIANCE_TYPE_UNKNOWN else _covariance("NavSatFix.position",
                                                                          msg.position_covariance, 3)
    return GnssFix(stamp, status, lat, lon, cov[0], cov[1], cov[4], kind)


def _vector(v) -> tuple[float, float, float]:
    return float(v.x), float(v.y), float(v.z)


def imu_sample_from_msg(msg) -> ImuSample:
    """An ImuSample of a sensor_msgs/Imu; InputRejected (module docstring). A field whose
    covariance[0] is -1 is absent (REP-145): None."""
    stamp = stamp_to_sec(msg.header.stamp)
    out = {}
    for name in ("angular_velocity", "linear_acceleration"):
        raw_cov = tuple(float(c) for c in getattr(msg, f"{name}_covariance"))
        if raw_cov and raw_cov[0] == -1.0:
            out[name], out[f"{name}_covariance"] = None, (0.0,) * 9
            continue
        vec = _vector(getattr(msg, name))
        _finite(f"Imu.{name}", x=vec[0], y=vec[1], z=vec[2])
        out[name], out[f"{name}_covariance"] = vec, _covariance(f"Imu.{name}", raw_cov, 3)
    if out["angular_velocity"] is None and out["linear_acceleration"] is None:
        raise InputRejected("missing", "Imu message marks both angular_velocity and linear_acceleration absent")
    return ImuSample(stamp, **out)


def _twist(stamp: float, twist, kind: str) -> BodyTwist:
    speed = float(twist.twist.linear.x)
    _finite(kind, speed=speed)
    cov = _covariance(f"{kind}.twist", twist.covariance, 6)
    return BodyTwist(stamp, speed, cov[0])


def twist_from_odometry(msg) -> BodyTwist:
    """The BodyTwist of a nav_msgs/Odometry (its twist is in child_frame_id, the body)."""
    return _twist(stamp_to_sec(msg.header.stamp), msg.twist, "Odometry")


def twist_from_twist_stamped(msg) -> BodyTwist:
    """The BodyTwist of a geometry_msgs/TwistWithCovarianceStamped (in header.frame_id, the body)."""
    return _twist(stamp_to_sec(msg.header.stamp), msg.twist, "TwistWithCovarianceStamped")
