"""MLX EMF observer: position from the LSM drive's back-EMF (wayside inverter), seed 002.

Principle (seed 002 section 2.2.2, Fig. 3): the Japanese superconducting maglev MLX is
propelled by a ground-primary linear synchronous motor (LSM): the propulsion coils on the
guideway are the armature, the superconducting magnets of the train the field. The "EMF
observer processes the EMF (electromotive force) information measured in the drive
inverter to detect the train's position" and is used in the medium- and high-speed range;
at low speed the train runs on wheels and the wheel rotation sensor serves. The whole MLX
position detection reaches about +-5 deg with a 5 ms update cycle (seed 002 section
2.2.2); the degrees are those of the LSM's electrical angle, the quantity the inverter
needs, and are taken here as the EMF observer's accuracy.

Physics: the magnets, a pole pitch tau apart with alternating polarity, moving at speed v
past the 3-phase propulsion coils induce in phase k (k = 0, 1, 2 for U, V, W)

    e_k = -d psi_k / dt,   psi_k = Psi cos(theta - 2 pi k / 3),   theta = pi x / tau

(x: chainage of the magnets' reference pole from the pole origin), so

    e_k = K_e v sin(theta - 2 pi k / 3),    K_e = Psi pi / tau,

a 3-phase voltage of amplitude K_e |v| and frequency f = v / (2 tau) (one electrical period
per two pole pitches); its space vector turns with the magnets, so its angle is the
position within a pole pair and its rate the speed. The EMF is not measured directly: the
inverter measures the phase voltages and currents at its terminals, and the observer
removes the drop across the coils' resistance R and inductance L,

    e_hat = u - R_hat i - L_hat di/dt,

with R_hat, L_hat the observer's model of the feeding section (errors
``resistance_tolerance``, ``inductance_tolerance``). The inverter drives the current in
phase with the EMF (maximum thrust per ampere): i_k = I sin(theta - 2 pi k / 3) with I
from the thrust (``current_per_accel`` x acceleration plus the running resistance,
``current_cruise`` at 500 km/h growing with v^2). An error of R_hat then only scales the
observed EMF; an error of L_hat adds a quadrature voltage dL omega I, an angle error
dL pi I / (tau K_e) that does not depend on the speed. The measurement noise of the
voltages (``voltage_noise``: the PWM ripple left after filtering) does not grow with the
speed while the EMF does: below some speed the angle is lost in the noise, which is why
the observer serves medium and high speed only (cut-off ``min_speed``).

Pole pitch: seed 002 gives none; the MLX (Yamanashi test line) LSM has a 1.35 m pole pitch
(assumption, literature on the Japanese superconducting maglev), so the electrical period
is 2.7 m, f = 51 Hz at 500 km/h, and +-5 deg are +-37.5 mm.

Raw signal (default 2 kHz, 39 samples per electrical period at 500 km/h; a 5 ms update
is 10 samples): channels ``u``, ``v``, ``w`` [V], the phase voltages at the inverter, and
``i_u``, ``i_v``, ``i_w`` [A], the phase currents. Errors modelled: the observer's R and L
model errors (drawn per device run), a 5th space harmonic of the EMF (``harmonic5``: the
magnets' field is not sinusoidal; in a 3-phase winding the 5th harmonic turns backwards
and makes an angle ripple of +-``harmonic5`` rad six times per electrical period), white
noise of the voltage and current measurements, 16-bit converters over the ranges.

Decoder (the same code for simulated, recorded and ingested blocks): per sample the
observed EMF (the current's derivative by central differences, so a block's last sample is
used with the next block), its Clarke space vector, angle and amplitude; the angle is
unwrapped from block to block. The EMF of forward motion lags the magnets' angle by 90
deg, that of backward motion leads it by 90 deg, so theta = angle + 90 deg x sign(v).
Each block is judged: the angle's rate (a straight line fitted to the unwrapped angle)
gives the speed v = 2 tau f; below ``min_speed``, or with an amplitude that does not match
K_e |v| within ``amplitude_tolerance`` (no train over the section, a wrong section), the
block gives nothing and the angle track is dropped (``stats["below_min_speed"]``,
``stats["amplitude_mismatch"]``); the first good block afterwards starts a new track. A
good block gives one DistanceIncrement from the end of the previous one: distance =
(change of the unwrapped angle) / (2 pi) x 2 tau, the angle at each end taken from a line
fitted to the last ``fit_samples`` samples (5 ms, the seed's update cycle) at the centre of
that window (an increment ends there, a few ms before the block's end); speed from the
line over the whole block. ``pole_position`` holds the last position of the magnets within
the pole pair [m], 0 .. 2 tau from the pole origin, at ``pole_time``. 1-sigma of an end: the seed's +-5 deg
taken as 2.5 sigma (``accuracy_deg``) and the fit's own error; the pole pitch's scale
error on top. Blocks with a sample beyond the converters' ranges, or a zero-sequence
voltage or current (the star point has no neutral: u + v + w = 0 and i_u + i_v + i_w = 0;
a broken measurement otherwise) are rejected ("implausible"), a gap between blocks drops
the angle track.

Not modelled: the feeding sections of the LSM (the inverter is switched from section to
section as the train runs; at a changeover the observer is briefly without current and
EMF: a gap), the inverter's PWM as such (only the residual ripple as noise), the coils'
mutual inductance with the magnets' eddy currents, a fault of the inverter's
measurements other than the zero-sequence check.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurements import DistanceIncrement
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator

SENSOR = "emf_observer"
TWO_PI = 2.0 * math.pi
V_REF = 500.0 / 3.6          # [m/s] the MLX's 500 km/h, reference of the running resistance
PHASES = np.array([0.0, -TWO_PI / 3.0, TWO_PI / 3.0])   # U, V, W
SPEED_RESOLUTION = 1.0e-3    # [m/s] the decoder's floor of a reported 1-sigma (assumption)

PARAMS = {
    "pole_pitch": Param(1.35, "LSM pole pitch tau [m] (assumption: MLX / Yamanashi test line; seed 002 section "
                              "2.2.2 gives none); f = v / (2 tau)", (0.1, 10.0)),
    "magnet_offset": Param(4.0, "distance of the magnets' reference pole (theta = 0 at the pole origin) behind "
                                "the train front [m] (assumption: the leading bogie); within a train of up to "
                                "1 km", (0.0, 1000.0)),
    "pole_origin": Param(0.0, "chainage at which the reference pole has theta = 0 [m] (the propulsion coils' "
                              "phase origin, surveyed)", (-1.0e6, 1.0e6)),
    "emf_constant": Param(20.0, "back-EMF amplitude per speed K_e [V s/m] (assumption: 2.8 kV at 500 km/h)",
                          (0.1, 1000.0)),
    "phase_resistance": Param(0.5, "resistance R of a phase of the fed section with its feeder cable [ohm] "
                                   "(assumption)", (0.0, 100.0)),
    "phase_inductance": Param(0.005, "inductance L of a phase of the fed section [H] (assumption)", (0.0, 1.0)),
    "resistance_tolerance": Param(0.05, "1-sigma relative error of the observer's R (temperature of the coils) "
                                        "[1]; scales the observed EMF only", (0.0, 0.5)),
    "inductance_tolerance": Param(0.02, "1-sigma relative error of the observer's L [1]: an angle error dL pi I "
                                        "/ (tau K_e)", (0.0, 0.5)),
    "current_per_accel": Param(400.0, "thrust current per acceleration [A s^2/m] (assumption; braking by "
                                      "regeneration reverses it)", (0.0, 1.0e4)),
    "current_cruise": Param(300.0, "current for the running resistance at 500 km/h [A], growing with v^2 "
                                   "(assumption: aerodynamic drag)", (0.0, 1.0e4)),
    "harmonic5": Param(0.03, "5th space harmonic of the EMF, fraction of the fundamental [1] (non-sinusoidal "
                             "field of magnets and coils; assumption): an angle ripple of +-1.7 deg",
                       (0.0, 0.3)),
    "harmonic5_phase": Param(20.0, "phase of the 5th harmonic [deg]", (-180.0, 180.0)),
    "voltage_noise": Param(20.0, "1-sigma white noise of each phase voltage measurement [V] (PWM ripple left "
                                 "after filtering; assumption)", (0.0, 1000.0)),
    "current_noise": Param(2.0, "1-sigma white noise of each phase current measurement [A] (assumption)",
                           (0.0, 100.0)),
    "voltage_range": Param(8000.0, "voltage measurement range +- [V]; a sample at or beyond it is implausible",
                           (10.0, 1.0e5)),
    "current_range": Param(3000.0, "current measurement range +- [A]; a sample at or beyond it is implausible",
                           (1.0, 1.0e5)),
    "pitch_scale_sigma": Param(1.0e-4, "1-sigma relative error of the installed mean pole pitch [1] (precast "
                                       "coil panels, concrete 1e-5/K; assumption); reported as the decoder's "
                                       "scale error", (0.0, 0.01)),
    "min_speed": Param(20.0, "decoder: lowest speed at which the observer gives increments [m/s] (72 km/h; "
                             "seed 002 section 2.2.2: medium and high speed only; assumption: the EMF, 400 V "
                             "there, is 20 x the voltage noise)", (0.1, 150.0)),
    "amplitude_tolerance": Param(0.3, "decoder: largest relative deviation of the observed EMF amplitude from "
                                      "K_e times the speed [1]; beyond it the block is not the train's EMF",
                                (0.01, 1.0)),
    "accuracy_deg": Param(5.0, "accuracy of the electrical angle +-[deg] (seed 002 section 2.2.2: +-5 deg, "
                               "5 ms update), taken as 2.5 sigma of one increment end", (0.0, 90.0)),
    "fit_samples": Param(10, "decoder: samples of the line fitted to the angle at an increment end [1] (5 ms at "
                             "2 kHz: the seed's update cycle)", (2, 100000)),
    "zero_sequence_limit": Param(0.05, "decoder: a zero-sequence voltage (u + v + w) / 3 or current "
                                       "(i_u + i_v + i_w) / 3 beyond this fraction of its range is implausible [1]",
                                (0.0, 1.0)),
}

CHANNELS = ("u", "v", "w", "i_u", "i_v", "i_w")


def min_speed_stddev(params: dict) -> float:
    """Smallest 1-sigma [m/s] of an increment's speed and of its mean speed (distance_stddev /
    duration) the decoder reports (ErrorModel.min_stddev): the pole pitch's scale error at the
    lowest speed it reports, ``pitch_scale_sigma`` x ``min_speed``, at least SPEED_RESOLUTION."""
    return max(SPEED_RESOLUTION, params["pitch_scale_sigma"] * params["min_speed"])


def electrical_angle(x: np.ndarray, params: dict) -> np.ndarray:
    """theta = pi (x - pole origin) / tau of the magnets' reference pole at chainages x [rad]."""
    return math.pi * (np.asarray(x, dtype=float) - params["pole_origin"]) / params["pole_pitch"]


def clarke(abc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(alpha, beta) space vector of (n, 3) phase quantities (amplitude-invariant)."""
    a, b, c = abc[:, 0], abc[:, 1], abc[:, 2]
    return (2.0 * a - b - c) / 3.0, (b - c) / math.sqrt(3.0)


class EmfObserverSimulator(Simulator):
    """The inverter's voltage and current measurements of the section under the train."""

    sensor = SENSOR
    channels = CHANNELS
    units = ("V", "V", "V", "A", "A", "A")
    default_sample_rate = 2000.0

    def __init__(self, *args):
        super().__init__(*args)
        p, rng = self.params, self.rng
        # the observer's model of R and L errs; the coils are what they are
        self.r_true = p["phase_resistance"] / max(0.05, 1.0 + rng.normal(0.0, p["resistance_tolerance"]))
        self.l_true = p["phase_inductance"] / max(0.05, 1.0 + rng.normal(0.0, p["inductance_tolerance"]))
        self.adc_lsb = {"V": 2.0 * p["voltage_range"] / 65536, "A": 2.0 * p["current_range"] / 65536}

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        theta = electrical_angle(position - p["magnet_offset"], p)
        omega = math.pi * speed / p["pole_pitch"]
        th = theta[:, None] + PHASES[None, :]
        h5 = p["harmonic5"] * np.sin(5.0 * th + math.radians(p["harmonic5_phase"]))
        emf = p["emf_constant"] * speed[:, None] * (np.sin(th) + h5)
        amp = p["current_per_accel"] * acceleration + p["current_cruise"] * speed * np.abs(speed) / V_REF ** 2
        cur = amp[:, None] * np.sin(th)
        dcur = (amp * omega)[:, None] * np.cos(th)
        volt = emf + self.r_true * cur + self.l_true * dcur
        rng = self.rng
        volt = volt + rng.normal(0.0, p["voltage_noise"], (n, 3))
        cur = cur + rng.normal(0.0, p["current_noise"], (n, 3))
        volt = np.clip(volt, -0.999 * p["voltage_range"], 0.999 * p["voltage_range"])
        cur = np.clip(cur, -0.999 * p["current_range"], 0.999 * p["current_range"])
        return np.column_stack([volt, cur])


class EmfObserverDecoder(Decoder):
    sensor = SENSOR
    channels = CHANNELS

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self.tau = float(p["pole_pitch"])
        self._min_sigma = min_speed_stddev(p)   # [m/s]
        # state carried between blocks (plain numbers and a small array, replaced whole)
        self._t_next: float | None = None     # expected t0 of the next block [s]
        self._prev: np.ndarray | None = None  # last raw sample (u, v, w, i_u, i_v, i_w) of the previous block
        self._prev2_i: np.ndarray | None = None  # the currents of the sample before it
        self._t_prev: float | None = None     # time of that last sample [s]
        self._angle: float | None = None      # unwrapped EMF angle of the last observed sample [rad]
        self._end: tuple | None = None        # end of the last increment: (t [s], unwrapped angle [rad], var)
        self.pole_position = math.nan         # magnets' position within the pole pair [m], 0 .. 2 tau
        self.pole_time = math.nan             # its time [s]: the end of the last increment
        self.stats = {"increments": 0, "below_min_speed": 0, "amplitude_mismatch": 0, "gaps": 0}

    def _check(self, block: RawBlock) -> np.ndarray:
        p = self.params
        if block.channels != self.channels:
            raise InputRejected("channels", f"EMF observer channels {block.channels}, expected {self.channels}")
        data = block.data.astype(float)
        vr, ir = p["voltage_range"], p["current_range"]
        if float(np.abs(data[:, :3]).max()) >= vr or float(np.abs(data[:, 3:]).max()) >= ir:
            raise InputRejected("implausible", f"a phase voltage or current at or beyond the measurement range "
                                               f"(+-{vr:g} V, +-{ir:g} A)")
        lim = p["zero_sequence_limit"]
        if float(np.median(np.abs(data[:, :3].sum(axis=1)))) / 3.0 > lim * vr or \
                float(np.median(np.abs(data[:, 3:].sum(axis=1)))) / 3.0 > lim * ir:
            raise InputRejected("implausible", "zero-sequence voltage or current: the star point has no neutral "
                                               "(a broken phase measurement)")
        return data

    def _drop(self, why: str | None) -> None:
        if why is not None and self._end is not None:
            self.stats[why] += 1
        self._angle = None
        self._end = None

    def decode(self, block: RawBlock):
        p = self.params
        data = self._check(block)              # raises before any state changes
        fs = block.sample_rate
        dt = 1.0 / fs
        n = block.n_samples
        t = block.t0 + self.sample_offsets(n, fs)
        continued = self._t_next is not None and abs(block.t0 - self._t_next) <= 0.5 * dt
        if self._t_next is not None and not continued:
            self.stats["gaps"] += 1
            self._drop(None)
        self._t_next = block.t_end
        # samples whose current derivative is known by central differences: the previous block's last
        # sample (if this block continues it) and this block's samples but the last
        if continued and self._prev is not None:
            raw = np.vstack([self._prev[None, :], data])
            cur_before = self._prev2_i
            ts = np.r_[self._t_prev, t]
        else:
            raw, cur_before, ts = data, None, t
        self._prev, self._prev2_i, self._t_prev = data[-1].copy(), data[-2, 3:].copy() if n > 1 else None, float(t[-1])
        cur = raw[:, 3:]
        if cur_before is not None:
            ext = np.vstack([cur_before[None, :], cur])
            didt = (ext[2:] - ext[:-2]) / (2.0 * dt)        # samples 0 .. m-2 of raw
            use = slice(0, raw.shape[0] - 1)
        else:
            didt = (cur[2:] - cur[:-2]) / (2.0 * dt)        # samples 1 .. m-2 of raw
            use = slice(1, raw.shape[0] - 1)
        volt = raw[use, :3]
        if volt.shape[0] < 2:
            self._drop(None)
            return []
        emf = volt - p["phase_resistance"] * cur[use] - p["phase_inductance"] * didt
        alpha, beta = clarke(emf)
        tt = ts[use]
        amp = np.hypot(alpha, beta)
        ang = np.unwrap(np.arctan2(beta, alpha))
        if self._angle is not None:
            # continue the unwrapped track from the last sample of the previous block
            ang = ang + TWO_PI * round((self._angle - ang[0]) / TWO_PI)
        slope, icpt = np.polyfit(tt - tt[-1], ang, 1)
        res_block = float(np.sqrt(((ang - slope * (tt - tt[-1]) - icpt) ** 2).sum() / max(tt.size - 2, 1)))
        speed = slope * self.tau / math.pi
        mean_amp = float(amp.mean())
        if abs(speed) < p["min_speed"]:
            self._drop("below_min_speed")
            return []
        if abs(mean_amp - p["emf_constant"] * abs(speed)) > p["amplitude_tolerance"] * p["emf_constant"] * abs(speed):
            self._drop("amplitude_mismatch")
            return []
        direction = 1.0 if speed > 0 else -1.0
        t_end, a_end, var_end = self._line_end(tt, ang)
        theta = a_end + 0.5 * math.pi * direction      # the EMF lags the magnets by 90 deg moving forwards
        self.pole_position = float((theta / math.pi * self.tau) % (2.0 * self.tau))
        self.pole_time = t_end
        self._angle = float(ang[-1])
        if self._end is None:
            self._end = (t_end, a_end, var_end)
            return []
        t0, a0, var0 = self._end
        self._end = (t_end, a_end, var_end)
        if not t_end > t0:
            return []
        to_m = self.tau / math.pi
        distance = (a_end - a0) * to_m
        dist_sigma = math.sqrt((var0 + var_end) * to_m ** 2 + (p["pitch_scale_sigma"] * distance) ** 2)
        # speed: the line over the whole block. Its error: the white part from the regression; the
        # angle error that is periodic in position (the 5th harmonic, L error at varying current:
        # six ripples per electrical period), of the accuracy's 1-sigma, tilts the line by at most
        # 12 sigma / (T^2 omega_r) over a block of T s (least-squares slope of a sinusoid)
        sxx = float(((tt - tt.mean()) ** 2).sum())
        span = max(float(tt[-1] - tt[0]), dt)
        omega_r = max(6.0 * abs(slope), TWO_PI / span)
        sigma_acc = math.radians(p["accuracy_deg"]) / 2.5
        slope_var = (res_block ** 2 / sxx if sxx > 0 else math.inf) + (12.0 * sigma_acc / (span * span * omega_r)) ** 2
        speed_sigma = math.sqrt(slope_var * to_m ** 2 + (p["pitch_scale_sigma"] * speed) ** 2)
        self.stats["increments"] += 1
        duration = float(t_end - t0)
        # the floor of the speed and of the mean speed (min_speed_stddev, the error model's min_stddev): at the
        # defaults it binds the distance only over an increment of 10 s or more at a mean speed below min_speed
        return [DistanceIncrement(float(t_end), self.sensor, self.unit_id, duration, float(distance),
                                  float(max(dist_sigma, 1e-6, self._min_sigma * duration)), float(speed),
                                  float(max(speed_sigma, self._min_sigma)))]

    def _line_end(self, tt: np.ndarray, ang: np.ndarray) -> tuple[float, float, float]:
        """(time [s], angle [rad], its variance [rad^2]) of an increment end: a line fitted to the
        last ``fit_samples`` angles, taken at the centre of its window (the mean time and angle,
        where the line is known best); the variance is the accuracy's 1-sigma squared plus the
        line's own error there (its residual / sqrt(samples))."""
        p = self.params
        k = min(int(p["fit_samples"]), tt.size)
        x, y = tt[-k:], ang[-k:]
        fit_var = 0.0
        if k >= 3:
            slope, icpt = np.polyfit(x - x[-1], y, 1)
            fit_var = float(((y - (slope * (x - x[-1]) + icpt)) ** 2).sum()) / (k - 2) / k
        acc = math.radians(p["accuracy_deg"]) / 2.5
        return float(x.mean()), float(y.mean()), acc * acc + fit_var


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """EMF observer errors for the fusion: the installed pole pitch's scale error (reported inside
    the decoder's stddev); contactless, no slip. Silent below ``min_speed`` by design (seed 002
    section 2.2.2: the wheels serve low speed), so no timeout."""
    scale = params["pitch_scale_sigma"]
    return ErrorModel(SENSOR, "distance", scale_sigma=scale, reported_scale=scale,
                      min_stddev=min_speed_stddev(params))   # the decoder's floor of both stddevs


SPEC = SensorSpec(
    node="emf_observer", sensor=SENSOR, simulator=EmfObserverSimulator, decoder=EmfObserverDecoder,
    params=PARAMS, description="MLX EMF observer (wayside inverter): the LSM's back-EMF from the measured phase "
    "voltages and currents; its angle gives the position within a pole pair, its rate the speed: distance "
    "increments and speed above a minimum speed",
    seeds=("002",), outputs=("distance",), error_model=error_model,
)
