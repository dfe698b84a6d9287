"""An IMU's sensor_msgs/Imu as the gyro's yaw rate and the accelerometer's acceleration.

REP-145: a driver reports in the IMU's own frame; ``ImuMount`` (roll, pitch, yaw of that
frame in base_link, fixed-axis x-y-z as URDF's rpy) turns each sample into the body frame
(REP-103: x forward, y left, z up). The samples are gathered into blocks of
``block_duration`` and decoded by the project's own decoders, the same as their raw blocks:

  * yaw rate: the body's z rate -> core/sensors/gyro.py's decoder (the mean of the block, its
    1-sigma the gyro model's white noise and bias bound);
  * acceleration: the specific force along the body's x, signed by ``direction`` (+1: base_link
    x points towards increasing chainage) -> core/sensors/accelerometer.py's decoder (gravity of
    the gradient taken out at the train's position, ``set_position``). sensor_msgs/Imu carries
    no temperature: the block's is ``temperature``, which bounds the drift's share of the 1-sigma.

Each 1-sigma is the decoder's, or the message's own covariance of the mean where that is larger.
A sample stamped at or before the previous one is refused (``out_of_order``); a pause longer
than three blocks drops the partial block (counted ``gaps``).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..measurements import Acceleration, YawRate
from ..signals import InputRejected, RawBlock
from ..sensors.accelerometer import AccelerometerDecoder, TrackPosition
from ..sensors.gyro import GyroDecoder
from .records import ImuSample


@dataclass(frozen=True)
class ImuMount:
    """Orientation of the IMU's frame in base_link: roll, pitch, yaw [rad] (fixed axes x, y, z)."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    def matrix(self) -> np.ndarray:
        """Rotation taking a vector in the IMU frame into base_link."""
        return Rotation.from_euler("xyz", [self.roll, self.pitch, self.yaw]).as_matrix()


class ImuIngest:
    """ImuSample records -> YawRate (``gyro_params`` given) and Acceleration
    (``accelerometer_params`` given) per block (module docstring)."""

    def __init__(self, track, mount: ImuMount, block_duration: float, temperature: float,
                 gyro_params: dict | None, accelerometer_params: dict | None, direction: int = 1):
        if direction not in (-1, 1):
            raise ValueError(f"direction must be +1 or -1, not {direction!r}")
        if not block_duration > 0.0:
            raise ValueError(f"block_duration must be > 0 s, not {block_duration!r}")
        self.gyro = GyroDecoder(gyro_params, track) if gyro_params is not None else None
        self.accelerometer = (AccelerometerDecoder(accelerometer_params, track)
                              if accelerometer_params is not None else None)
        self._rot = mount.matrix()
        self.block_duration = block_duration
        self.temperature = temperature
        self.direction = direction
        self._rows: list[tuple[float, float, float, float, float]] = []   # stamp, rate, var, force, var
        self._last: float | None = None
        self._seq = 0
        self.stats = {"samples": 0, "blocks": 0, "gaps": 0}

    def set_position(self, where: TrackPosition) -> None:
        """The train's position for the accelerometer's gravity (core/sensors/accelerometer.py)."""
        if self.accelerometer is not None:
            self.accelerometer.set_position(where)

    def _body(self, vec, cov) -> tuple[np.ndarray, np.ndarray]:
        v = self._rot @ np.asarray(vec, dtype=float)
        c = self._rot @ np.asarray(cov, dtype=float).reshape(3, 3) @ self._rot.T
        return v, np.diag(c)

    def add(self, s: ImuSample) -> list:
        """Take one sample; the measurements of a block it completes. InputRejected for a sample
        out of order or without the field an output needs (``missing``)."""
        if self._last is not None and not s.stamp > self._last:
            raise InputRejected("out_of_order", f"Imu sample stamped {s.stamp - self._last:+.6f} s after the "
                                                "previous one")
        if self.gyro is not None and s.angular_velocity is None:
            raise InputRejected("missing", "Imu message without angular_velocity: no yaw rate")
        if self.accelerometer is not None and s.linear_acceleration is None:
            raise InputRejected("missing", "Imu message without linear_acceleration: no acceleration")
        if self._last is not None and s.stamp - self._last > 3.0 * self.block_duration:
            if self._rows:
                self.stats["gaps"] += 1
            self._rows = []
        self._last = s.stamp
        rate = rate_var = force = force_var = 0.0
        if self.gyro is not None:
            w, w_var = self._body(s.angular_velocity, s.angular_velocity_covariance)
            rate, rate_var = float(w[2]), float(w_var[2])
        if self.accelerometer is not None:
            a, a_var = self._body(s.linear_acceleration, s.linear_acceleration_covariance)
            force, force_var = self.direction * float(a[0]), float(a_var[0])
        out = []
        if len(self._rows) >= 2 and s.stamp - self._rows[0][0] >= self.block_duration - 1e-9:
            out = self._flush()   # a block spans [t0, t0 + block_duration): this sample starts the next
        self._rows.append((s.stamp, rate, rate_var, force, force_var))
        self.stats["samples"] += 1
        return out

    def _flush(self) -> list:
        rows = np.array(self._rows, dtype=float)
        self._rows = []
        n = rows.shape[0]
        stamps = rows[:, 0]
        sample_rate = (n - 1) / (stamps[-1] - stamps[0])
        self._seq += 1
        self.stats["blocks"] += 1
        out = []
        if self.gyro is not None:
            block = RawBlock(self.gyro.sensor, self.gyro.unit_id, self._seq, float(stamps[0]), sample_rate,
                             self.gyro.channels, ("rad/s",), rows[:, 1:2].astype(np.float32))
            for m in self.gyro.decode(block):
                given = math.sqrt(float(np.mean(rows[:, 2])) / n)
                out.append(dataclasses.replace(m, yaw_rate_stddev=max(m.yaw_rate_stddev, given)))
        if self.accelerometer is not None:
            data = np.column_stack([rows[:, 3], np.full(n, self.temperature)]).astype(np.float32)
            block = RawBlock(self.accelerometer.sensor, self.accelerometer.unit_id, self._seq, float(stamps[0]),
                             sample_rate, self.accelerometer.channels, ("m/s^2", "degC"), data)
            for m in self.accelerometer.decode(block):
                given = math.sqrt(float(np.mean(rows[:, 4])) / n)
                out.append(dataclasses.replace(m, acceleration_stddev=max(m.acceleration_stddev, given)))
        return out
