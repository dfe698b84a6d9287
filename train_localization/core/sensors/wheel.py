"""Wheel rotation sensor: two-channel pulse generator on an axle (on-board), seed 002.

The MLX position detection uses a "wheel rotation sensor" that counts the
revolutions of the running wheels for position and speed at low speed (seed 002
section 2.2.2); on conventional railways the same device (an axle-box pulse
generator) is the primary odometer. This module models it up to conventional-rail
speeds (``max_speed`` 300 km/h by default), not beyond: a maglev runs on wheels only
at low speed. Above ``retract_speed`` the wheels are retracted (an EDS maglev lifts off:
seed 002 section 2.2.2) and the sensor sends nothing; the first block after the wheels
are down again restarts the decoder's count (a gap).

Physics (raw signal): a toothed/slotted disc on the axle with
``pulses_per_revolution`` pulses gives two square-wave channels A and B, 90 deg apart
(quadrature), levels 0/1, sampled at ``sample_rate``. B lags A when the wheel turns
forwards (chainage increasing), so the order of the edges gives the direction.
Errors modelled:
  * wheel diameter: the true diameter differs from the nominal one by a wear error
    (``diameter_error``; by default drawn per device uniformly within
    +-``diameter_tolerance``): a scale error of the distance;
  * creep: under traction or braking the wheel's circumferential speed differs from
    the train speed by ``creep_coefficient`` x a (wheel-rail creep);
  * slip (traction) and slide (braking) episodes of several seconds with slip ratios
    of a few % up to 20 %: random while |a| >= ``slip_accel_threshold`` at
    ``slip_rate`` per second, or forced by a scenario through ``slip_episodes``;
    a positive slip ratio means the wheel turns faster than the train moves;
  * manufacturing tolerance of the disc/sensor: A/B phase deviation from 90 deg
    (``phase_tolerance``) and duty-cycle deviation (``duty_tolerance``), drawn per
    device: unevenly spaced edges;
  * longitudinal/torsional vibration of the wheel (``vibration``): edge chatter at
    standstill, which quadrature decoding cancels;
  * EMI glitches: a single-sample flip of one channel (``glitch_rate``).

Decoder (vectorised): state sequence 00 -> 10 -> 11 -> 01 forwards; each legal
state change counts +-1 edge, a change of both levels at once is illegal (a skipped
state: speed beyond what the sample rate resolves, or a glitch); it is counted as 2
edges in the last direction (which keeps the count right up to ~120 m/s with the
defaults) and a block with more than 10 % illegal changes is rejected
("implausible"). Counts -> distance
with the NOMINAL diameter: one edge = pi D / (4 ppr). One DistanceIncrement per block
(from the last sample of the previous block to the last sample of this one), speed
from the timing of edges of the same kind (one full pulse period or more apart, so
disc tolerances cancel) within the block or ``speed_window``; at low speed from any
two edges in the same direction; else from the count. A lost block (gap in time)
restarts the count at the next block. The stddevs are
those of quantisation, edge timing and diameter tolerance; the decoder does NOT
know about slip: the fusion has to detect it (speed excess over other sensors).
Note: quantisation errors of consecutive increments are anti-correlated (the total
count is exact to one edge); the diameter error is common to all increments.

``CycleCounter`` and ``IncrementEstimator`` below are shared with the pattern belt
(6 states instead of 4).
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from ..measurements import MAX_SPEED, DistanceIncrement
from ..signals import InputRejected, RawBlock
from .base import Decoder, ErrorModel, Param, SensorSpec, Simulator, continuous_timeout, first_order_filter

PARAMS = {
    "pulses_per_revolution": Param(
        60, "pulses per wheel revolution per channel [1]; rail speed sensors give 60-300 "
        "(Wikipedia 'Wheel speed sensor'); 4 edges per pulse are counted (one edge = pi D / 240 "
        "= 12 mm at D = 0.92 m)", (1, 1000)),
    "wheel_diameter": Param(
        0.92, "NOMINAL wheel diameter configured in the on-board unit [m]; must equal "
        "vehicle.wheel_diameter of the scenario (the simulator checks it; the decoder has no "
        "access to the vehicle)", (0.1, 2.0)),
    "max_speed": Param(
        83.4, "highest speed the configuration must resolve [m/s] (300 km/h, conventional rail; "
        "a maglev uses wheels only at low speed, seed 002 2.2.2). The simulator refuses a "
        "sample rate at which the narrowest quadrature state (tolerances included) would last "
        "less than one sample at this speed with a wheel at the lower diameter tolerance; at most "
        "the wheel-rail speed record, 574.8 km/h", (0.0, 160.0)),
    "phase_tolerance": Param(
        15.0, "max deviation of the A-B phase from 90 deg [deg], drawn per device uniformly "
        "(typical two-channel rail speed-sensor datasheet figure); below 90 (A and B would coincide)",
        (0.0, 90.0)),
    "duty_tolerance": Param(
        0.03, "max deviation of each channel's duty cycle from 0.5 [fraction of a pulse], drawn "
        "per device uniformly (typical datasheet figure)", (0.0, 0.5)),
    "diameter_tolerance": Param(
        0.01, "max |true/nominal - 1| of the wheel diameter [fraction]: wear between two "
        "re-calibrations (wheel wear up to 1 %, task statement); the decoder uses "
        "tolerance/sqrt(3) as 1-sigma scale error; a wheel worn from new to scrap loses < 10 %",
        (0.0, 0.1)),
    "diameter_error": Param(
        float("nan"), "true/nominal - 1 of this wheel [fraction]; NaN (default) = drawn per device "
        "uniformly within +-diameter_tolerance", (-0.1, 0.1)),
    "retract_speed": Param(
        float("nan"), "speed at and above which the running wheels are retracted and the sensor sends no "
        "block [m/s]; NaN (default) = the vehicle's: 41.7 m/s (150 km/h) for a maglev, never for others; "
        "0 = never. Seed 002 section 2.2.2: the MLX (EDS) runs on wheels because it lifts off only above "
        "some speed, and the wheel sensor serves the low-speed stretch, the EMF observer the medium and high "
        "speeds (its min_speed 72 km/h); the seed gives no figure, 150 km/h is the lift-off speed "
        "published for the SCMaglev (assumption)", (0.0, 160.0)),
    "wear_fault_sigma": Param(
        0.03, "1-sigma size of a diameter error beyond diameter_tolerance (fault mode 'wear': a missed "
        "re-calibration, a re-profiled or changed wheel whose diameter was not re-entered) [fraction]; "
        "3.29 x 0.03 = 10 %, a wheel from new to scrap; the fusion's bound of that fault while the wheel "
        "carries the speed alone, and the size its scale may learn", (0.0, 0.2)),
    "creep_coefficient": Param(
        0.002, "steady creep per unit acceleration [s^2/m]: wheel speed = v (1 + c a sign v); "
        "0.2 % at 1 m/s^2 (creep of a few 0.1 % at adhesion use 0.1, Kalker/Polach creep curves)",
        (0.0, 0.1)),
    "driven_axle": Param(
        True, "the sensor sits on a motored axle: traction slip and creep occur; False = trailer "
        "axle: only braking creep and slides"),
    "slip_rate": Param(
        0.02, "random slip/slide episodes per second while |a| >= slip_accel_threshold [1/s] "
        "(poor adhesion: about one episode per 50 s of hard traction or braking)", (0.0, 100.0)),
    "slip_accel_threshold": Param(0.6, "|acceleration| above which random episodes can start [m/s^2]",
                                  (0.0, 5.0)),
    "slip_ratio_min": Param(0.02, "smallest |slip ratio| of a random episode [fraction]", (0.0, 1.0)),
    "slip_ratio_max": Param(0.20, "largest |slip ratio| of a random episode [fraction] (wheel-slide "
                                  "protection keeps slides below ~20 %); the fusion's bound of a slip that "
                                  "no other speed source sees", (0.0, 1.0)),
    "slip_duration": Param(2.0, "mean length of a random episode [s] (exponential, 0.5 s .. "
                                "slip_duration_max)", (0.0, 60.0)),
    "slip_duration_max": Param(10.0, "longest slip or slide episode [s]: anti-slip control and wheel-slide "
                                     "protection restore adhesion within it (UIC 541-05 slide cycles last "
                                     "seconds); the fusion takes a longer disagreement for another "
                                     "sensor's fault", (0.5, 600.0)),
    "slip_episodes": Param(
        [], "forced episodes, flat list t_start [s], duration [s], slip_ratio, t_start, ... (nested "
        "triples are accepted too); slip_ratio > 0: wheel faster than the train (traction slip), "
        "< 0: slower (braking slide)"),
    "vibration": Param(0.0003, "1-sigma longitudinal/torsional vibration of the wheel, as "
                               "circumferential displacement [m]", (0.0, 0.01)),
    "vibration_tau": Param(0.02, "correlation time of the vibration [s]", (1.0e-4, 10.0)),
    "glitch_rate": Param(0.01, "EMI glitches per second: one channel flipped for one sample [1/s]", (0.0, 100.0)),
    "speed_window": Param(0.1, "decoder: longest time span of the edges used for the speed [s]", (1.0e-3, 10.0)),
}

MAGLEV_RETRACT_SPEED = 150.0 / 3.6
"""[m/s] a maglev's wheels are up from this speed (``retract_speed`` NaN: the vehicle's)."""


def retract_speed(params: dict, vehicle) -> float:
    """Speed [m/s] at and above which the wheels are retracted; inf if never (module doc)."""
    v = float(params["retract_speed"])
    if math.isnan(v):
        v = MAGLEV_RETRACT_SPEED if getattr(vehicle, "kind", "") == "maglev" else 0.0
    return v if v > 0.0 else math.inf


DEFAULT_SAMPLE_RATE = 10_000.0
"""A, B sampled at 10 kHz (2 x 10 k samples/s). With 60 ppr, +-15 deg phase and +-3 % duty
tolerance the narrowest state is 0.178 pulse, which lasts 100 us = one sample at 85 m/s
(306 km/h) with a wheel 1 % under the nominal 0.92 m: quadrature edges are resolved up to
``max_speed`` = 300 km/h."""

# CycleCounter: look-up value of a state change that is neither none nor a legal step;
# large, so that one of them shows in the sum of the values of a block's changes
_OTHER = 1 << 40

# (A, B) -> position in the forward sequence 00 -> 10 -> 11 -> 01; code = 2A + B
QUAD_INDEX = np.array([0, 3, 1, 2], dtype=np.int64)
_CODE_WEIGHTS = np.array([2.0, 1.0], dtype=np.float32)  # (A, B) levels -> code


# --------------------------------------------------------------------------- decoding core
SPEED_STDDEV_FLOOR = 1.0e-3
"""Smallest 1-sigma [m/s] an IncrementEstimator reports for an increment's speed and for its
mean speed (distance_stddev / duration): the counting sensors' ErrorModel.min_stddev (wheel,
pattern belt, coil counter, rig loop). 1 mm/s, the decoders' speed resolution (assumption): a
standing train's bound, the widest state / (sqrt(3) x the time since the last transition),
reaches it after about 9 s on the wheel. The distance of a long increment (blocks of
seconds) between two edges, known to millimetres, would otherwise claim a finer mean speed."""


@dataclass
class FeedResult:
    steps: int            # signed steps of the last gap-free segment of the block
    t_start: float | None  # time of the reference sample of that segment [s]
    t_end: float | None    # time of its last valid sample [s]
    illegal: int          # skipped-state transitions in the block
    transitions: int      # state changes in the block
    dropped_steps: int    # steps of earlier segments (before a loss of signal)
    continued: bool = False  # the segment starts at the last state of the previous block
    after_loss: bool = False  # the segment is the first valid one after a loss of signal


class CycleCounter:
    """Counts steps through a cyclic sequence of ``n`` states (quadrature: 4, belt: 6).

    Shared by the wheel sensor and the pattern belt. ``feed`` takes state indices
    (0..n-1; -1 = no valid state, held) and a loss mask (no counting across lost
    samples); it keeps the last state between blocks. A change by more than one state
    is illegal (a skipped state); it is counted as the shortest way round, or, for a
    change by n/2, in the last known direction.

    Speed: a block has hundreds of samples but far fewer state changes, so ``feed``
    works on the changes only, with a fast path for the usual block (only legal
    steps, no loss of signal). The transition history is kept in plain lists
    (extended per block, searched with bisect) together with the start of the last
    run of transitions in one direction, which ``transition_speed`` needs.
    """

    def __init__(self, n_states: int, history: float = 1.0):
        self.n = n_states
        self.history = history
        self.state = -1
        self.t_state: float | None = None
        self.direction = 0
        self.count = 0
        self.t_last_transition: float | None = None
        self._lost = False             # the last valid samples were followed by a loss of signal
        self._tr_t: list[float] = []   # transition times [s]
        self._tr_c: list[int] = []     # count after each transition
        self._tr_s: list[int] = []     # its direction (+-1)
        self._run0 = 0                 # index of the first transition of the last one-direction run
        # Look-up tables indexed by the difference of two state indices; a negative
        # difference wraps round to the end of the table, which is the "mod n".
        half = n_states // 2
        # signed step of a change by d states: the shortest way round
        self._signed = np.array([d if d <= half else d - n_states for d in range(n_states)], dtype=np.int64)
        # +-1 for a legal step that is not a change by n/2, 0 for no change, _OTHER otherwise
        # (illegal or ambiguous: the general path decides)
        unit = [s if abs(s) == 1 and not (n_states % 2 == 0 and d == half) else _OTHER
                for d, s in enumerate(self._signed.tolist())]
        unit[0] = 0
        self._unit = np.array(unit, dtype=np.int64)

    def reset(self) -> None:
        """Forget the last state and the transition history (gap or loss of signal)."""
        self.state = -1
        self.t_state = None
        self._clear_history()

    def _clear_history(self) -> None:
        self.t_last_transition = None   # one before a loss or gap says nothing of the motion since
        self._tr_t = []
        self._tr_c = []
        self._tr_s = []
        self._run0 = 0

    def feed(self, times: np.ndarray, states: np.ndarray, lost: np.ndarray | None = None,
             sample_period: float = 0.0, crossing_times=None, all_valid: bool = False) -> FeedResult:
        """Count the steps of one block.

        times: sample times [s]; states: state index per sample (-1 = none); lost: True
        where the signal is absent; crossing_times: per sample, the interpolated time of
        a state change completed at that sample (default: half a sample before it), or
        a function returning these times [s] for an array of sample indices (so that
        they need only be computed where the state changes); all_valid: the caller
        knows that no state is -1 (saves a pass over the states).
        """
        n = self.n
        states = np.asarray(states, dtype=np.int64)
        any_lost = lost is not None and bool(lost.any())
        # seq: the valid samples of the block, after the last state of the previous block
        # (if known); sample(k) = idx[k - pre] is the block sample of seq entry k >= pre
        if all_valid or (len(states) and states.min() >= 0):
            idx = None
            valid = states
        else:
            idx = (states >= 0).nonzero()[0]
            valid = states[idx]
        pre = 1 if self.state >= 0 else 0
        seq_s = np.concatenate(([self.state], valid)) if pre else valid
        if len(seq_s) == 0:
            if any_lost:
                self.reset()
                self._lost = True
            return FeedResult(0, None, None, 0, 0, 0, False)
        g = self._unit[seq_s[1:] - seq_s[:-1]]
        ev = g.nonzero()[0]            # seq steps k -> k + 1 that change the state
        n_ev = len(ev)
        seg0 = 0                       # seq index of the first sample of the last gap-free segment
        if any_lost:
            lost_cum = np.cumsum(lost)
            seq_l = lost_cum if idx is None else lost_cum[idx]
            if pre:
                seq_l = np.concatenate(([0], seq_l))
            bridged = seq_l[1:] == seq_l[:-1]
            breaks = (~bridged).nonzero()[0]
        else:
            breaks = ()
        gz = g[ev]
        s_tr = gz.tolist()
        # count after each change if all are legal steps (the count added to the first);
        # one _OTHER among them makes the total exceed the number of changes
        if n_ev:
            gz[0] += self.count
        c_tr = gz.cumsum()
        total = int(c_tr[-1]) - self.count if n_ev else 0
        if not len(breaks) and abs(total) <= n_ev:
            # fast path: all changes are legal steps of one state, no loss of signal
            illegal = 0
            illegal_free = True
            tr = ev
            seg_steps, dropped = total, 0
            if n_ev:
                self.direction = s_tr[-1]
        else:
            illegal_free = False
            d = (seq_s[ev + 1] - seq_s[ev]) % n
            signed = self._signed[d]
            legal_sign = np.where(np.abs(signed) == 1, signed, 0)
            # direction in force before each step: last legal step before it (forward fill)
            pos = np.where(legal_sign != 0, np.arange(n_ev), -1)
            last = np.maximum.accumulate(np.concatenate(([-1], pos)))[:-1]
            prev_dir = np.where(last >= 0, legal_sign[np.maximum(last, 0)], self.direction)
            half = (n % 2 == 0) & (d == n // 2)
            signed = np.where(half, prev_dir * (n // 2), signed)
            br = bridged[ev] if len(breaks) else np.ones(n_ev, dtype=bool)
            illegal = int((br & ((np.abs(signed) > 1) | (half & (prev_dir == 0)))).sum())
            steps = np.where(br, signed, 0)
            # segments: the last gap-free stretch ends the block
            if len(breaks):
                seg0 = int(breaks[-1]) + 1
            e0 = int(np.searchsorted(ev, seg0))
            seg_steps = int(steps[e0:].sum())
            dropped = int(steps[:e0].sum())
            total = seg_steps + dropped
            nzs = steps.nonzero()[0]
            tr = ev[nzs]
            c_tr = self.count + np.cumsum(steps)[nzs]
            s_tr = np.sign(steps[nzs])
            if len(breaks):  # history before a loss is not comparable
                keep = tr >= seg0
                tr, c_tr, s_tr = tr[keep], c_tr[keep], s_tr[keep]
                self._clear_history()
            s_tr = s_tr.tolist()
            nz = legal_sign.nonzero()[0]
            if len(nz):
                self.direction = int(legal_sign[nz[-1]])
        if len(tr):
            # transition time: between the last sample of the old state and the first of the new
            k = tr if pre else tr + 1
            samples = k if idx is None else idx[k]
            if crossing_times is None:
                t_tr = times[samples] - 0.5 * sample_period
            elif callable(crossing_times):
                t_tr = crossing_times(samples)
            else:
                t_tr = crossing_times[samples]
            self._append_history(t_tr.tolist(), c_tr.tolist(), s_tr, unit=illegal_free)
        self.count += total
        t = self._tr_t
        if t:
            self.t_last_transition = t[-1]
            cut = bisect.bisect_left(t, t[-1] - self.history)
            if cut:
                del t[:cut], self._tr_c[:cut], self._tr_s[:cut]
                self._run0 = max(0, self._run0 - cut)
        t_start = self._seq_time(seg0, pre, idx, times)
        t_end = self._seq_time(len(seq_s) - 1, pre, idx, times)
        self.state = int(seq_s[-1])
        self.t_state = t_end
        after_loss = self._lost or bool(len(breaks))
        self._lost = False
        if any_lost and lost_cum[-1] > seq_l[-1]:
            # the block ends without signal: the next valid sample starts afresh
            self.reset()
            self._lost = True
        return FeedResult(seg_steps, t_start, t_end, illegal, n_ev, dropped, seg0 < pre, after_loss)

    @property
    def last_transition(self) -> tuple[float, int, int] | None:
        """(time [s], count after it, its direction +-1) of the last transition in the history."""
        return (self._tr_t[-1], self._tr_c[-1], self._tr_s[-1]) if self._tr_t else None

    def _seq_time(self, k: int, pre: int, idx, times) -> float:
        """Time [s] of entry k of the valid-sample sequence of ``feed``."""
        if k < pre:
            return float(self.t_state)
        k -= pre
        return float(times[k if idx is None else idx[k]])

    def _append_history(self, t_tr: list, c_tr: list, s_tr: list, unit: bool) -> None:
        """Append one block's transitions; keep the start of the last one-direction run.

        unit: all steps are +-1, so the count tells whether the direction changed."""
        s_first = s_tr[0]
        base = len(self._tr_s)
        if unit and s_first == s_tr[-1] and abs(c_tr[-1] - c_tr[0]) == len(c_tr) - 1:
            rev = 0     # one direction throughout
        else:
            rev = next((i for i in range(len(s_tr) - 1, 0, -1) if s_tr[i] != s_tr[i - 1]), 0)
        if rev:
            self._run0 = base + rev
        elif not self._tr_s or self._tr_s[-1] != s_first:
            self._run0 = base    # the run goes on unless it reverses here
        self._tr_t.extend(t_tr)
        self._tr_c.extend(c_tr)
        self._tr_s.extend(s_tr)

    def transition_speed(self, t_from: float, t_to: float, same_kind: bool = True):
        """Steps per second between the last transition and the earliest usable one.

        Looks at transitions in [t_from, t_to]: the last one L and the earliest j after
        the last reversal with a count difference that is non-zero and, if
        ``same_kind``, a multiple of n (the same state entered in the same direction, so
        unequal state widths cancel). Returns (steps/s, t_j, t_L) or None.
        """
        t = self._tr_t
        if len(t) < 2:
            return None
        hi = bisect.bisect_right(t, t_to) - 1
        lo = bisect.bisect_left(t, t_from)
        m = self.n if same_kind else 1
        if hi - lo < m:
            return None
        c = self._tr_c
        if hi == len(t) - 1:
            first = max(lo, self._run0)
            if abs(c[hi] - c[first]) == hi - first:
                # one step per transition since the reversal: the count difference to L is
                # a multiple of m every m transitions, first at j
                j = first + (hi - first) % m
                if j >= hi:
                    return None
                return self._rate(j, hi)
        # general case (window ending before the last transition, or skipped states)
        s = np.array(self._tr_s[lo:hi + 1])
        cw = np.array(c[lo:hi + 1])
        diff_sign = (s != s[-1]).nonzero()[0]
        first = int(diff_sign[-1]) + 1 if len(diff_sign) else 0
        dc = cw[-1] - cw[first:]
        ok = ((dc != 0) & (dc % m == 0)).nonzero()[0]
        if not len(ok):
            return None
        return self._rate(lo + first + int(ok[0]), hi)

    def _rate(self, j: int, last: int):
        """(steps/s, t_j, t_L) between history entries j and L = last, or None."""
        tj, tl = self._tr_t[j], self._tr_t[last]
        if tl <= tj:
            return None
        return float(self._tr_c[last] - self._tr_c[j]) / (tl - tj), tj, tl


def restart_after_gap(decoder, block: RawBlock) -> bool:
    """Restart ``decoder``'s counter and estimator unless ``block`` continues the last one.

    True for the first block and after a gap (counted in stats["gaps"])."""
    gap = decoder._t_next is None or abs(block.t0 - decoder._t_next) > 0.5 / block.sample_rate
    if gap:
        if decoder._t_next is not None:
            decoder.stats["gaps"] += 1
        decoder.counter.reset()
        decoder.estimator.reset()
    decoder._t_next = block.t_end
    return gap


def increment_or_reject(counter: "CycleCounter", estimator: "IncrementEstimator", res, sample_rate: float,
                        max_illegal: float, what: str, part: str) -> list:
    """The DistanceIncrement of a fed block, or InputRejected("implausible") (state reset)
    when more than ``max_illegal`` state changes skipped a state."""
    if res.illegal > max_illegal:
        counter.reset()
        estimator.reset()
        raise InputRejected("implausible", f"{res.illegal} of {res.transitions} {what} skip a state: speed "
                            f"beyond what the sample rate resolves, or a faulty {part}")
    inc = estimator.make(res, sample_rate)
    return [inc] if inc is not None else []


class IncrementEstimator:
    """Turns counted steps of one block into a DistanceIncrement (shared with the belt).

    An increment runs from the end of the previous one to the last transition of the
    block, so that both ends are transitions whenever the train moves: the distance
    between two transitions is a whole number of steps, known to the transitions'
    position scatter (millimetres), while a block boundary falls anywhere inside a state
    (up to a whole step, 0.1 m on the belt). Consecutive increments then add up to the
    counted distance without a quantisation error at every block, and the fusion's white
    noise model of an increment holds. A block without a transition ends its increment at
    its last sample (the train stands or creeps: the quantisation is then the only
    information there is).

    step: distance of one step [m]; step_max: widest state [m] (quantisation of a block
    boundary); scale_sigma: 1-sigma relative scale error; position_jitter: 1-sigma of a
    transition's position [m]; accel_sigma: prior 1-sigma of the train's acceleration
    [m/s^2], for a speed taken over a window that is not centred on the increment
    (the larger of it and the acceleration seen between the last two speeds is used);
    timing_sigma: 1-sigma error of a transition time [samples] (1/sqrt(12): the
    transition is only known to lie between two samples); unevenness: 1-sigma deviation
    of a transition's position from the even grid of steps [m] (transitions of different
    kinds: coil or channel mounting, duty cycle); settles: the detector settles after a loss of
    signal (the belt's coils coming back onto the belt, their envelope rising through the
    thresholds): the states of the block that ends the loss are not where the boundary model
    puts them (a count 1.5 steps short in 23 ms at 9 m/s was seen), so the increments go on
    from that block's last transition, or its end.
    """

    def __init__(self, sensor: str, unit_id: str, counter: CycleCounter, step: float, step_max: float,
                 scale_sigma: float, speed_window: float, position_jitter: float = 0.0,
                 accel_sigma: float = 0.5, timing_sigma: float = 1.0 / math.sqrt(12.0),
                 unevenness: float = 0.0, settles: bool = False):
        self.sensor, self.unit_id, self.counter = sensor, unit_id, counter
        self.settles = settles
        self.unevenness = unevenness
        self.timing_sigma = timing_sigma
        self.accel_sigma = accel_sigma
        self.step, self.step_max, self.scale_sigma = step, step_max, scale_sigma
        self.speed_window, self.position_jitter = speed_window, position_jitter
        # variance of an increment's end [steps^2]: at a transition; inside a state (a block boundary)
        self._var_edge = (position_jitter ** 2 + unevenness ** 2) / step ** 2
        self._var_boundary = (step_max ** 2 / 12.0 + unevenness ** 2) / step ** 2
        self.reset()

    def reset(self) -> None:
        self._prev_v: float | None = None
        self._prev_t: float | None = None
        self._acc = 0.0
        self._end: tuple | None = None   # end of the last increment: (time [s], position, variance [steps])

    def make(self, res: FeedResult, sample_rate: float):
        """Positions are in steps from the count's origin: state c spans [c - 1/2, c + 1/2],
        so a transition into c in direction s lies at c - s/2 and a block boundary inside c
        at c (uniform over the state)."""
        if res.t_end is None or res.t_start is None:
            return None
        counter = self.counter
        if self._end is not None and res.continued:
            t0, p0, var0 = self._end
        else:   # first block, or the count restarted after a loss of signal
            t0, p0, var0 = res.t_start, float(counter.count - res.steps), self._var_boundary
        last = counter.last_transition
        at_transition = last is not None and t0 < last[0] <= res.t_end and last[0] >= res.t_start
        if at_transition:
            t1, p1, var1 = last[0], last[1] - 0.5 * last[2], self._var_edge
        else:
            t1, p1, var1 = res.t_end, float(counter.count), self._var_boundary
        if self.settles and res.after_loss:
            # the count restarted after a loss of signal: the block's states may be the detector
            # settling; the increments go on from its last transition (or its end)
            self._end = (t1, p1, var1)
            return None
        if t1 <= t0 or abs(p1 - p0) * self.step > MAX_SPEED * (t1 - t0):
            # nothing to report; or a transition just after a block boundary (near a standstill
            # an increment ends inside a state, at its centre): the half step between them is the
            # boundary's quantisation, not a speed; the increment runs on to the next block
            return None
        self._end = (t1, p1, var1)
        t_last = counter.t_last_transition
        dt_s = 1.0 / sample_rate
        duration = t1 - t0
        distance = (p1 - p0) * self.step
        dist_sigma = math.sqrt((var0 + var1) * self.step ** 2 + (self.scale_sigma * distance) ** 2
                               + (2 * res.illegal * self.step) ** 2)
        t_mid = 0.5 * (t0 + t1)
        # edges of the same kind within the increment (the speed is its mean speed), else
        # reaching back at most speed_window, else (low speed) any two edges in the same
        # direction
        uneven = 0.0
        est = counter.transition_speed(t0, t1)
        if est is None:
            est = counter.transition_speed(t1 - self.speed_window, t1)
        if est is None:
            est = counter.transition_speed(t1 - self.speed_window, t1, same_kind=False)
            uneven = self.unevenness
        if est is not None and res.illegal == 0:
            rate, tj, tl = est
            span = tl - tj
            speed = rate * self.step
            # timing: each transition known within one sample; jitter of its position
            rel_t = math.sqrt(2.0) * self.timing_sigma * dt_s / span
            pos_t = math.sqrt(2.0 * (self.position_jitter ** 2 + uneven ** 2)) / (abs(rate) * self.step * span)
            offset = abs(0.5 * (tj + tl) - t_mid)
            speed_sigma = math.sqrt((speed * rel_t) ** 2 + (speed * pos_t) ** 2 + (self.scale_sigma * speed) ** 2
                                    + (max(self._acc, self.accel_sigma) * offset) ** 2)
        elif at_transition or t_last is None:
            speed = distance / duration
            speed_sigma = dist_sigma / duration
        else:
            # no transition since t_last: the train moved less than one state since then
            speed = 0.0
            since = t1 - t_last
            speed_sigma = min(dist_sigma / duration, self.step_max / (math.sqrt(3.0) * max(since, duration)))
        if self._prev_v is not None and t1 > self._prev_t:
            self._acc = abs(speed - self._prev_v) / (t1 - self._prev_t)
        self._prev_v, self._prev_t = speed, t1
        # the floor of both (SPEED_STDDEV_FLOOR, the error models' min_stddev); it binds the distance only
        # for an increment of seconds (the wheel's ends scatter by 2.8 mm at the defaults) or without scatter
        return DistanceIncrement(float(t1), self.sensor, self.unit_id, float(duration), float(distance),
                                 float(max(dist_sigma, SPEED_STDDEV_FLOOR * duration)), float(speed),
                                 float(max(speed_sigma, SPEED_STDDEV_FLOOR)))


# --------------------------------------------------------------------------- device
def narrowest_state(phase_tolerance_deg: float, duty_tolerance: float) -> float:
    """Worst-case shortest quadrature state [fraction of a pulse period]."""
    return 0.25 - phase_tolerance_deg / 360.0 - duty_tolerance


def resolvable_speed(sample_rate: float, ppr: int, diameter: float, phase_tolerance_deg: float,
                     duty_tolerance: float) -> float:
    """Highest speed [m/s] at which every quadrature state lasts at least one sample."""
    return sample_rate * narrowest_state(phase_tolerance_deg, duty_tolerance) * math.pi * diameter / ppr


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class WheelSimulator(Simulator):
    sensor = "wheel"
    channels = ("A", "B")
    units = ("level", "level")
    default_sample_rate = DEFAULT_SAMPLE_RATE

    def __init__(self, *args):
        super().__init__(*args)
        p = self.params
        nominal = float(self.vehicle.wheel_diameter)
        if abs(p["wheel_diameter"] - nominal) > 1e-9:
            raise ValueError(
                f"wheel_sensor parameter wheel_diameter = {p['wheel_diameter']} m differs from the vehicle's "
                f"nominal {nominal} m: set sensors.wheel_sensor.wheel_diameter to it")
        self.ppr = int(p["pulses_per_revolution"])
        if self.ppr < 1:
            raise ValueError("pulses_per_revolution must be >= 1")
        tol = p["diameter_tolerance"]
        err = p["diameter_error"]
        if not math.isfinite(err):
            err = float(self.rng.uniform(-tol, tol))
        self.diameter_error = err
        self.diameter = nominal * (1.0 + err)
        self.phase_b = 0.25 + float(self.rng.uniform(-1.0, 1.0)) * p["phase_tolerance"] / 360.0
        self.duty = 0.5 + self.rng.uniform(-1.0, 1.0, 2) * p["duty_tolerance"]
        v_res = resolvable_speed(self.sample_rate, self.ppr, nominal * (1.0 - tol), p["phase_tolerance"],
                                 p["duty_tolerance"])
        if v_res < p["max_speed"]:
            raise ValueError(
                f"wheel_sensor: {self.sample_rate:.0f} Hz resolves {self.ppr} ppr quadrature only up to "
                f"{v_res:.1f} m/s < max_speed {p['max_speed']} m/s; raise sample_rate or lower the ppr")
        forced = np.asarray(p["slip_episodes"], dtype=float).reshape(-1, 3) if len(p["slip_episodes"]) else \
            np.empty((0, 3))
        self._episodes: list[tuple[float, float, float]] = [tuple(map(float, row)) for row in forced]
        self._busy_until = -math.inf
        self._s_ref: float | None = None
        self._extra = 0.0   # circumferential distance gained by creep and slip [m]
        self._vib_zi = np.zeros(1)
        self._angle0 = float(self.rng.uniform(0.0, 1.0))  # initial disc angle [pulse periods]
        self.slip_log: list[tuple[float, float, float]] = []  # random episodes started (t, duration, ratio)
        self.retract_speed = retract_speed(p, self.vehicle)
        self._up: set[int] = set()    # seqs of blocks during which the wheels were up (not sent)

    def simulate(self, truth):
        """The blocks of Simulator.simulate but those during which the wheels were retracted."""
        blocks = super().simulate(truth)
        if self._up:
            blocks = [b for b in blocks if b.seq not in self._up]
            self._up.clear()
        return blocks

    # slip ratio r(t): wheel circumferential speed = v (1 + r)
    def _slip_ratio(self, times, speed, accel):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        drive = accel * np.sign(speed)          # > 0 traction, < 0 braking
        creep = p["creep_coefficient"] * drive
        if not p["driven_axle"]:
            creep = np.minimum(creep, 0.0)
        r = creep
        # random episodes (one at a time)
        u = self.rng.random(n)
        cand = np.flatnonzero((np.abs(accel) >= p["slip_accel_threshold"]) & (u < p["slip_rate"] * dt)
                              & (speed != 0.0))
        for i in cand:
            t = float(times[i])
            if t < self._busy_until:
                continue
            traction = drive[i] > 0
            dur = float(np.clip(self.rng.exponential(p["slip_duration"]), 0.5, p["slip_duration_max"]))
            mag = float(self.rng.uniform(p["slip_ratio_min"], p["slip_ratio_max"]))
            if traction and not p["driven_axle"]:
                continue
            ratio = mag if traction else -mag
            self._episodes.append((t, dur, ratio))
            self.slip_log.append((t, dur, ratio))
            self._busy_until = t + dur
        t0, t1 = times[0], times[-1]
        for ts, dur, ratio in self._episodes:
            if ts > t1 or ts + dur < t0:
                continue
            ramp = min(0.3, dur / 3.0)
            shape = _smoothstep(np.minimum(times - ts, ts + dur - times) / ramp)
            r = r + ratio * shape
        self._episodes = [e for e in self._episodes if e[0] + e[1] >= t0]
        return np.maximum(r, -1.0)

    def samples(self, times, position, speed, acceleration):
        p = self.params
        n = len(times)
        dt = 1.0 / self.sample_rate
        if np.any(np.abs(speed) >= self.retract_speed):
            self._up.add(self.seq)
        if self._s_ref is None:
            self._s_ref = float(position[0])
        r = self._slip_ratio(times, speed, acceleration)
        extra = self._extra + np.cumsum(r * speed) * dt
        self._extra = float(extra[-1])
        # AR(1) vibration, exact discretisation, state kept between blocks
        phi = math.exp(-dt / p["vibration_tau"])
        w = self.rng.normal(0.0, p["vibration"] * math.sqrt(1.0 - phi * phi), n)
        vib, self._vib_zi = first_order_filter([1.0], [1.0, -phi], w, self._vib_zi)
        circ = (position - self._s_ref) + extra + vib          # wheel circumferential travel [m]
        phase = circ / (math.pi * self.diameter) * self.ppr + self._angle0  # pulse periods
        a = (np.mod(phase, 1.0) < self.duty[0]).astype(np.float64)
        b = (np.mod(phase - self.phase_b, 1.0) < self.duty[1]).astype(np.float64)
        # EMI glitches
        k = int(self.rng.poisson(p["glitch_rate"] * n * dt))
        if k:
            where = self.rng.integers(0, n, k)
            which = self.rng.integers(0, 2, k)
            for i, c in zip(where, which):
                if c == 0:
                    a[i] = 1.0 - a[i]
                else:
                    b[i] = 1.0 - b[i]
        return np.column_stack([a, b])


class WheelDecoder(Decoder):
    sensor = "wheel"
    channels = WheelSimulator.channels

    def __init__(self, params, track):
        super().__init__(params, track)
        p = self.params
        self.ppr = int(p["pulses_per_revolution"])
        self.edge = math.pi * p["wheel_diameter"] / (4.0 * self.ppr)      # one step [m]
        widest = 0.25 + p["phase_tolerance"] / 360.0 + p["duty_tolerance"]  # pulse periods
        self.counter = CycleCounter(4, history=max(1.0, 2 * p["speed_window"]))
        self.estimator = IncrementEstimator(
            self.sensor, self.unit_id, self.counter, self.edge, widest * 4.0 * self.edge,
            p["diameter_tolerance"] / math.sqrt(3.0), p["speed_window"],
            position_jitter=p["vibration"],
            unevenness=(p["phase_tolerance"] / 360.0 + p["duty_tolerance"]) * 4.0 * self.edge / math.sqrt(3.0))
        self._t_next: float | None = None
        self.stats = {"edges": 0, "illegal_transitions": 0, "gaps": 0}

    @property
    def count(self) -> int:
        """Cumulative signed edge count since start."""
        return self.counter.count

    def decode(self, block: RawBlock):
        ab = block.data if block.channels == self.channels else \
            block.data[:, [block.channels.index("A"), block.channels.index("B")]]
        # x (x - 1) is 0 exactly for the levels 0 and 1 and for nothing else (NaN included)
        if np.count_nonzero(ab * (ab - 1.0)):
            a, b = ab[:, 0], ab[:, 1]
            bad = ~(((a == 0.0) | (a == 1.0)) & ((b == 0.0) | (b == 1.0)))
            raise InputRejected("implausible", f"{int(bad.sum())} samples with levels other than 0/1 "
                                f"(first {block.data[np.flatnonzero(bad)[0]].tolist()})")
        fs = block.sample_rate
        restart_after_gap(self, block)
        q = QUAD_INDEX[(ab @ _CODE_WEIGHTS).astype(np.intp)]
        res = self.counter.feed(block.t0 + self.sample_offsets(len(ab), fs), q, sample_period=1.0 / fs, all_valid=True)
        self.stats["edges"] += res.transitions
        self.stats["illegal_transitions"] += res.illegal
        return increment_or_reject(self.counter, self.estimator, res, fs, max(2, 0.1 * res.transitions),
                                   "quadrature transitions", "channel")


def error_model(params: dict, track, vehicle) -> ErrorModel:
    """Wheel errors for the fusion: the diameter error, constant between re-calibrations and
    uniform within +-``diameter_tolerance`` (1-sigma tolerance/sqrt(3), which the decoder
    reports inside its stddev); creep under braking, and under traction on a driven axle;
    slip (driven axle) and slide episodes, which the decoder cannot see, none longer than
    ``slip_duration_max`` or the longest forced episode, nor larger than ``slip_ratio_max`` or the
    largest forced one. Its slips come with a radar's echo off the same wet or snowy track: common
    cause ``track_surface``."""
    scale = params["diameter_tolerance"] / math.sqrt(3.0)
    forced = np.asarray(params["slip_episodes"], dtype=float).reshape(-1, 3)
    longest = max(params["slip_duration_max"], float(forced[:, 1].max()) if forced.size else 0.0)
    largest = max(params["slip_ratio_max"], float(np.abs(forced[:, 2]).max()) if forced.size else 0.0)
    # wheels that are retracted at speed are silent by design there: no timeout
    timeout = continuous_timeout(params) if math.isinf(retract_speed(params, vehicle)) else math.inf
    return ErrorModel("wheel", "distance", scale_sigma=scale, reported_scale=scale,
                      creep_coefficient=params["creep_coefficient"], creep_in_traction=params["driven_axle"],
                      faults=("slip", "slide", "wear") if params["driven_axle"] else ("slide", "wear"),
                      scale_fault_sigma=params["wear_fault_sigma"], fault_duration_max=longest,
                      common_causes=("track_surface",),
                      slip_ratio_max=largest, timeout=timeout,
                      min_stddev=SPEED_STDDEV_FLOOR)   # IncrementEstimator.make's floor of both stddevs


SPEC = SensorSpec(
    node="wheel_sensor", sensor="wheel", simulator=WheelSimulator, decoder=WheelDecoder,
    params=PARAMS, description="on-board wheel pulse generator (quadrature): signed distance increments "
    "from edge to edge (no quantisation at block boundaries) and speed; affected by diameter error, creep, "
    "slip and slide", seeds=("002",),
    outputs=("distance",), error_model=error_model,
)
