"""M-Bahn pole-position transmitter: the magnets' pole position in the long stator, seed 000.

Principle (seed 000 section 2.1.3, Fig. 7): the M-Bahn is propelled, like the Transrapid,
by a long-stator linear synchronous motor whose field is the vehicle's permanent magnets.
Its position detection: "the signal of the pole-position transmitter, which announces the
position of the on-board permanent magnets (the pole position), is induced in the wayside
linear motor's stator; the motor control detects this voltage and computes the real speed
and the distance, and controls the inverter's output with them". The inverter must know
where the magnets' poles stand in its winding to drive the current in phase with them,
also at a standstill, where the magnets induce no back-EMF (core/sensors/emf_observer.py:
the EMF is proportional to the speed and vanishes at rest): hence a transmitter.

Physics (the seed gives the principle, Fig. 7 no figures; the numbers are assumptions):
  * the transmitter is a coil on the vehicle, fixed to its magnet poles (``transmitter_offset``
    behind the train front), fed with a carrier ``carrier_frequency`` f_c. The stator's
    three-phase winding U, V, W (k = 0, 1, 2) has the pole pitch tau and its phases are
    2 tau / 3 apart along the track (120 deg electrical); the coil's mutual inductance with
    phase k follows the winding's layout,
        M_k(x) = M0 [cos(theta - 2 pi k / 3) + h5 cos(5 (theta - 2 pi k / 3))],
        theta = pi x / tau                      (x: the coil's chainage from the pole origin),
    with the 5th space harmonic h5 (``harmonic5``) of the meander winding. The carrier
    voltage induced in phase k, u_k = -M_k dI/dt, has the amplitude A = omega_c M0 I and
    does not depend on the speed: the signal is there at a standstill and at any speed, no
    dropout below a minimum speed (the motional term I v dM/dx is (v pi / tau) / omega_c,
    under 1.5 % at 80 km/h, in quadrature: not modelled). The envelope of each phase has
    the period 2 tau (one pole pair) in distance, 2 tau / v in time; the three envelopes
    are the magnets' electrical angle theta, the quantity the inverter needs.
  * the stator also carries the drive's own voltage at f = v / (2 tau); the pickup's
    band-pass leaves ``drive_residual`` of it (assumption), at least 20 % of it at rest
    (the magnetising current);
  * the on-board oscillator is not synchronised to the wayside demodulator: its carrier
    is off by ``oscillator_ppm`` and has an unknown phase.
Pole pitch: seed 000 gives none for the M-Bahn; tau = 0.1 m is assumed (a low-speed
permanent-magnet LSM: f = v / (2 tau) = 111 Hz at 80 km/h, the M-Bahn's top speed). The
stator's lamination packs are stamped to tolerance, so the mean pitch over a long stretch
errs by ``pitch_scale_sigma`` (the stretch as laid, drawn per device run).

Raw signal (default 20 kHz = 4 f_c): channels ``u``, ``v``, ``w`` [V], the stator pickup
voltages of the three phases of the section under the train, 12-bit over +-``voltage_range``.

Decoder (the same code for simulated, recorded and ingested blocks): synchronous
demodulation at the nominal carrier over frames of ``frame_periods`` carrier periods (the
drive's low-frequency voltage averages out) gives a complex amplitude c_k = A a_k e^(j phi)
per phase and frame; the carrier phase phi (unknown, drifting with the oscillator's offset)
is the half angle of sum_k c_k^2 = e^(2 j phi) A^2 sum_k a_k^2 (sum a_k^2 = 3/2 for balanced
phases: never zero), tracked continuously from frame to frame and block to block; the real
envelopes a_k = Re(c_k e^(-j phi)) give by the Clarke transform the angle theta, unwrapped
from frame to frame (a frame must move less than tau: ``max_speed``). The direction is the
phase sequence of the three envelopes (U -> V -> W forwards, the angle grows; backwards it
falls): no quadrature pair is needed. theta is known only up to pi (the sign of the carrier
phase: the pole's polarity), which cancels in every increment. One DistanceIncrement per
block from the end of the previous one: distance = (change of theta) x tau / pi, its ends
the last frame of each block; speed from a line fitted to the block's angles. Below
``min_amplitude`` (no transmitter over the section) the track is dropped
(``stats["no_signal"]``) and starts again on the next block with a signal; a gap between
blocks drops it too. ``pole_position`` holds the last angle as a position within the pole
pair [m] (0 .. 2 tau, up to the polarity). 1-sigma of an end: the 5th harmonic's angle
ripple (h5 rad peak, six ripples per electrical period, taken as h5 / sqrt 2) and the
demodulated noise; the pitch's scale error on top; the angle resolution of the 12-bit
converter (quantisation) is far below the noise. Blocks with a voltage at or beyond the
converter's range or a zero-sequence voltage (the carrier and its harmonics sum to zero in a
balanced winding; a broken pickup otherwise) are rejected ("implausible").

Not modelled: the stator sections and their switching (the pickup follows the section under
the train; a changeover is a gap), the carrier's motional term, interference from a second
vehicle in the same section.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import DistanceIncrement
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout
from .emf_observer import clarke

SENSOR = "pole_position"
CHANNELS = ("u", "v", "w")
PHASES = np.array([0.0, -2.0 * math.pi / 3.0, -4.0 * math.pi / 3.0])   # theta - 2 pi k / 3
TWO_PI = 2.0 * math.pi
SPEED_RESOLUTION = 1.0e-4    # [m/s] the decoder's floor of a reported 1-sigma (assumption)

PARAMS = {
    "pole_pitch": Param(0.1, "pole pitch tau of the long stator and of the vehicle's magnets [m] (assumption: "
                             "seed 000 section 2.1.3 gives none; 111 Hz at 80 km/h)", (0.01, 2.0)),
    "pole_origin": Param(0.0, "chainage of the stator's electrical angle 0 [m]", (-1.0e7, 1.0e7)),
    "transmitter_offset": Param(2.0, "distance of the pole-position transmitter behind the train front [m] "
                                     "(assumption: on the leading magnet frame)", (0.0, 1000.0)),
    "carrier_frequency": Param(5000.0, "carrier of the pole-position transmitter [Hz] (assumption: far above the "
                                       "drive's <= 120 Hz)", (100.0, 1.0e6)),
    "oscillator_ppm": Param(50.0, "offset of the on-board oscillator from the nominal carrier [ppm] "
                                  "(assumption: a crystal oscillator)", (-1000.0, 1000.0)),
    "amplitude": Param(1.0, "carrier amplitude A induced in a phase at full coupling [V] (after the pickup's "
                            "amplifier; assumption)", (1.0e-3, 10.0)),
    "harmonic5": Param(0.02, "5th space harmonic of the winding's coupling, relative to the fundamental [1] "
                             "(an angle ripple of +-h5 rad; assumption)", (0.0, 0.2)),
    "drive_residual": Param(0.5, "drive voltage at v / (2 tau) left after the pickup's band-pass at the top "
                                 "speed [V] (assumption)", (0.0, 10.0)),
    "top_speed": Param(22.2, "speed at which the drive residual is full [m/s] (M-Bahn: 80 km/h)", (0.1, 200.0)),
    "noise": Param(0.02, "1-sigma white noise of each pickup voltage [V] (the inverter's PWM; assumption)",
                   (0.0, 1.0)),
    "voltage_range": Param(2.5, "pickup converter range +- [V]; a sample at or beyond it is implausible",
                           (0.1, 100.0)),
    "pitch_scale_sigma": Param(1.0e-4, "1-sigma relative error of the stator's mean pole pitch [1] (lamination "
                                       "packs stamped to tolerance; assumption); reported as the scale error",
                               (0.0, 0.01)),
    "frame_periods": Param(10, "decoder: carrier periods per demodulation frame [1] (2 ms at 5 kHz)",
                           (1, 100000)),
    "min_amplitude": Param(0.3, "decoder: smallest demodulated amplitude, fraction of ``amplitude``, taken as the "
                                "transmitter's signal [1]", (0.0, 1.0)),
    "max_speed": Param(30.0, "decoder: highest speed [m/s]; a frame must move less than a pole pitch (50 m/s at "
                             "the defaults); the decoder refuses a configuration that cannot", (0.1, 200.0)),
    "zero_sequence_limit": Param(0.05, "decoder: a zero-sequence voltage (u + v + w) / 3 beyond this fraction of "
                                       "the range is implausible [1]", (0.0, 1.0)),
}

DEFAULT_SAMPLE_RATE = 20000.0


def electrical_angle(x, params: dict):
    """theta = pi (x - pole origin) / tau at chainages x [rad]."""
    return math.pi * (np.asarray(x, dtype=float) - params["pole_origin"]) / params["pole_pitch"]


def coupling(theta: np.ndarray, harmonic5: float) -> np.ndarray:
    """(n, 3) relative coupling of the transmitter to phases U, V, W at electrical angles theta."""
    th = np.asarray(theta, dtype=float)[:, None] + PHASES[None, :]
    return np.cos(th) + harmonic5 * np.cos(5.0 * th)


class PolePositionSimulator(Simulator):
    """The stator pickup voltages of the three phases with the transmitter's carrier on them."""

    sensor = SENSOR
    channels = CHANNELS
    units = ("V", "V", "V")
    default_sample_rate = DEFAULT_SAMPLE_RATE

    def __init__(self, *args):
        super().__init__(*args)
        p, rng = self.params, self.rng
        self.adc_lsb = {"V": 2.0 * p["voltage_range"] / 4096}
        self.pitch = p["pole_pitch"] * (1.0 + rng.normal(0.0, p["pitch_scale_sigma"]))   # the stator as laid
        self.carrier = p["carrier_frequency"] * (1.0 + 1.0e-6 * p["oscillator_ppm"])
        self.phase0 = float(rng.uniform(0.0, TWO_PI))

    def samples(self, times, position, speed, acceleration):
        p = self.params
        x = position - p["transmitter_offset"] - p["pole_origin"]
        theta = math.pi * x / self.pitch
        env = p["amplitude"] * coupling(theta, p["harmonic5"])
        carrier = np.cos(TWO_PI * self.carrier * times + self.phase0)
        drive = p["drive_residual"] * np.maximum(0.2, np.abs(speed) / p["top_speed"])
        u = env * carrier[:, None] + drive[:, None] * np.sin(theta[:, None] + PHASES[None, :])
        u = u + self.rng.normal(0.0, p["noise"], u.shape)
        return np.clip(u, -0.999 * p["voltage_range"], 0.999 * p["voltage_range"])


class PolePositionDecoder(Decoder):
    sensor = SENSOR
    channels = CHANNELS
    caches = ("_offsets", "_refs")

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self.tau = float(p["pole_pitch"])
        frame_time = p["frame_periods"] / p["carrier_frequency"]
        if p["max_speed"] * frame_time >= 0.9 * self.tau:
            raise ValueError(f"pole_position: a frame of {frame_time * 1e3:.2f} ms moves "
                             f"{p['max_speed'] * frame_time:.3f} m at max_speed, not under 0.9 pole pitch "
                             f"({self.tau} m): the angle cannot be unwrapped")
        self._refs: dict = {}
        self._t_next: float | None = None
        self._phi2: float | None = None       # unwrapped twice the carrier phase, last frame [rad]
        self._angle: float | None = None      # unwrapped electrical angle, last frame [rad]
        self._end: tuple | None = None        # end of the last increment (t [s], angle [rad])
        self.pole_position = math.nan
        self.pole_time = math.nan
        self.stats = {"increments": 0, "no_signal": 0, "gaps": 0, "frames": 0}

    def _reference(self, n: int, fs: float) -> tuple[np.ndarray, int]:
        """(exp(-j omega_c t) at the sample offsets of the whole frames, samples per frame)."""
        key = (n, fs)
        ref = self._refs.get(key)
        if ref is None:
            per = fs / self.params["carrier_frequency"] * self.params["frame_periods"]
            m = int(round(per))
            if m < 2 or abs(per - m) > 1e-6 * per or m > n:
                raise InputRejected("sample_rate", f"{fs:g} Hz does not give whole frames of "
                                    f"{self.params['frame_periods']} carrier periods within a {n}-sample block")
            if len(self._refs) > 8:
                self._refs.clear()
            k = (n // m) * m
            omega = TWO_PI * self.params["carrier_frequency"]
            ref = np.exp(-1j * omega * self.sample_offsets(k, fs)).astype(np.complex64)
            ref.flags.writeable = False
            self._refs[key] = ref, m
            return ref, m
        return ref

    def _check(self, block: RawBlock) -> np.ndarray:
        p = self.params
        if block.channels != self.channels:
            raise InputRejected("channels", f"pole-position channels {block.channels}, expected {self.channels}")
        data = block.data
        vr = p["voltage_range"]
        if max(float(data.max()), -float(data.min())) >= vr:
            raise InputRejected("implausible", f"a pickup voltage at or beyond the converter range (+-{vr:g} V)")
        if float(np.abs(data.sum(axis=1, dtype=np.float64)).mean()) / 3.0 > p["zero_sequence_limit"] * vr:
            raise InputRejected("implausible", "zero-sequence voltage: the phases do not sum to zero (a broken "
                                               "pickup)")
        return data

    def _drop(self, why: str | None) -> None:
        if why is not None and self._end is not None:
            self.stats[why] += 1
        self._phi2 = None
        self._angle = None
        self._end = None

    def decode(self, block: RawBlock):
        p = self.params
        data = self._check(block)
        fs = block.sample_rate
        n = block.n_samples
        ref, m = self._reference(n, fs)
        continued = self._t_next is not None and abs(block.t0 - self._t_next) <= 0.5 / fs
        if self._t_next is not None and not continued:
            self.stats["gaps"] += 1
            self._drop(None)
        self._t_next = block.t_end
        k = ref.size
        nf = k // m
        rot = np.exp(-1j * TWO_PI * p["carrier_frequency"] * block.t0)
        c = (data[:k] * ref[:, None]).reshape(nf, m, 3).sum(axis=1, dtype=np.complex128) * ((2.0 / m) * rot)
        tt = block.t0 + (np.arange(nf) + 0.5) * (m / fs)
        self.stats["frames"] += nf
        power = (np.abs(c) ** 2).sum(axis=1) / 1.5
        if float(np.sqrt(power.mean())) < p["min_amplitude"] * p["amplitude"]:
            self._drop("no_signal")
            return []
        phi2 = np.unwrap(np.angle((c * c).sum(axis=1)))
        if self._phi2 is not None:
            phi2 = phi2 + TWO_PI * round((self._phi2 - phi2[0]) / TWO_PI)
        a = (c * np.exp(-0.5j * phi2)[:, None]).real
        alpha, beta = clarke(a)
        ang = np.unwrap(np.arctan2(beta, alpha))
        if self._angle is not None:
            ang = ang + TWO_PI * round((self._angle - ang[0]) / TWO_PI)
        self._phi2, self._angle = float(phi2[-1]), float(ang[-1])
        to_m = self.tau / math.pi
        self.pole_position = float((ang[-1] * to_m) % (2.0 * self.tau))
        self.pole_time = float(tt[-1])
        t_end, a_end = float(tt[-1]), float(ang[-1])
        if self._end is None:
            self._end = (t_end, a_end)
            return []
        t0, a0 = self._end
        self._end = (t_end, a_end)
        if not t_end > t0:
            return []
        distance = (a_end - a0) * to_m
        if nf >= 2:
            x = tt - tt.mean()
            sxx = float(x @ x)
            y = ang - ang.mean()
            slope = float(x @ y) / sxx
            r = y - slope * x
            res = math.sqrt(float(r @ r) / max(nf - 2, 1))
        else:
            slope, res, sxx = (a_end - a0) / (t_end - t0), 0.0, (t_end - t0) ** 2
        speed = slope * to_m
        sigma_end = angle_sigma(p, m)
        dist_sigma = math.sqrt(2.0 * (sigma_end * to_m) ** 2 + (p["pitch_scale_sigma"] * distance) ** 2)
        # the harmonic ripple (six per electrical period) tilts the line over a block of T s by at most
        # 12 h5 / (T^2 omega_r) (least-squares slope of a sinusoid)
        span = max(float(tt[-1] - tt[0]), m / fs)
        omega_r = max(6.0 * abs(slope), TWO_PI / span)
        slope_var = (res * res / sxx if sxx > 0 else 0.0) + (12.0 * p["harmonic5"] / (span * span * omega_r)) ** 2
        speed_sigma = math.sqrt(slope_var * to_m ** 2 + (p["pitch_scale_sigma"] * speed) ** 2)
        self.stats["increments"] += 1
        duration = t_end - t0
        floor = min_speed_stddev(p)
        # the floor of the speed and of the mean speed (the error model's min_stddev): at the defaults (0.66 mm
        # of a distance from its end angles) it binds the distance only for increments over 6.6 s
        return [DistanceIncrement(t_end, self.sensor, self.unit_id, duration, float(distance),
                                  float(max(dist_sigma, 1e-5, floor * duration)), float(speed),
                                  float(max(speed_sigma, floor)))]


def min_speed_stddev(params: dict) -> float:
    """Smallest 1-sigma [m/s] of an increment's speed and of its mean speed (distance_stddev /
    duration) the decoder reports (ErrorModel.min_stddev): SPEED_RESOLUTION; the signal is there
    at a standstill, so no speed-dependent term bounds it."""
    return SPEED_RESOLUTION


def angle_sigma(params: dict, frame_samples: int) -> float:
    """1-sigma [rad] of one frame's electrical angle: the 5th harmonic's ripple (h5 rad peak, as
    h5 / sqrt 2) and the noise demodulated over a frame of ``frame_samples`` samples."""
    noise = params["noise"] * math.sqrt(2.0 / frame_samples) / params["amplitude"] / math.sqrt(1.5)
    return math.hypot(params["harmonic5"] / math.sqrt(2.0), noise)


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Pole-position errors for the fusion: the stator's mean pole-pitch error (a constant scale
    error, reported inside the decoder's stddev). Contactless and independent of the speed (the
    carrier's induction needs no motion): no slip, no silence at a standstill, a continuous
    sensor with a timeout."""
    scale = params["pitch_scale_sigma"]
    return ErrorModel(SENSOR, "distance", scale_sigma=scale, reported_scale=scale,
                      timeout=continuous_timeout(params),
                      min_stddev=min_speed_stddev(params))   # the decoder's floor of both stddevs


SPEC = SensorSpec(
    node="pole_position", sensor=SENSOR, simulator=PolePositionSimulator, decoder=PolePositionDecoder,
    params=PARAMS, description="M-Bahn pole-position transmitter: the on-board carrier induced in the long "
    "stator's three phases; the motor control's demodulated envelopes give the magnets' electrical angle: "
    "signed distance increments and speed, also at a standstill",
    seeds=("000",), outputs=("distance",), error_model=error_model,
)
