"""Doppler radar speed sensor (on-board), seeds 000 and 002.

Physics: the radar looks at the guideway at the mounting angle theta; the echo is
shifted by f_d = 2 v f0 cos(theta) / c (Birmingham People Mover speed detection,
000 section 2.2.2; UTM-02 Doppler sensor integrated for distance, 002 section 2.1.2).
An I/Q front end gives the sign of f_d, hence the direction.

Raw signal (one sample per spectrum estimate, default 200 Hz): the Doppler peak
frequency [Hz] and its signal-to-noise ratio [dB]. Errors modelled:
  * spectral spread of the echo (finite beam width): white, ``spread`` x |f_d|;
  * scale error from pitching and reflectivity changes: AR(1) with ``scale_sigma``
    and ``scale_tau``;
  * a constant ``bias`` [m/s] of the device;
  * a mounting-angle error ``mount_angle_error`` [deg] of the installed radar (the
    decoder uses the configured ``mount_angle``): a constant scale error
    cos(theta + e) / cos(theta) - 1, about -tan(theta) e; the error model takes its
    1-sigma ``mount_angle_tolerance`` as a constant scale-error state;
  * injected scale faults (``faults``, tests and campaigns): a scale error added over
    a time window (water film or snow changing the echo, a loosened mount), at once or
    growing linearly over a ramp (a film building up, a mount working loose);
  * dropouts (smooth, wet or snow-covered surface): episodes at ``dropout_rate`` per
    second of ``dropout_duration`` s, SNR below threshold and a random peak;
  * below ``min_speed`` the peak is lost in the low-frequency clutter filter.
Defaults give about 1 % (1-sigma) of speed at 24 GHz per output, the datasheet
figure of 24 GHz ground-speed radars (e.g. Deuta DRS05: +-1 % accuracy).

Decoder: mean of the valid samples of a block -> one SpeedMeasurement per block.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import SpeedMeasurement
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout

C = 299_792_458.0  # speed of light [m/s]
SPEED_RESOLUTION = 0.01   # [m/s] the decoder's floor of a reported 1-sigma (assumption: 1 cm/s, 1.1 Hz of f_d at
                          # the default 24 GHz and 45 deg)

PARAMS = {
    "carrier_frequency": Param(24.125e9, "radar carrier f0 [Hz] (24 GHz ISM band ground-speed radar; microwave "
                                         "radars 1-100 GHz)", (1.0e9, 1.0e11)),
    "mount_angle": Param(45.0, "angle between beam and track [deg]; below 90 (a beam across the track sees no "
                               "Doppler shift)", (0.0, 89.0)),
    "spread": Param(0.02, "1-sigma spectral spread of one peak estimate [fraction of f_d]", (0.0, 1.0)),
    "scale_sigma": Param(0.005, "1-sigma slowly varying scale error (pitch, surface) [fraction]", (0.0, 1.0)),
    "scale_tau": Param(5.0, "correlation time of the scale error [s]", (1.0e-3, 1.0e6)),
    "bias": Param(0.02, "constant speed bias of the device [m/s]", (-1.0, 1.0)),
    "min_speed": Param(0.3, "below this speed no Doppler peak is found [m/s]", (0.0, 10.0)),
    "snr_nominal": Param(25.0, "SNR of a good echo [dB]", (-20.0, 60.0)),
    "snr_threshold": Param(10.0, "samples below this SNR are invalid [dB]", (-20.0, 60.0)),
    "dropout_rate": Param(0.01, "dropout episodes per second [1/s]", (0.0, 100.0)),
    "dropout_duration": Param(0.5, "mean dropout length [s]", (0.0, 3600.0)),
    "mount_angle_tolerance": Param(0.2, "1-sigma uncertainty of the installed beam angle [deg] (installation "
                                        "tolerance); a constant scale error of tan(theta) x this (0.35 % at 45 "
                                        "deg) in the error model", (0.0, 10.0)),
    "mount_angle_error": Param(0.0, "simulator: true deviation of the installed beam angle from mount_angle "
                                    "[deg]", (-10.0, 10.0)),
    "fault_scale_sigma": Param(0.05, "1-sigma size of a scale fault (a shifted mounting, an echo off snow or "
                                     "water) [fraction]; assumption: the beam angle shifted by 3 deg at 45 deg "
                                     "is tan(45 deg) x 3 deg = 5 %; what the fusion lets the scale learn once "
                                     "the fixes and the dead reckoning disagree, and, while the radar is the "
                                     "only speed source, the interval's bound of its undetected fault "
                                     "(3.29 x this x the distance since the last fix)", (0.0, 1.0)),
    "faults": Param("", "injected scale faults 'T0-T1:SCALE[:RAMP]' (scale error added from T0 to T1 [s], "
                        "fraction; reached over RAMP s from T0, at once without), separated by ';' "
                        "(tests, campaigns)"),
}


def parse_window_faults(text: str, sensor: str = "doppler",
                        value: str = "SCALE") -> list[tuple[float, float, float, float]]:
    """'T0-T1:VALUE[:RAMP]' items (an error injected over a time window: a Doppler's scale, an
    accelerometer's bias) -> (t0, t1, value, ramp); ValueError naming ``sensor``."""
    out = []
    for item in filter(None, (s.strip() for s in str(text).split(";"))):
        try:
            window, scale, *ramp = item.split(":")
            t0, t1 = (float(v) for v in window.split("-"))
            if len(ramp) > 1 or (ramp and float(ramp[0]) < 0.0):
                raise ValueError
            out.append((t0, t1, float(scale), float(ramp[0]) if ramp else 0.0))
        except ValueError:
            raise ValueError(f"malformed {sensor} fault {item!r}; expected 'T0-T1:{value}' or "
                             f"'T0-T1:{value}:RAMP' (RAMP >= 0 s)") from None
    return out


_parse_faults = parse_window_faults   # the Doppler's own name (tests and campaigns)


def fault_scale(faults: list, times) -> np.ndarray:
    """The injected scale error [1] at ``times`` [s] of parsed ``faults`` (``_parse_faults``)."""
    times = np.asarray(times, dtype=float)
    out = np.zeros(times.shape)
    for t0, t1, extra, ramp in faults:
        grown = np.clip((times - t0) / ramp, 0.0, 1.0) if ramp > 0.0 else 1.0
        out += np.where((times >= t0) & (times < t1), extra * grown, 0.0)
    return out


def min_speed_stddev(params: dict) -> float:
    """Smallest 1-sigma [m/s] the decoder reports (ErrorModel.min_stddev): its sigma at v = 0,
    the device ``bias``, and no less than SPEED_RESOLUTION."""
    return max(SPEED_RESOLUTION, abs(params["bias"]))


def doppler_shift(speed, f0: float, angle_deg: float):
    """f_d = 2 v f0 cos(theta) / c [Hz] (000 section 2.2.2, 002 section 2.1.2)."""
    return 2.0 * np.asarray(speed) * f0 * math.cos(math.radians(angle_deg)) / C


class DopplerSimulator(Simulator):
    sensor = "doppler"
    channels = ("doppler_shift", "snr")
    units = ("Hz", "dB")
    default_sample_rate = 200.0

    def __init__(self, *args):
        super().__init__(*args)
        self._scale = self.rng.normal(0.0, self.params["scale_sigma"])
        self._dropout_left = 0.0
        theta = math.radians(self.params["mount_angle"])
        # the installed angle differs from the configured one: a constant scale error
        self._mount_scale = math.cos(theta + math.radians(self.params["mount_angle_error"])) / math.cos(theta) - 1.0
        self._faults = _parse_faults(self.params["faults"])

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        # AR(1) scale error, exact discretisation
        phi = math.exp(-dt / p["scale_tau"])
        scale = np.empty(n)
        for i in range(n):
            self._scale = phi * self._scale + math.sqrt(1 - phi * phi) * p["scale_sigma"] * self.rng.normal()
            scale[i] = self._scale
        scale = scale + self._mount_scale
        scale = scale + fault_scale(self._faults, times)
        v_meas = (speed + np.sign(speed) * p["bias"]) * (1.0 + scale)
        fd = doppler_shift(v_meas, p["carrier_frequency"], p["mount_angle"])
        fd = fd + self.rng.normal(0.0, 1.0, n) * p["spread"] * np.abs(fd)
        snr = p["snr_nominal"] + self.rng.normal(0.0, 1.5, n)
        # dropouts
        valid = np.ones(n, dtype=bool)
        for i in range(n):
            if self._dropout_left <= 0 and self.rng.random() < p["dropout_rate"] * dt:
                self._dropout_left = self.rng.exponential(p["dropout_duration"])
            if self._dropout_left > 0:
                valid[i] = False
                self._dropout_left -= dt
        slow = np.abs(speed) < p["min_speed"]
        lost = ~valid | slow
        snr[lost] = self.rng.uniform(0.0, p["snr_threshold"] - 1.0, int(lost.sum()))
        fd[lost] = self.rng.uniform(-50.0, 50.0, int(lost.sum()))
        return np.column_stack([fd, snr])


class DopplerDecoder(Decoder):
    sensor = "doppler"
    channels = DopplerSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self._k = 2.0 * p["carrier_frequency"] * math.cos(math.radians(p["mount_angle"])) / C  # f_d per m/s [Hz s/m]
        self._min_sigma = min_speed_stddev(p)   # [m/s]

    def decode(self, block: RawBlock):
        p = self.params
        fd, snr = block.channel("doppler_shift").astype(float), block.channel("snr").astype(float)
        good = snr >= p["snr_threshold"]
        n_samples = len(good)
        n = int(np.count_nonzero(good))
        self.stats["invalid_samples"] = self.stats.get("invalid_samples", 0) + (n_samples - n)
        if not n:
            return []
        if n == n_samples:      # the usual block: all samples valid
            v = float(np.add.reduce(fd)) / n / self._k   # the mean as np.mean computes it
            i_mean = (n - 1) / 2                    # mean sample index (exact, as np.mean)
        else:
            v = float(np.mean(fd[good])) / self._k
            i_mean = float(np.flatnonzero(good).mean())
        if abs(v) > 200.0:
            raise InputRejected("implausible", f"Doppler speed {v:.1f} m/s is beyond any vehicle")
        sigma = math.sqrt((p["spread"] * v) ** 2 / n + (p["scale_sigma"] * v) ** 2 + p["bias"] ** 2)
        t_mid = block.t0 + (i_mean + 0.5) / block.sample_rate
        return [SpeedMeasurement(float(t_mid), self.sensor, self.unit_id, v, max(sigma, self._min_sigma))]


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Doppler errors for the fusion: the AR(1) scale (``scale_sigma``, ``scale_tau``), a
    constant mounting-angle scale error (tan(theta) x ``mount_angle_tolerance``), the
    device ``bias``; the decoder reports the scale and the bias inside its stddev. Fault
    modes: dropouts, and a scale fault of about ``fault_scale_sigma``. Its echo off a wet or snowy
    track bed fails with the wheels' adhesion there: common cause ``track_surface``."""
    mount = math.tan(math.radians(params["mount_angle"])) * math.radians(params["mount_angle_tolerance"])
    return ErrorModel("doppler", "speed", scale_sigma=params["scale_sigma"], scale_tau=params["scale_tau"],
                      scale_offset_sigma=mount, bias_sigma=abs(params["bias"]),
                      reported_scale=params["scale_sigma"], reported_bias=abs(params["bias"]),
                      faults=("dropout", "scale_fault"), scale_fault_sigma=params["fault_scale_sigma"],
                      common_causes=("track_surface",),
                      timeout=continuous_timeout(params),
                      min_stddev=min_speed_stddev(params))   # the decoder's max(sigma, min_speed_stddev)


SPEC = SensorSpec(
    node="doppler_radar", sensor="doppler", simulator=DopplerSimulator, decoder=DopplerDecoder,
    params=PARAMS, description="on-board Doppler radar: signed speed", seeds=("000", "002"),
    outputs=("speed",), error_model=error_model,
)
