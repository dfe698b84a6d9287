"""Longitudinal accelerometer on the carbody: the train's acceleration, independent of adhesion
(docs/nodes.md, "Accelerometer").

Not from the seeds: none of them has an accelerometer. It is the sensor of the odometry of
on-board units in service (wheel sensors, radar and a longitudinal accelerometer, whose speed
carries the train while the wheels slip and the radar drops out) and of the IMU in the trials
of Heirich (J. Sensors 2016) (docs/references.md). The figures below are assumptions of an
industrial-grade MEMS or servo accelerometer, marked as such.

Physics (simulator). The device measures the specific force along its axis, the body's
longitudinal axis, + towards increasing chainage, at ``mount_offset`` behind the train front
(chainage s_m = s - mount_offset):

  f = a (1 + g c) + g sin(atan(i(s_m))) + d (v^2 kappa(s_m)) + b + k a + n

  * a: the train's acceleration; i: the track's gradient (core/gradient.py, the track file's
    ``gradient`` block; level without one): on a rising track a train at rest reads + g sin;
  * c = ``pitch_compliance``: the carbody pitches on its secondary suspension, nose up under
    traction and down under braking, by c a [rad], and tilts gravity into the axis: g c a;
  * d: the yaw misalignment of the mounting (drawn per run, 1-sigma ``misalignment_sigma``
    [rad]): the curve's lateral acceleration v^2 kappa (core/track.py's curvature; no cant)
    leaks into the axis;
  * b: the bias: a turn-on bias drawn per run (``bias_sigma``), an in-run instability as a
    Gauss-Markov process (``bias_instability``, ``bias_tau``), a temperature drift k_T (T -
    ``calibration_temperature``) with k_T drawn per run (1-sigma ``temp_coefficient``) and the
    device warming from ``ambient_temperature`` by ``warmup_rise`` with time constant
    ``warmup_tau``, and injected bias steps (``faults``: a mount worked loose and tilted, a
    shock to the proof mass);
  * k: the scale error drawn per run (``scale_sigma``); n: white noise of ``noise_density``
    (the device's and the body's longitudinal vibration), sigma = noise_density sqrt(rate) per
    sample, as the gyro's;
  * the output saturates at +-``full_range`` and is quantised by an ADC of ``adc_bits`` over
    that range.
Not modelled: cant and transition curves (the track model has neither: the body's pitch on a
cant ramp, half the cant over the ramp's length, about 0.05 % of gradient, is not there), the
body's bounce and the wheel-rail shocks beyond the white noise.

Raw signal: channels ``specific_force`` [m/s^2] and ``temperature`` [degC] (the device's own
sensor, 1/16 K) at ``sample_rate`` (default 100 Hz).

Decoder (the same for simulated, recorded and ingested blocks). It needs the train's position to
take gravity out: ``set_position`` (a TrackPosition: the fusion's state, or the truth in tests;
the node takes it from the TrainState topic ``position_topic``, docs/nodes.md). Per block: the
mean specific force and temperature, stamped at the mean of its sample instants; gravity g sin(atan(i)) at the
mount's chainage, from the latest position moved on by its speed to the block's middle;

  a = (mean f - gravity) / (1 + g c),

1-sigma the root sum of squares of: the white noise of the mean, the bias (turn-on and
instability), the temperature drift at the block's temperature (temp_coefficient |T - T_cal|),
the scale on a, the misalignment on v^2 |kappa|, the gradient data's tolerance
(``gradient_tolerance``) and the gravity's spread over the position's own 1-sigma (the RMS
change of the gravity term over a Gaussian of that 1-sigma, Gauss-Hermite points). With no
position, or one older than ``position_timeout``, gravity is the middle of the track's whole
gradient span and its 1-sigma half that span (a level track loses nothing). Refused, counted: a
block of other channels (``channels``), a sample at full range (``saturated``: a clipped
mean is wrong by an unknown amount), a temperature beyond the device's operating range
(``implausible``), a decoded acceleration beyond any train (``implausible``).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.polynomial.hermite_e import hermegauss

from ..gradient import along_track_gravity
from ..measurements import GRAVITY, MAX_ACCELERATION, Acceleration
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout, gauss_markov
from .doppler import fault_scale, parse_window_faults

SENSOR = "accelerometer"
TEMPERATURE_RANGE = (-40.0, 85.0)   # [degC] operating range of an industrial device: beyond, a broken reading
TEMPERATURE_LSB = 0.0625            # [K] of the device's temperature channel
TEMPERATURE_NOISE = 0.05            # [K] 1-sigma of one temperature sample (assumption)
MIN_STDDEV = 1.0e-4                 # [m/s^2] floor of a reported 1-sigma (10 ug: below any device's bias)
# Gauss-Hermite points and weights of a standard normal (the gravity's spread over a position's 1-sigma)
_NODES, _WEIGHTS = hermegauss(9)
_WEIGHTS = _WEIGHTS / _WEIGHTS.sum()

PARAMS = {
    "noise_density": Param(2.0e-3, "white noise density of the specific force [m/s^2/sqrt(Hz)]: the device's "
                                    "(about 1e-3, 100 ug/sqrt(Hz)) and the carbody's longitudinal vibration "
                                    "(assumption)", (0.0, 1.0)),
    "bias_sigma": Param(0.02, "1-sigma turn-on bias, drawn per run [m/s^2] (assumption: 2 mg, an industrial "
                              "MEMS after its mounting is calibrated)", (0.0, 1.0)),
    "bias_instability": Param(2.0e-3, "1-sigma in-run bias instability, a Gauss-Markov process [m/s^2] "
                                      "(assumption: 200 ug)", (0.0, 1.0)),
    "bias_tau": Param(300.0, "correlation time of the in-run bias [s] (assumption)", (1.0, 1.0e6)),
    "scale_sigma": Param(0.002, "1-sigma scale error, drawn per run [fraction] (assumption: 0.2 %, the device's "
                                "and the residual of pitch_compliance)", (0.0, 0.2)),
    "temp_coefficient": Param(5.0e-4, "1-sigma of the bias's temperature coefficient, drawn per run "
                                      "[m/s^2/K] (assumption: 50 ug/K)", (0.0, 0.1)),
    "calibration_temperature": Param(25.0, "device temperature at which the bias was calibrated [degC]",
                                     (-40.0, 85.0)),
    "ambient_temperature": Param(20.0, "simulator: the device's temperature at the start [degC]", (-40.0, 85.0)),
    "warmup_rise": Param(10.0, "simulator: the device's warming above ambient_temperature once running [K] "
                               "(assumption)", (0.0, 60.0)),
    "warmup_tau": Param(600.0, "simulator: time constant of that warming [s] (assumption)", (1.0, 1.0e5)),
    "pitch_compliance": Param(1.0e-3, "pitch of the carbody on its secondary suspension per unit acceleration "
                                      "[rad/(m/s^2)] (assumption: 0.06 deg at 1 m/s^2; g x this = 1 % of a, "
                                      "which the decoder takes out)", (0.0, 0.01)),
    "misalignment_sigma": Param(5.0e-3, "1-sigma yaw misalignment of the mounting, drawn per run [rad] "
                                        "(assumption: 0.3 deg); couples a curve's lateral acceleration",
                                (0.0, 0.1)),
    "full_range": Param(2.0 * GRAVITY, "full-scale range [m/s^2] (assumption: +-2 g); a sample there is "
                                       "saturated", (1.0, 200.0)),
    "adc_bits": Param(16, "resolution of the output over +-full_range [bits] (assumption)", (8, 32)),
    "mount_offset": Param(5.0, "distance of the device behind the train front [m] (assumption: over the "
                               "leading bogie); gravity is taken at its chainage", (0.0, 1000.0)),
    "gradient_tolerance": Param(0.5, "1-sigma error of the track's gradient data [per mille] (assumption: a "
                                     "surveyed profile); g x this in the reported 1-sigma", (0.0, 50.0)),
    "position_topic": Param("localization/state", "node: TrainState topic whose position (and speed) places "
                                                  "the gradient: the fusion's state, or ground_truth/state"),
    "position_timeout": Param(2.0, "a position older than this is not used: the track's whole gradient span "
                                   "bounds the gravity [s]", (0.01, 3600.0)),
    "bias_correlation_time": Param(20.0, "correlation time the fusion gives the bias state [s]: the gradient "
                                         "data's error changes from one gradient section to the next "
                                         "(assumption: a 600 m section at 30 m/s)", (1.0, 1.0e6)),
    "fault_bias_sigma": Param(0.05, "1-sigma size of a bias step (a mount tilted by 0.3 deg: g x 0.005) "
                                    "[m/s^2]: what the fusion must allow once it suspects one", (0.0, 10.0)),
    "faults": Param("", "injected bias steps 'T0-T1:BIAS[:RAMP]' (bias added from T0 to T1 [s], m/s^2; "
                        "reached over RAMP s from T0, at once without), separated by ';' (tests, campaigns)"),
}


class GravityTerm(NamedTuple):
    """What the decoder takes out of a block: gravity along the track [m/s^2] and its 1-sigma
    [m/s^2], at the device's chainage [m] with the train's speed [m/s] (both NaN: no position)."""

    gravity: float
    sigma: float
    chainage: float
    speed: float


class TrackPosition(NamedTuple):
    """Where the train is, for the gradient: chainage of the train front [m] with 1-sigma [m] and
    speed [m/s], valid at ``stamp`` [s] (a TrainState: the fusion's, or the truth)."""

    stamp: float
    position: float
    position_stddev: float
    speed: float


def parse_faults(text: str) -> list[tuple[float, float, float, float]]:
    """'T0-T1:BIAS[:RAMP]' items -> (t0, t1, bias [m/s^2], ramp [s]); ValueError in one line."""
    return parse_window_faults(text, SENSOR, "BIAS")


def lsb(params: dict) -> float:
    """Resolution of the specific force [m/s^2]: 2 full_range / 2^adc_bits."""
    return 2.0 * params["full_range"] / 2.0 ** params["adc_bits"]


def turn_on_sigma(params: dict) -> float:
    """1-sigma of the bias apart from temperature [m/s^2]: turn-on and in-run instability."""
    return math.hypot(params["bias_sigma"], params["bias_instability"])


def white_sigma(params: dict, n_samples: int, sample_rate: float) -> float:
    """1-sigma [m/s^2] of the mean of n samples at ``sample_rate`` [Hz]: white noise and the
    quantisation (lsb / sqrt(12) per sample)."""
    per_sample = math.hypot(params["noise_density"] * math.sqrt(sample_rate), lsb(params) / math.sqrt(12.0))
    return per_sample / math.sqrt(max(n_samples, 1))


class AccelerometerSimulator(Simulator):
    sensor = SENSOR
    channels = ("specific_force", "temperature")
    units = ("m/s^2", "degC")
    default_sample_rate = 100.0

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        self.adc_lsb = {"m/s^2": lsb(p), "degC": TEMPERATURE_LSB}
        self._bias = self.rng.normal(0.0, p["bias_sigma"])
        self._scale = self.rng.normal(0.0, p["scale_sigma"])
        self._temp_k = self.rng.normal(0.0, p["temp_coefficient"])
        self._misalignment = self.rng.normal(0.0, p["misalignment_sigma"])
        self._instability = self.rng.normal(0.0, p["bias_instability"])
        self._faults = parse_faults(p["faults"])
        self._t_start: float | None = None

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        if self._t_start is None:
            self._t_start = float(times[0])
        dt = 1.0 / self.sample_rate
        instability = (np.full(n, self._instability) if p["bias_instability"] == 0.0 else
                       np.asarray(gauss_markov(self.rng, p["bias_instability"], p["bias_tau"], dt, n,
                                                self._instability)))
        self._instability = float(instability[-1])
        temperature = p["ambient_temperature"] + p["warmup_rise"] * (1.0 - np.exp(-(times - self._t_start)
                                                                                   / p["warmup_tau"]))
        bias = (self._bias + instability + self._temp_k * (temperature - p["calibration_temperature"])
                + fault_scale(self._faults, times))
        s_m = np.asarray(position, dtype=float) - p["mount_offset"]
        v, a = np.asarray(speed, dtype=float), np.asarray(acceleration, dtype=float)
        gravity = along_track_gravity(self.track.grade(s_m), GRAVITY)
        lateral = v * v * self.track.curvature(s_m)
        force = (a * (1.0 + GRAVITY * p["pitch_compliance"]) * (1.0 + self._scale) + gravity
                 + self._misalignment * lateral + bias
                 + self.rng.normal(0.0, p["noise_density"] * math.sqrt(self.sample_rate), n))
        force = np.clip(force, -p["full_range"], p["full_range"])
        temperature = temperature + self.rng.normal(0.0, TEMPERATURE_NOISE, n)
        return np.column_stack([force, temperature])


class AccelerometerDecoder(Decoder):
    sensor = SENSOR
    channels = AccelerometerSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self._position: TrackPosition | None = None
        self._gain = 1.0 + GRAVITY * p["pitch_compliance"]
        self._saturation = p["full_range"] - lsb(p)
        self._data_sigma = GRAVITY * p["gradient_tolerance"] / 1000.0
        lo, hi = self._grade_span()
        g_lo, g_hi = along_track_gravity(np.array([lo, hi]), GRAVITY)
        self._unplaced = (0.5 * (g_lo + g_hi), 0.5 * (g_hi - g_lo))   # gravity, 1-sigma without a position

    def _grade_span(self) -> tuple[float, float]:
        profile = self.track.gradient
        return (0.0, 0.0) if profile is None else profile.span(-math.inf, math.inf)

    def set_position(self, where: TrackPosition) -> None:
        """The train's latest position (its stamp in the blocks' time); one older than the last is
        ignored, a non-finite one is refused (InputRejected ``nan``)."""
        if not all(map(math.isfinite, where)) or where.position_stddev < 0.0:
            raise InputRejected("nan", f"position input {tuple(where)} is not finite with a 1-sigma >= 0")
        if self._position is None or where.stamp >= self._position.stamp:
            self._position = where

    def gravity(self, stamp: float) -> GravityTerm:
        """Gravity along the track at the device's chainage at ``stamp`` [s], from the latest
        position (module docstring)."""
        where = self._position
        if where is None or abs(stamp - where.stamp) > self.params["position_timeout"]:
            gravity, spread = self._unplaced
            return GravityTerm(gravity, math.hypot(spread, self._data_sigma), math.nan, math.nan)
        s_m = where.position + where.speed * (stamp - where.stamp) - self.params["mount_offset"]
        gravity = along_track_gravity(self.track.grade(s_m), GRAVITY)
        spread = 0.0
        if where.position_stddev > 0.0 and self.track.gradient is not None:
            around = along_track_gravity(self.track.grade(s_m + where.position_stddev * _NODES), GRAVITY)
            spread = math.sqrt(float(np.dot(_WEIGHTS, (around - gravity) ** 2)))
        return GravityTerm(gravity, math.hypot(spread, self._data_sigma), s_m, where.speed)

    def decode(self, block: RawBlock):
        if block.channels != self.channels:
            raise InputRejected("channels", f"accelerometer channels {block.channels}, expected {self.channels}")
        p = self.params
        force = block.channel("specific_force").astype(float)
        if np.any(np.abs(force) >= self._saturation):
            raise InputRejected("saturated", f"a specific force of {np.abs(force).max():.2f} m/s^2 is at the "
                                             f"device's full range ({p['full_range']:.2f} m/s^2)")
        temperature = float(np.mean(block.channel("temperature")))
        if not TEMPERATURE_RANGE[0] <= temperature <= TEMPERATURE_RANGE[1]:
            raise InputRejected("implausible", f"device temperature {temperature:.1f} degC is beyond its "
                                               f"operating range {TEMPERATURE_RANGE[0]:g} .. {TEMPERATURE_RANGE[1]:g}")
        t_mid = block.t0 + 0.5 * (block.n_samples - 1) / block.sample_rate   # the mean of the sample instants
        term = self.gravity(t_mid)
        accel = (float(np.mean(force)) - term.gravity) / self._gain
        if not abs(accel) <= MAX_ACCELERATION:
            raise InputRejected("implausible", f"acceleration {accel:.2f} m/s^2 is beyond any train "
                                               f"({MAX_ACCELERATION:g} m/s^2)")
        temp_sigma = p["temp_coefficient"] * abs(temperature - p["calibration_temperature"])
        lateral_sigma = 0.0
        if math.isfinite(term.speed):   # a curve's lateral acceleration through the misalignment
            lateral_sigma = p["misalignment_sigma"] * term.speed ** 2 * abs(float(self.track.curvature(term.chainage)))
        sigma = math.sqrt(white_sigma(p, block.n_samples, block.sample_rate) ** 2 + turn_on_sigma(p) ** 2
                          + temp_sigma ** 2 + (p["scale_sigma"] * accel) ** 2 + lateral_sigma ** 2
                          + term.sigma ** 2)
        self.stats["gravity"] = round(term.gravity, 6)   # [m/s^2] taken out of the last block (diagnostics)
        return [Acceleration(float(t_mid), self.sensor, self.unit_id, float(accel), float(max(sigma, MIN_STDDEV)))]


def min_stddev(params: dict) -> float:
    """Smallest 1-sigma [m/s^2] the decoder reports: the bias (turn-on and instability) and the
    gradient data's tolerance, no less than MIN_STDDEV."""
    return max(math.hypot(turn_on_sigma(params), GRAVITY * params["gradient_tolerance"] / 1000.0), MIN_STDDEV)


def bias_state_sigma(params: dict) -> float:
    """1-sigma [m/s^2] of what the decoder's acceleration carries as a slowly varying bias: the
    turn-on bias and its in-run instability, the temperature drift over the device's span
    (``calibration_temperature`` to ``ambient_temperature`` + ``warmup_rise``) and the gradient
    data's tolerance."""
    span = max(abs(params["ambient_temperature"] - params["calibration_temperature"]),
               abs(params["ambient_temperature"] + params["warmup_rise"] - params["calibration_temperature"]))
    return math.sqrt(turn_on_sigma(params) ** 2 + (params["temp_coefficient"] * span) ** 2
                     + (GRAVITY * params["gradient_tolerance"] / 1000.0) ** 2)


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """An acceleration (measures "acceleration"): the fusion's state carries its bias
    (``bias_state_sigma``, Gauss-Markov with ``bias_correlation_time``: the filter re-learns it
    from the speed sources and the fixes), whose turn-on and gradient parts are taken out of the
    decoder's stddev (``reported_bias``); the temperature drift at the block's temperature, the
    scale error (0.2 % of a), the misalignment on curves and the white noise stay in it. Fault modes: silence (``dropout``) and a bias step (``bias_step``, 1-sigma
    size ``fault_bias_sigma``, in the module's figures: the ErrorModel has no field of an
    acceleration fault's size)."""
    # the decoder reports the temperature drift at the block's own temperature, which may be below
    # the span the state allows: only the turn-on bias and the gradient's tolerance, which it
    # reports in full, come out of R (what is left is never below the white noise)
    reported = math.hypot(turn_on_sigma(params), GRAVITY * params["gradient_tolerance"] / 1000.0)
    return ErrorModel(SENSOR, "acceleration", bias_sigma=bias_state_sigma(params),
                      bias_tau=float(params["bias_correlation_time"]), reported_bias=reported,
                      faults=("dropout", "bias_step"), timeout=continuous_timeout(params),
                      min_stddev=min_stddev(params), sensor_offset=float(params["mount_offset"]))


SPEC = SensorSpec(
    node="accelerometer", sensor=SENSOR, simulator=AccelerometerSimulator, decoder=AccelerometerDecoder,
    params=PARAMS, description="on-board longitudinal accelerometer: the train's acceleration, gravity of the "
                               "gradient taken out", seeds=(), outputs=("acceleration",), error_model=error_model,
)
