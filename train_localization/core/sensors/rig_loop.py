"""Round experimental unit of seed 003: a widened/narrowed inductive loop on a rotating disc,
three stator antennas, envelope detection, Schmitt triggers, an adder and an F/V converter.

The rig (seed 003 sections 3.1, 4.1): an aluminium disc of 120 cm diameter (the reaction plate
of two LIMs) carries, 3 cm above it, a wooden ring with the inductive loop, widened and narrowed
at equal intervals (Fig. 2) and fed at one end with a 190 kHz sine; the loop (11.14 uH) is tuned
with 0.062 uF in parallel (1 / (2 pi sqrt(LC)) = 191.5 kHz). Three receiving antennas on the
stator, 1/3 of the loop period apart (section 2), see the carrier over the wide parts of the loop
and almost nothing over the narrow parts, where the fields of the two wires cancel. After
amplification and envelope detection, Schmitt triggers make three square waves 120 deg apart;
their sum (the adder) is a square wave of 1/3 of the loop period, 21 cm (section 4.1): counted it
gives the position, through a frequency-to-voltage converter the speed.

Geometry (assumptions where the seed gives no figure): the seed gives the adder period (21 cm,
so the loop period is p = 63 cm) and the speeds 300 rpm = 55 km/h and 500 rpm = 100 km/h, which
put the loop at a radius of 0.49-0.53 m (inside the 0.6 m rim). A closed loop needs a whole
number of periods per revolution: 5 periods (15 adder periods) give a circumference of 3.15 m,
radius 0.501 m (``config/track_rig.yaml``, a closed track: chainage = arc length along the loop
from a reference mark on the disc). The disc's chainage under antenna k is the disc's rotation
minus the antenna's place on the stator, wrapped round the circumference.

Field (seed 003 eq. 1-4): each wide part of the loop is a rectangle 2l x 2b; B_z at an antenna
from the Biot-Savart law for its straight sides (eq. 1, 2), the flux through the antenna (eq. 3:
B_z integrated over its area) and the induced voltage (eq. 4). ``pattern_belt.flux_table``
computes eq. 2-3 for any loop pattern (here the plain, uncrossed loop of seed 003); this module
adds eq. 4: the loop current I0 sin(omega t) and the rotation x(t) give
V = -d/dt [psi(x) I0 sin(omega t)] = -I0 [omega psi cos(omega t) + dpsi/dx dx/dt sin(omega t)];
the second term is the seed's eq. 4 (``motional_voltage``), the first the transformer EMF of the
carrier. The envelope detector sees their quadrature sum (``envelope``); the motional term is
below 3e-4 of the other up to 100 km/h (v / (omega x the ~0.1 m over which the flux rises)).

Decoder: Schmitt triggers with hysteresis; the adder's sum of the three outputs is 1 or 2
(0 and 3 cannot occur: a stuck channel or mis-set thresholds); each change of the sum is one
p/6 step (10.5 cm), its direction given by which antenna switched (the order of the antennas,
section 2: forward or backward). The counting, the switching-point timing and the increment
are the pattern belt's (``PatternBeltDecoder``, seed 003 is one of its seeds): one
DistanceIncrement per block. The F/V converter (section 4.1, Fig. 6 (d)) is emulated as the
analog circuit does it: every rising edge of the adder output (one per 21 cm) puts a fixed
charge into an RC low-pass of time constant ``fv_time_constant``, whose output is proportional
to the adder frequency, i.e. the speed (``stats['fv_speed']``, signed by the direction).
"""
from __future__ import annotations

import math

import numpy as np

from ..signals import RawBlock
from .base import ErrorModel, Param, SensorSpec, Simulator, continuous_timeout, first_order_filter, gauss_markov
from .pattern_belt import (PARAMS as BELT_PARAMS, PatternBeltDecoder, flux_table, geometry, resolvable_speed,
                           table_lookup)
from .wheel import SPEED_STDDEV_FLOOR

ADDER_PERIOD = 0.21          # [m] seed 003 section 4.1: one period of the adder output
SEED_INDUCTANCE = 11.14e-6   # [H] seed 003 section 3.1: equivalent inductance of the loop
SEED_CAPACITANCE = 0.062e-6  # [F] seed 003 section 3.1: parallel capacitor matching the loop
SEED_CARRIER = 190.0e3       # [Hz] seed 003 section 3.1


def _belt(name: str, default, description: str) -> Param:
    """A pattern-belt parameter with the rig's default and description (same limits)."""
    return Param(default, description, BELT_PARAMS[name].limits)


PARAMS = {
    "period": _belt("period", 3 * ADDER_PERIOD, "loop period p [m]: 3 x the adder period of 21 cm (seed 003 "
                    "section 4.1: the adder output, 1/3 of the loop period, repeats every 21 cm)"),
    "wide_fraction": _belt("wide_fraction", 0.5, "fraction of a period where the loop is wide [1] (widened and "
                           "narrowed at equal intervals, seed 003 Fig. 2)"),
    "loop_width": _belt("loop_width", 0.08, "width 2b of the wide parts of the loop [m] (seed 003 eq. 2; "
                        "assumption: the seed gives no figure)"),
    "crossed": _belt("crossed", False, "crossed loop (consecutive wide parts with opposite currents); False: "
                     "the plain widened/narrowed loop of seed 003 Fig. 2"),
    "coil_length": _belt("coil_length", 0.1, "antenna length along the loop [m] (assumption; shorter than the "
                         "21 cm between the antennas)"),
    "coil_width": _belt("coil_width", 0.08, "antenna width across the loop [m] (assumption: the loop width)"),
    "gap": _belt("gap", 0.02, "height of the antennas above the loop [m] (assumption; the loop ring is 3 cm "
                 "above the aluminium disc, seed 003 section 3.1)"),
    "gap_sigma": _belt("gap_sigma", 0.0005, "1-sigma axial run-out of the disc at the antennas [m] "
                       "(assumption)"),
    "gap_tau": _belt("gap_tau", 0.02, "correlation time of the run-out [s] (assumption: of the order of a "
                     "revolution at speed)"),
    "antenna_offset": _belt("antenna_offset", ADDER_PERIOD / 4, "place of antenna 1 on the stator [m]: the loop "
                            "chainage under it is the disc's chainage less this; antennas 2 and 3 follow at p/3 "
                            "and 2p/3 (seed 003 section 2). Default p/12: the disc's chainage 0 (its reference "
                            "mark) lies half-way between two switching points, so that a disc standing there "
                            "does not make a Schmitt trigger chatter (assumption)"),
    "spacing_error": _belt("spacing_error", 0.001, "1-sigma mounting error of each antenna's place [m], per "
                           "device (assumption)"),
    "carrier_frequency": _belt("carrier_frequency", SEED_CARRIER, "loop carrier [Hz] (seed 003 section 3.1: "
                               "190 kHz); it must lie within 5 % of the tuned loop's resonance"),
    "loop_inductance": Param(SEED_INDUCTANCE, "equivalent inductance of the loop [H] (seed 003 section 3.1: "
                             "11.14 uH)", (1.0e-7, 1.0e-3)),
    "tuning_capacitance": Param(SEED_CAPACITANCE, "capacitor in parallel with the loop [F] (seed 003 section "
                                "3.1: 0.062 uF, matched for the largest radiated power)", (1.0e-10, 1.0e-4)),
    "peak_voltage": _belt("peak_voltage", 2.0, "envelope at the peak of the pattern at the nominal gap [V] "
                          "(the HF amplifier brings the antenna signal to a fixed level, seed 003 section 4.1)"),
    "gain_mismatch": _belt("gain_mismatch", 0.03, "1-sigma gain difference between the 3 receive chains [1], "
                           "per device (assumption)"),
    "detector_offset": _belt("detector_offset", 0.01, "1-sigma DC offset of each envelope detector [V], per "
                             "device (assumption)"),
    "noise": _belt("noise", 0.02, "1-sigma receiver noise per quadrature component at the detector [V] "
                   "(assumption: 40 dB SNR at the peak)"),
    "detector_bandwidth": _belt("detector_bandwidth", 1000.0, "-3 dB bandwidth of the envelope detector's RC "
                                "low-pass [Hz] (assumption)"),
    "saturation": _belt("saturation", 5.0, "output swing of the detector [V]"),
    "threshold_on": _belt("threshold_on", 0.94, "Schmitt trigger: output goes high above this [V]; with "
                          "threshold_off centred on 0.89 V = 44.5 % of the peak, where the default geometry "
                          "gives 50 % duty (even p/6 states; assumption: the seed gives no levels)"),
    "threshold_off": _belt("threshold_off", 0.84, "Schmitt trigger: output goes low below this [V] "
                           "(hysteresis 0.1 V = 5 x noise)"),
    "loss_threshold": _belt("loss_threshold", 0.4, "decoder: all three envelopes below this = no carrier [V]"),
    "max_speed": _belt("max_speed", 30.6, "highest speed the configuration must resolve [m/s] (110 km/h: the "
                       "rig's 100 km/h, seed 003 section 5, and margin)"),
    "scale_sigma": _belt("scale_sigma", 1.0e-4, "decoder: 1-sigma relative error of a counted distance [1]: "
                         "the loop closes on itself with whole periods, so the mean period is the "
                         "circumference / 5 exactly; what is left is the laying of single periods "
                         "(assumption: 1 mm in 0.63 m, averaged over the periods run)"),
    "transition_jitter": _belt("transition_jitter", 0.004, "decoder: 1-sigma scatter of a switching point [m] "
                               "(noise / slope, run-out, hysteresis; assumption)"),
    "speed_window": _belt("speed_window", 0.25, "decoder: longest time span of the switching points used for "
                          "the speed [s]"),
    "fv_time_constant": Param(0.1, "F/V converter: time constant of its output low-pass [s] (assumption: "
                              "ripple of one 21 cm pulse below 15 % of the output above 55 km/h)", (1.0e-3, 10.0)),
}

DEFAULT_SAMPLE_RATE = 2000.0
"""3 envelopes at 2 kHz: every p/6 state (10.5 cm) lasts >= 2.5 samples at 100 km/h."""


def resonance_frequency(inductance: float, capacitance: float) -> float:
    """Resonance of the loop and its parallel capacitor, 1 / (2 pi sqrt(L C)) [Hz] (seed 003 Fig. 3)."""
    return 1.0 / (2.0 * math.pi * math.sqrt(inductance * capacitance))


def eq2_bz(x, y, z, l, b, current: float = 1.0):
    """B_z [T] at (x, y, z) of the two long sides (y = -b and y = +b, -l <= x <= l) of a 2l x 2b
    rectangle centred at the origin in the plane z = 0, carrying ``current`` [A] counter-clockwise
    (+x along y = -b): seed 003 eq. 2 as printed, which leaves out the short sides."""
    mu0_4pi = 1.0e-7
    x, y, z = (np.asarray(v, dtype=float) for v in (x, y, z))

    def side(yy):
        r2 = yy * yy + z * z
        return yy / r2 * ((x + l) / np.sqrt((x + l) ** 2 + r2) - (x - l) / np.sqrt((x - l) ** 2 + r2))

    return mu0_4pi * current * (side(y + b) - side(y - b))


def flux_profile(params: dict, gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(position of the antenna centre in a loop period [m], flux per unit loop current [Wb/A]):
    seed 003 eq. 2-3 over one period (pattern_belt.flux_table, the plain loop)."""
    g = geometry(params)
    z = float(params["gap"] if gap is None else gap)
    psi = flux_table(g["period"], g["wide_fraction"], g["loop_width"], g["coil_length"], g["coil_width"],
                     g["crossed"], (z,))[0]
    return np.arange(psi.size) * g["period"] / psi.size, psi


def motional_voltage(params: dict, speed: float, current: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(position [m], V = -dpsi/dx dx/dt [V]) along one loop period at ``speed`` [m/s] for a loop
    current ``current`` [A]: seed 003 eq. 4 (the derivative taken round the periodic profile)."""
    x, psi = flux_profile(params)
    dx = x[1] - x[0]
    dpsi = (np.roll(psi, -1) - np.roll(psi, 1)) / (2.0 * dx)
    return x, -dpsi * speed * current


def envelope(params: dict, speed: float, current: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(position [m], amplitude of the induced carrier voltage [V]) along one period at ``speed``:
    I0 sqrt((omega psi)^2 + (v dpsi/dx)^2), the transformer EMF and eq. 4's motional term in
    quadrature (see the module docstring)."""
    x, psi = flux_profile(params)
    _, v_mot = motional_voltage(params, speed, current)
    omega = 2.0 * math.pi * params["carrier_frequency"]
    return x, np.hypot(omega * psi * current, v_mot)


def half_duty_level(params: dict) -> float:
    """Envelope level [V] above which an antenna is half of the period (nominal gap)."""
    _, env = envelope(params, 0.0)
    return float(np.median(env / env.max())) * params["peak_voltage"]


class RigLoopSimulator(Simulator):
    """The three antennas' envelope-detected levels [V] over the rotating loop."""

    sensor = "rig_loop"
    channels = ("antenna_1", "antenna_2", "antenna_3")
    units = ("V", "V", "V")
    adc_lsb = {"V": 5.0 / 4096}  # 12-bit ADC over 0..5 V
    default_sample_rate = DEFAULT_SAMPLE_RATE

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        period = p["period"]
        f0 = resonance_frequency(p["loop_inductance"], p["tuning_capacitance"])
        if abs(p["carrier_frequency"] / f0 - 1.0) > 0.05:
            raise ValueError(f"rig_loop: carrier {p['carrier_frequency']:.0f} Hz is not within 5 % of the tuned "
                             f"loop's resonance {f0:.0f} Hz (loop_inductance, tuning_capacitance)")
        v_res = resolvable_speed(self.sample_rate, period)
        if v_res < p["max_speed"]:
            raise ValueError(f"rig_loop: {self.sample_rate:.0f} Hz resolves p/6 states of a {period} m loop only "
                             f"up to {v_res:.1f} m/s < max_speed {p['max_speed']} m/s")
        g = geometry(p)
        self._gaps = tuple(float(z) for z in p["gap"] * np.linspace(0.7, 1.3, 7))
        psi = flux_table(g["period"], g["wide_fraction"], g["loop_width"], g["coil_length"], g["coil_width"],
                         g["crossed"], self._gaps)
        nominal = flux_table(g["period"], g["wide_fraction"], g["loop_width"], g["coil_length"], g["coil_width"],
                             g["crossed"], (float(p["gap"]),))
        # the amplifier gain makes the nominal peak of the transformer EMF = peak_voltage
        gain = p["peak_voltage"] / np.abs(nominal).max()
        self._psi = np.concatenate([psi, psi[:, :1]], axis=1) * gain       # wrap column
        dx = period / psi.shape[1]
        self._dpsi = (np.roll(self._psi[:, :-1], -1, axis=1) - np.roll(self._psi[:, :-1], 1, axis=1)) / (2 * dx)
        self._dpsi = np.concatenate([self._dpsi, self._dpsi[:, :1]], axis=1)
        self._omega = 2.0 * math.pi * p["carrier_frequency"]
        self.gain = 1.0 + self.rng.normal(0.0, p["gain_mismatch"], 3)
        self.offset = self.rng.normal(0.0, p["detector_offset"], 3)
        self.antenna_places = (p["antenna_offset"] + np.arange(3) * period / 3.0
                               + self.rng.normal(0.0, p["spacing_error"], 3))
        self._gap_dev = float(self.rng.normal(0.0, p["gap_sigma"]))
        self._lp_zi = np.zeros((3, 1))

    def _lookup(self, table: np.ndarray, x: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """A (gap, position in the period) table at loop coordinates x [m] and gaps [m]."""
        return table_lookup(table, np.mod(x / self.params["period"], 1.0), gap, self._gaps)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        dev = gauss_markov(self.rng, p["gap_sigma"], p["gap_tau"], dt, n, self._gap_dev)
        self._gap_dev = float(dev[-1])
        gap = p["gap"] + dev
        noise = self.rng.normal(0.0, p["noise"], (2, n, 3))
        alpha = math.exp(-2.0 * math.pi * p["detector_bandwidth"] * dt)
        out = np.empty((n, 3))
        for k in range(3):
            # the loop coordinate under antenna k: the disc's chainage less the antenna's place,
            # round the closed loop (the table is periodic in p, the circumference whole periods)
            x = self.track.wrap(position - self.antenna_places[k])
            transformer = self._lookup(self._psi, x, gap)
            motional = self._lookup(self._dpsi, x, gap) * speed / self._omega   # eq. 4 term, in carrier units
            amp = np.hypot(transformer, motional) * self.gain[k]
            env = np.hypot(amp + noise[0, :, k], noise[1, :, k]) + self.offset[k]
            env, self._lp_zi[k] = first_order_filter([1.0 - alpha], [1.0, -alpha], env, self._lp_zi[k])
            out[:, k] = env
        return np.clip(out, 0.0, p["saturation"])


class RigLoopDecoder(PatternBeltDecoder):
    """Schmitt triggers -> adder -> counter (DistanceIncrement per block) and the F/V converter."""

    sensor = "rig_loop"
    channels = RigLoopSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        self.stats.update({"adder_edges": 0, "fv_speed": 0.0})
        self._fv = 0.0                  # F/V output [m/s]
        self._t_fv: float | None = None  # time of that output [s]
        self._adder_last = -1           # adder output at the end of the previous block (-1 unknown)
        self._y_block: np.ndarray | None = None   # Schmitt outputs of the block being decoded

    def _schmitt(self, env: np.ndarray) -> np.ndarray:
        y = super()._schmitt(env)
        self._y_block = y
        return y

    def decode(self, block: RawBlock):
        try:
            out = super().decode(block)
            self._convert_frequency(block, self._y_block)
        finally:
            self._y_block = None
        return out

    def _convert_frequency(self, block: RawBlock, y: np.ndarray) -> None:
        """The adder and the F/V converter over one block. The adder sums the three Schmitt
        outputs: 1 or 2 on the loop (high = 2), a square wave of period p/3. Each of its rising
        edges charges the F/V's output low-pass by p/3 / tau; between edges the output decays
        with tau, so that its mean is (p/3) x the edge rate = the speed. Signed by the counted
        direction (the order in which the antennas switch)."""
        tau = self.params["fv_time_constant"]
        known = (y >= 0).all(axis=1)
        adder = np.where(known, (y.sum(axis=1) == 2).astype(np.int64), -1)
        before = np.concatenate(([self._adder_last], adder[:-1]))
        rising = np.flatnonzero((adder == 1) & (before == 0))
        t_end = block.t0 + (block.n_samples - 1) / block.sample_rate
        t_prev = block.t0 if self._t_fv is None or self._t_fv > t_end else self._t_fv
        charge = (self.params["period"] / 3.0) / tau * (self.counter.direction or 1)
        fv = self._fv * math.exp(-(t_end - t_prev) / tau)
        if rising.size:
            t_edges = block.t0 + rising / block.sample_rate
            fv += charge * float(np.exp(-(t_end - t_edges) / tau).sum())
        self._fv, self._t_fv = fv, t_end
        self._adder_last = int(adder[-1])
        self.stats["adder_edges"] += int(rising.size)
        self.stats["fv_speed"] = fv


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Counting errors for the fusion: the relative error of a counted distance ``scale_sigma``
    (reported inside the decoder's stddev); contactless, so no slip."""
    return ErrorModel("rig_loop", "distance", scale_sigma=params["scale_sigma"],
                      reported_scale=params["scale_sigma"], timeout=continuous_timeout(params),
                      min_stddev=SPEED_STDDEV_FLOOR)   # the belt's wheel.IncrementEstimator.make floor of both stddevs


SPEC = SensorSpec(
    node="rig_loop_receiver", sensor="rig_loop", simulator=RigLoopSimulator, decoder=RigLoopDecoder,
    params=PARAMS, description="seed 003 round experimental unit: loop on a rotating disc, 3 stator antennas, "
    "Schmitt triggers and adder (21 cm): signed distance increments at p/6 and the F/V speed",
    seeds=("003",), outputs=("distance",), error_model=error_model,
)
