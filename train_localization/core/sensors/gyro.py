"""Yaw-rate gyro on the vehicle body: the turn rate that tells a turnout's curve from the
straight way (docs/network.md).

Not from the seeds: none of them has a gyro. It is the sensor the track-selective
localisation of Heirich (J. Sensors 2016, docs/references.md) takes from its IMU: where a
train takes the diverging way of a switch, its body turns at v x kappa (a 1:9 turnout,
R = 190 m, at 10 m/s: 0.053 rad/s) while on the straight way it does not, in a tunnel as in
the open. The numbers below are assumptions of a MEMS rate gyro of navigation grade,
marked as such.

Raw signal: one channel ``rate`` [rad/s], the sensor's output at ``sample_rate`` (default
100 Hz), + turning left (counter-clockwise seen from above). Modelled: the true yaw rate
at the gyro's place (``mount_offset`` behind the train front: the body's heading there is
the alignment's), v x kappa(s - mount_offset); white rate noise of density
``noise_density``; a turn-on bias of 1-sigma ``bias_sigma`` that wanders as a random walk
(``bias_walk``); a scale error of 1-sigma ``scale_sigma``.

Decoder (the same for simulated, recorded and ingested blocks): the mean of a block's
samples, stamped at its middle, 1-sigma the white noise of that mean and the bias bound
``bias_sigma`` together. A block whose rate is beyond any vehicle's turn (``MAX_YAW_RATE``)
is rejected as ``implausible``. The along-track fusion does not use a turn rate (it is
refused ``not_used`` there); on a network the track hypotheses are ranked by it.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import MAX_YAW_RATE, YawRate
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator

SENSOR = "gyro"

PARAMS = {
    "noise_density": Param(2.0e-4, "white rate noise density [rad/s/sqrt(Hz)] (assumption: 0.01 deg/s/sqrt(Hz), "
                                    "a navigation-grade MEMS gyro)", (0.0, 0.1)),
    "bias_sigma": Param(5.0e-4, "1-sigma turn-on bias [rad/s] (assumption: 0.03 deg/s, 100 deg/h)", (0.0, 0.1)),
    "bias_walk": Param(2.0e-5, "random walk of the bias [rad/s/sqrt(s)] (assumption)", (0.0, 0.01)),
    "scale_sigma": Param(0.005, "1-sigma scale error [fraction] (assumption: 0.5 %)", (0.0, 0.2)),
    "mount_offset": Param(5.0, "distance of the gyro behind the train front [m] (assumption: over the leading "
                               "bogie)", (0.0, 1000.0)),
}


def reported_sigma(params: dict, n_samples: int, sample_rate: float) -> float:
    """1-sigma [rad/s] of a block's mean: the white noise of n samples at ``sample_rate`` and
    the bias bound, never below 1e-6 rad/s."""
    white = params["noise_density"] * math.sqrt(sample_rate) / math.sqrt(max(n_samples, 1))
    return max(math.hypot(white, params["bias_sigma"]), 1.0e-6)


class GyroSimulator(Simulator):
    sensor = SENSOR
    channels = ("rate",)
    units = ("rad/s",)
    default_sample_rate = 100.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self._bias = self.rng.normal(0.0, p["bias_sigma"])
        self._scale = self.rng.normal(0.0, p["scale_sigma"])

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        walk = self.rng.normal(0.0, p["bias_walk"] * math.sqrt(dt), n)
        bias = self._bias + np.cumsum(walk)
        self._bias = float(bias[-1]) if n else self._bias
        kappa = self.track.curvature(np.asarray(position, dtype=float) - p["mount_offset"])
        rate = np.asarray(speed, dtype=float) * kappa * (1.0 + self._scale) + bias
        rate = rate + self.rng.normal(0.0, p["noise_density"] * math.sqrt(self.sample_rate), n)
        return rate[:, None]


class GyroDecoder(Decoder):
    sensor = SENSOR
    channels = GyroSimulator.channels

    def decode(self, block: RawBlock):
        if block.channels != self.channels:
            raise InputRejected("channels", f"gyro channels {block.channels}, expected {self.channels}")
        rate = block.channel("rate").astype(float)
        mean = float(np.mean(rate))
        if not abs(mean) <= MAX_YAW_RATE:
            raise InputRejected("implausible", f"yaw rate {mean:.3f} rad/s is beyond any vehicle's turn "
                                               f"({MAX_YAW_RATE} rad/s)")
        t_mid = block.t0 + 0.5 * block.n_samples / block.sample_rate
        sigma = reported_sigma(self.params, block.n_samples, block.sample_rate)
        return [YawRate(float(t_mid), self.sensor, self.unit_id, mean, sigma)]


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """A turn rate for the track selection (core/network/hypotheses.py): the decoder's stddev
    holds the white noise and the bias bound; the scale error (a fraction of the turn) is
    ``scale_sigma``. No along-track states; no timeout (a network's hypotheses do without it)."""
    return ErrorModel(SENSOR, "yaw_rate", faults=(), min_stddev=reported_sigma(params, 10 ** 6, 1.0),
                      sensor_offset=float(params["mount_offset"]), reported_scale=float(params["scale_sigma"]))


SPEC = SensorSpec(
    node="gyro", sensor=SENSOR, simulator=GyroSimulator, decoder=GyroDecoder, params=PARAMS,
    description="on-board yaw-rate gyro: the body's turn rate (track selection on a network)",
    seeds=(), outputs=("yaw_rate",), error_model=error_model,
)
