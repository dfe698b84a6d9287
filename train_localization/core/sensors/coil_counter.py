"""MLX wayside coil counter: counting the guideway's null-flux coils (on-board), seed 002.

Principle (seed 002 section 2.2.2, Fig. 3): the new position detection of the Japanese
superconducting maglev MLX (ground-primary LSM propulsion, EDS levitation) consists of a
wheel rotation sensor, a wayside coil counter, an EMF observer and a mm-wave radio
system. The wayside coil counter "counts the number of the wayside coils (null flux
cable) installed beside the track to detect position and speed"; it is the backup of the
EMF observer when that fails and corrects the error of the wheels. The coils are laid at
a fixed pitch, so the count of coils passed times the pitch is the distance run from a
reference, and the rate at which coils pass is the speed; the count slips neither like a
wheel nor drifts like an integrated speed.

Device (assumption: seed 002 names only the counting): two inductive proximity pickups
on the bogie face the sidewall coil row, head A ``head_offset`` behind the train front
and head B a quarter of the coil pitch behind A. The conductor bundle of each coil
raises a pickup's output while it passes; the field of a coil's conductor at distance
``gap`` falls off like that of a line current, so one coil gives a bump

    e(u) = E0 g0 / gap / (1 + (u / gap)^2)    (u: along-track distance from the coil centre,
                                               g0: the nominal gap)

and the pickup output is the sum of the bumps of the nearby coils, E0 set so that the
nominal peak is ``peak_voltage``. A Schmitt trigger at the level where the output is high
for half a pitch turns each pickup into a square wave of period ``coil_pitch``; as the
heads are a quarter pitch apart the two square waves are in quadrature, like the two
channels of a wheel pulse generator (core/sensors/wheel.py): the order of their edges
gives the direction, four states per coil, one step = pitch / 4.

Coil pitch: seed 002 gives no figure. The MLX LSM pole pitch is 1.35 m (see
core/sensors/emf_observer.py); the coil row of the counter is taken at a third of it,
0.45 m (assumption). The pitch is a property of the guideway's precast coil panels:
its mean over a long stretch errs by the panels' thermal expansion only (concrete
1e-5/K), each coil by its installation tolerance.

Raw signal: channels ``head_a``, ``head_b`` [V], the two pickup outputs, default 4 kHz:
a quadrature state (a quarter pitch, at least 0.18 pitch with the tolerances) lasts one
sample up to 0.18 x 0.45 m x 4 kHz = 324 m/s, beyond the 603 km/h maglev record.
Errors modelled: each coil's position error ``coil_sigma`` (installation), the mean pitch
error ``pitch_scale_sigma`` of the row (drawn per device run: the installed row), per-head
gain mismatch ``gain_sigma`` (moves the Schmitt threshold along the bump: uneven states),
the lateral gap varying around ``gap`` (AR(1), guidance ``gap_sigma`` with ``gap_tau``),
white noise ``noise``, the pickups' detector low-pass ``detector_bandwidth``, coil rows that
end (track equipment below; no coils: no bumps, only noise).

Track equipment (kind ``null_flux_coils``), one entry per coil row::

    null_flux_coils:
      - {id: NF01, position: 0.0, end: 6000.0}             # position = centre of the first coil [m]
      - {id: NF02, position: 6100.0, length: 5900.0, pitch: 0.45}

``position`` is the chainage of the first coil's centre [m], ``end`` or ``length`` the row's
end, ``pitch`` the row's nominal pitch (default: parameter ``coil_pitch``; the decoder uses
the parameter). No entry: one row over the whole track from chainage 0.

Decoder (the same code for simulated, recorded and ingested blocks): Schmitt triggers
around the half-duty level of the nominal geometry (``hysteresis`` [V] wide) -> 2 bits ->
quadrature state -> +-1 step per legal change (wheel.CycleCounter); a change of both bits
at once skipped a state (speed beyond the sample rate, a glitch) and a block with more
than 10 % of them is rejected ("implausible"). Both heads below ``loss_threshold`` = no
coils (end of a row): the count stops and restarts on the next row. One
DistanceIncrement per block (wheel.IncrementEstimator: from a switching point to a
switching point, so the count carries no quantisation error at block boundaries),
distance = steps x pitch / 4, speed from the timing of switching points of the same kind
(whole pitches: the head spacing and duty errors cancel). ``count`` is the signed number
of steps since the start; ``coils_passed`` = count / 4 the coils passed by head A. The
stddevs are those of the coils' installation tolerance, the switching jitter, the states'
unevenness and the pitch's scale error. Blocks whose levels lie beyond the detector's
output range are rejected ("implausible").

Not modelled: the LSM drive's field on the pickups (its frequency, v / 2.7 m, is far below
the pickups' carrier; a real device filters it out), a coil missing from a row (a
miscount of four steps, which the fusion's distance gate sees against the EMF observer),
the counter's own absolute reference (the fusion gets the absolute position from the
mm-wave radio system, seed 002 section 2.2.2: initialisation).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..signals import InputRejected, RawBlock
from ..track import Track, TrackError, extent
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout, first_order_filter, gauss_markov
from .wheel import (QUAD_INDEX, SPEED_STDDEV_FLOOR, CycleCounter, IncrementEstimator, increment_or_reject,
                    restart_after_gap)

KIND = "null_flux_coils"
SENSOR = "coil_counter"
NEIGHBOURS = 4              # coils either side whose bumps are added
NARROWEST_STATE = 0.18      # shortest quadrature state / pitch with the default tolerances

PARAMS = {
    "coil_pitch": Param(0.45, "nominal pitch of the null-flux coils [m] (assumption: a third of the 1.35 m MLX "
                              "pole pitch; seed 002 section 2.2.2 gives no figure); one step = pitch / 4",
                        (0.05, 5.0)),
    "head_offset": Param(3.0, "distance of pickup head A behind the train front [m] (assumption: on the "
                              "leading bogie); head B follows a quarter pitch behind A; within a train of "
                              "up to 1 km", (0.0, 1000.0)),
    "gap": Param(0.1, "nominal lateral distance of the pickups from the coils' conductors [m] (assumption); "
                       "the width of a coil's bump", (0.005, 0.5)),
    "gap_sigma": Param(0.003, "1-sigma variation of that distance [m] (guidance: lateral motion of the "
                              "levitated bogie, assumption)", (0.0, 0.05)),
    "gap_tau": Param(0.5, "correlation time of the gap variation [s]", (1.0e-3, 1.0e6)),
    "peak_voltage": Param(2.0, "pickup output at a coil centre at the nominal gap [V] (amplifier gain set at "
                               "commissioning)", (0.01, 10.0)),
    "noise": Param(0.01, "1-sigma white noise of each pickup output [V] (46 dB below the peak; assumption)",
                   (0.0, 1.0)),
    "gain_sigma": Param(0.02, "1-sigma gain mismatch of each pickup [1] (fraction, drawn per device)", (0.0, 0.5)),
    "detector_bandwidth": Param(5000.0, "-3 dB bandwidth of the pickups' detector low-pass [Hz]: a bump at "
                                        "150 m/s lasts gap / v = 0.4 ms (assumption)", (10.0, 1.0e6)),
    "coil_sigma": Param(0.002, "1-sigma installation error of each coil's centre along the track [m] "
                               "(precast coil panels; assumption)", (0.0, 0.05)),
    "pitch_scale_sigma": Param(2.0e-4, "1-sigma relative error of a coil row's mean pitch [1] (concrete "
                                       "thermal expansion 1e-5/K over +-20 K; assumption); the decoder "
                                       "reports it as its scale error", (0.0, 0.01)),
    "saturation": Param(5.0, "output range of the pickups' detectors [V]; a level beyond it is implausible",
                        (0.1, 10.0)),
    "hysteresis": Param(0.1, "decoder: width of the Schmitt triggers' hysteresis around the half-duty level "
                             "[V] (10 x noise)", (0.0, 5.0)),
    "loss_threshold": Param(0.3, "decoder: both pickups below this = no coils [V]; along a row the higher of the "
                                 "two never falls below 0.78 V at the default geometry", (0.0, 10.0)),
    "max_speed": Param(150.0, "highest speed the configuration must resolve [m/s] (540 km/h: the MLX runs at "
                              "500 km/h); the simulator refuses a sample rate that cannot", (0.0, 170.0)),
    "speed_window": Param(0.1, "decoder: longest time span of the switching points used for the speed [s]",
                          (1.0e-3, 10.0)),
}

DEFAULT_SAMPLE_RATE = 4000.0


def coil_rows(track: Track, default_pitch: float) -> np.ndarray:
    """(start, end, pitch) rows of the null-flux coil rows, sorted; one row over the whole
    track if the track lists none. TrackError for a row that cannot be laid."""
    rows = []
    for item in track.items(KIND):
        start, end = extent(KIND, item, default_end=track.length)
        pitch = float(item.get("pitch", default_pitch))
        if not (end > start and pitch > 0.0):
            raise TrackError(f"{KIND} '{item['id']}': needs end > position and pitch > 0")
        rows.append((start, min(end, track.length), pitch))
    if not rows:
        rows = [(0.0, track.length, default_pitch)]
    rows.sort()
    arr = np.array(rows, dtype=float)
    if np.any(arr[1:, 0] < arr[:-1, 1] - 1e-9):
        raise TrackError(f"{KIND}: coil rows overlap")
    return arr


def row_profile(pitch: float, gap: float, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """(u [m], output / E0) over one pitch of an endless row, u from a coil centre."""
    u = (np.arange(n) / n - 0.5) * pitch
    k = np.arange(-NEIGHBOURS, NEIGHBOURS + 1)
    return u, (1.0 / (1.0 + ((u[:, None] - k[None, :] * pitch) / gap) ** 2)).sum(axis=1)


@functools.lru_cache(maxsize=16)
def levels(pitch: float, gap: float, peak_voltage: float) -> tuple[float, float, float]:
    """(E0 [V], half-duty level [V], valley level [V]) of an endless row at the nominal gap:
    E0 makes the peak ``peak_voltage``; the output is above the half-duty level over half a
    pitch (the Schmitt threshold that gives even quadrature states)."""
    _, prof = row_profile(pitch, gap)
    e0 = peak_voltage / float(prof.max())
    return e0, e0 * float(np.median(prof)), e0 * float(prof.min())


def resolvable_speed(sample_rate: float, pitch: float) -> float:
    """Highest speed [m/s] at which every quadrature state (>= 0.18 pitch) lasts one sample."""
    return sample_rate * NARROWEST_STATE * pitch


def state_unevenness(params: dict) -> float:
    """1-sigma offset [m] of a switching point from the even pitch/4 grid, fixed per head and
    switching direction: the head's gain error moving its threshold crossing along the bump."""
    e0, half, _ = levels(params["coil_pitch"], params["gap"], params["peak_voltage"])
    u, prof = row_profile(params["coil_pitch"], params["gap"])
    slope = float(np.abs(np.gradient(prof * e0, u)[np.argmin(np.abs(prof * e0 - half))]))
    return params["gain_sigma"] * half / slope


class CoilCounterSimulator(Simulator):
    """The two pickups passing the null-flux coil rows of a track."""

    sensor = SENSOR
    channels = ("head_a", "head_b")
    units = ("V", "V")
    default_sample_rate = DEFAULT_SAMPLE_RATE
    adc_lsb = {"V": 5.0 / 4096}   # 12-bit over the detectors' 0..5 V

    def __init__(self, *args):
        super().__init__(*args)
        p, rng = self.params, self.rng
        v_res = resolvable_speed(self.sample_rate, p["coil_pitch"])
        if v_res < p["max_speed"]:
            raise ValueError(f"coil_counter: {self.sample_rate:.0f} Hz resolves the quadrature states of a "
                             f"{p['coil_pitch']} m pitch only up to {v_res:.1f} m/s < max_speed {p['max_speed']} m/s")
        rows = coil_rows(self.track, p["coil_pitch"])
        coils = []
        for start, end, pitch in rows:
            installed = pitch * (1.0 + rng.normal(0.0, p["pitch_scale_sigma"]))   # the row as laid
            n = int(math.floor((end - start) / pitch + 1e-9)) + 1
            coils.append(start + installed * np.arange(n) + rng.normal(0.0, p["coil_sigma"], n))
        self.coils = np.sort(np.concatenate(coils)) if coils else np.empty(0)
        self._e0, _, _ = levels(p["coil_pitch"], p["gap"], p["peak_voltage"])
        self.heads = np.array([p["head_offset"], p["head_offset"] + p["coil_pitch"] / 4.0])
        self.gain = 1.0 + rng.normal(0.0, p["gain_sigma"], 2)
        self._gap_dev = float(rng.normal(0.0, p["gap_sigma"]))
        self._lp_zi = np.zeros((2, 1))

    def output(self, x: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Noise-free output / gain [V] of a pickup at chainages x and gaps [m]."""
        c = self.coils
        if c.size == 0:
            return np.zeros_like(x)
        k = np.searchsorted(c, x)
        out = np.zeros_like(x)
        for o in range(-NEIGHBOURS, NEIGHBOURS):
            j = k + o
            ok = (j >= 0) & (j < c.size)
            u = x - c[np.clip(j, 0, c.size - 1)]
            out += np.where(ok, 1.0 / (1.0 + (u / gap) ** 2), 0.0)
        return self._e0 * self.params["gap"] / gap * out

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        dev = gauss_markov(self.rng, p["gap_sigma"], p["gap_tau"], dt, n, self._gap_dev)
        self._gap_dev = float(dev[-1])
        gap = np.maximum(p["gap"] + dev, 0.2 * p["gap"])
        noise = self.rng.normal(0.0, p["noise"], (n, 2))
        alpha = math.exp(-2.0 * math.pi * p["detector_bandwidth"] * dt)
        out = np.empty((n, 2))
        for h in range(2):
            raw = self.output(position - self.heads[h], gap) * self.gain[h] + noise[:, h]
            out[:, h], self._lp_zi[h] = first_order_filter([1.0 - alpha], [1.0, -alpha], raw, self._lp_zi[h])
        return np.clip(out, 0.0, 0.999 * p["saturation"])


class CoilCounterDecoder(Decoder):
    sensor = SENSOR
    channels = CoilCounterSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        _, half, _ = levels(p["coil_pitch"], p["gap"], p["peak_voltage"])
        self.threshold_on = half + 0.5 * p["hysteresis"]
        self.threshold_off = half - 0.5 * p["hysteresis"]
        if not self.threshold_off > p["loss_threshold"]:
            raise ValueError(f"coil_counter: loss_threshold {p['loss_threshold']} V must lie below the Schmitt "
                             f"triggers' low threshold {self.threshold_off:.3f} V")
        self.step = p["coil_pitch"] / 4.0
        widest = 1.0 - 3.0 * NARROWEST_STATE    # widest quadrature state [pitch]
        self.counter = CycleCounter(4, history=max(1.0, 2 * p["speed_window"]))
        self.estimator = IncrementEstimator(
            self.sensor, self.unit_id, self.counter, self.step, widest * p["coil_pitch"], p["pitch_scale_sigma"],
            p["speed_window"], position_jitter=math.hypot(p["coil_sigma"], 0.5 * p["gap_sigma"]),
            unevenness=state_unevenness(p))
        self._y = np.full(2, -1, dtype=np.int64)   # Schmitt outputs (-1 unknown)
        self._env_last: np.ndarray | None = None   # last outputs of the previous block [V]
        self._t_next: float | None = None
        self.stats = {"steps": 0, "illegal_transitions": 0, "gaps": 0, "no_coil_samples": 0}

    @property
    def count(self) -> int:
        """Signed count of quarter-pitch steps since the start."""
        return self.counter.count

    @property
    def coils_passed(self) -> float:
        """Signed number of coils passed by head A since the start (count / 4)."""
        return self.counter.count / 4.0

    def _schmitt(self, env: np.ndarray) -> np.ndarray:
        """Schmitt trigger outputs (0/1, -1 unknown) per sample and head; keeps the last ones."""
        on = env > self.threshold_on
        off = env < self.threshold_off
        n = env.shape[0]
        rows = np.arange(1, n + 1)[:, None]
        last = np.where(on | off, rows, 0)
        np.maximum.accumulate(last, axis=0, out=last)
        out = np.empty((n + 1, 2), dtype=np.int64)
        out[0] = self._y
        out[1:] = on
        y = out[last, np.arange(2)]
        self._y = y[-1].copy()
        return y

    def _crossing_times(self, times: np.ndarray, env: np.ndarray, y: np.ndarray, y_before: np.ndarray,
                        env_before: np.ndarray, dt: float, k: np.ndarray) -> np.ndarray:
        """At samples ``k`` (where the state changed): the time at which the Schmitt output that
        switched there crossed its threshold, interpolated between the sample and the one before
        (the outputs are analog: ~10 x finer than the sample spacing) [s]; the mean if both
        switched, half a sample before the sample if neither did. ``y_before``, ``env_before``:
        the last outputs of the previous block."""
        prev_env = np.where((k == 0)[:, None], env_before[None, :], env[np.maximum(k - 1, 0)])
        prev_y = np.where((k == 0)[:, None], y_before[None, :], y[np.maximum(k - 1, 0)])
        yk, ek = y[k], env[k]
        switched = (yk != prev_y) & (yk >= 0) & (prev_y >= 0)
        thr = np.where(yk == 1, self.threshold_on, self.threshold_off)
        denom = ek - prev_env
        frac = np.clip(np.divide(thr - prev_env, denom, out=np.full(ek.shape, 0.5), where=denom != 0), 0.0, 1.0)
        t_cross = times[k][:, None] - dt + frac * dt
        n_sw = switched.sum(axis=1)
        mean = np.where(switched, t_cross, 0.0).sum(axis=1) / np.maximum(n_sw, 1)
        return np.where(n_sw > 0, mean, times[k] - 0.5 * dt)

    def decode(self, block: RawBlock):
        p = self.params
        if block.channels != self.channels:
            raise InputRejected("channels", f"coil counter channels {block.channels}, expected {self.channels}")
        env = block.data.astype(float)
        lo, hi = float(env.min()), float(env.max())
        if lo < -0.5 or hi > p["saturation"] + 0.5:
            raise InputRejected("implausible", f"pickup output {lo:.2f}..{hi:.2f} V outside the detectors' "
                                f"0..{p['saturation']} V")
        fs = block.sample_rate
        if restart_after_gap(self, block):
            self._y[:] = -1
            self._env_last = None
        y_before = self._y.copy()
        env_before = self._env_last if self._env_last is not None else env[0]
        y = self._schmitt(env)
        self._env_last = env[-1].copy()
        lost = env.max(axis=1) < p["loss_threshold"]
        known = (y >= 0).all(axis=1)
        state = np.where(known, QUAD_INDEX[np.clip(2 * y[:, 0] + y[:, 1], 0, 3)], -1)
        n_lost = int(np.count_nonzero(lost))
        if n_lost:
            state[lost] = -1
        self.stats["no_coil_samples"] += n_lost
        times = block.t0 + self.sample_offsets(len(env), fs)
        crossing = functools.partial(self._crossing_times, times, env, y, y_before, env_before, 1.0 / fs)
        res = self.counter.feed(times, state, lost if n_lost else None, sample_period=1.0 / fs,
                                crossing_times=crossing)
        self.stats["steps"] += res.transitions
        self.stats["illegal_transitions"] += res.illegal
        return increment_or_reject(self.counter, self.estimator, res, fs, max(2, 0.1 * res.transitions),
                                   "quadrature transitions", "pickup")


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Coil counter errors for the fusion: the coil row's mean pitch error ``pitch_scale_sigma``
    (constant along a row, reported inside the decoder's stddev); contactless, so neither slip
    nor creep (seed 002 section 2.2.2: it corrects the wheels' error)."""
    scale = params["pitch_scale_sigma"]
    return ErrorModel(SENSOR, "distance", scale_sigma=scale, reported_scale=scale,
                      timeout=continuous_timeout(params),
                      min_stddev=SPEED_STDDEV_FLOOR)   # wheel.IncrementEstimator.make's floor of both stddevs


SPEC = SensorSpec(
    node="coil_counter", sensor=SENSOR, simulator=CoilCounterSimulator, decoder=CoilCounterDecoder,
    params=PARAMS, description="MLX wayside coil counter: two pickups count the guideway's null-flux coils "
    "(quadrature, pitch / 4 steps): signed distance increments and speed, no slip",
    seeds=("002",), outputs=("distance",), error_model=error_model,
)
