"""Fault impact: the protection level of a fault, by construction: a relative sensor's scale fault,
a wheel's slip that no other speed source sees, or an offset shared by a run of a position
sensor's fixes.

The filter is linear in the errors of what it takes in. A scale fault f of relative sensor j
(a Doppler radar reading 7 % low) adds f x v to each of j's speeds (a distance increment d over
a time T is a speed d / T), and the filter carries, whatever its policies decided to use or exclude, the
state error f x e with

    predict   e <- F e
    update    e <- e + K g,   g = delta - h e   (delta: the reading's own fault, v for j's
                                                 readings, 0 for every other sensor's)

g is also the mean of the update's innovation per unit fault, so the innovations test the
fault as they come (a generalised likelihood ratio): ``info`` = sum g^2 / S is the Fisher
information about f, ``score`` = sum g nu / S, and f_hat = score / info its least-squares
estimate with 1-sigma 1 / sqrt(info). The readings of other sensors count (fixes, another
speed source), the sensor's own only while another speed source in use checks them: against
the motion model alone a fault that ramps up, or down at its end, passes as an acceleration. The fault the data allows is f_hat (within the sensor's bound,
z x scale_fault_sigma) with 1-sigma 1 / sqrt(info), at most scale_fault_sigma (nothing has
tested it); the interval covers each hypothesis: |e_0 f_hat| + z sqrt(sigma^2 + (e_0
sigma_f)^2), ARAIM's bias + K sigma with the fault's spread taken with the filter's noise.

A wheel that was excluded through its slip episodes tested nothing, so a radar that carried
the speed meanwhile is covered up to its fault's size; a wheel in use tests the radar at every
increment, and the cover shrinks to what the two cannot tell apart. The onset is unknown: a
fault is followed from onsets ``fault_onset_spacing`` s apart (config.py); so is its end: at
each onset the hypothesis that matters most is also followed as ended there (its error stays
in the state while its sensor, right again, agrees with the others). At most ``fault_onsets``
per sensor: the newest active ones always, and the others whose cover is the largest.

An offset of a run of fixes (faults.OFFSET: each fix of sensor j carries f x its own 1-sigma, the
same f for the whole run) is the same linear algebra with delta = the fix's 1-sigma for j's fixes.
Its bound is the single-fix gate's radius (sqrt of the chi-square gate, in the fix's own sigma):
a larger offset fails the gate of a filter that knows its position. Its onsets are the sensor's
fixes (``fault_onset_spacing`` s apart at most), and the dead reckoning and every other sensor's
fixes test it: the jump at the run's first fix is its evidence, so a run the filter has absorbed
stays covered by the size of that jump (within the bound), and a later clean fix, or another
sensor's, shrinks it.

A transient fault of a relative sensor (a wheel's slip or slide, ``transient`` rows) is the same
linear algebra with a different input. The other speed sources' tests catch a slip while one of
them reads beside the wheel; each reading carries the share of a slip of the sensor's bound
(``slip_ratio_max``) that they let pass there (``FaultInput.unseen``, ``TrainFilter.unseen_share``:
all of it while nothing but the motion model sees the wheel), delta = that share x its speed. e is
then the filter's own sensitivity to what slips nobody could see have put into it, through every
later predict, update and policy (a readmission at a large gain included), shrinking as fixes
pull the filter. One row per episode: from the filter's first state, and again at each stretch
the sensor reads alone, where a new slip of another size may begin; the one before ends there,
its error left in the state. Only independent fixes (no fix-bias state: a DGPS bias can take up
the very error a slip left, campaign run network:4262354916) test a row's size, within
+-``slip_ratio_max``; at most ``fault_onsets`` rows per sensor, the smallest cover dropped.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import numpy as np


class FaultInput(NamedTuple):
    """What the reading being applied carries of the bank's faults (``updated``)."""

    sensor: str          # its sensor
    per_unit: float      # its own fault per unit fault: the speed of a relative reading, the 1-sigma of a fix
    checked: bool        # another speed source in use checks it (a fix: always)
    checkers: frozenset = frozenset()  # a relative reading: the other speed sources in use (a common-cause
                                       # group's row is tested by its members' readings only beside a non-member)
    in_groups: bool = True  # it may carry its common-cause groups' fault now (a wheel: while the train is
                            # driven or braked); else it reads outside them and tests their rows
    relative: bool = False  # a relative sensor's reading (else a fix)
    independent: bool = False  # a fix whose error is its own (no fix-bias state, which could take up a
                               # dead-reckoning error): it tests a transient fault's size
    unseen: float = 0.0  # the share [0, 1] of its sensor's transient fault that its tests let pass
                         # (1: nothing but the motion model sees it)


class Impact(NamedTuple):
    """One fault hypothesis, as read from a Bank: sensor ``sensor`` has had a constant scale
    fault since ``onset`` (``active``), or had one from ``onset`` until it ended (the error it
    left is in the state)."""

    sensor: str
    onset: float         # [s]
    e: np.ndarray        # (n,) state error per unit fault [m, m/s, m/s^2, error-state units]
    info: float          # Fisher information about the fault from the innovations since the onset [1]
    score: float         # sum g nu / S [1]
    active: bool = True  # the fault goes on (its sensor's readings carry it)
    offset: bool = False  # an offset of a run of fixes (per unit: one 1-sigma of each fix), else a scale
    transient: bool = False  # a transient fault, carried by unseen readings, tested by fixes only

    def fault(self, bound: float, z: float) -> tuple[float, float]:
        """(mean, 1-sigma) [1] of the fault the data allows: the least-squares estimate within
        +-bound, and 1 / sqrt(info), at most the prior bound / z (nothing tested: the sensor's
        own scale_fault_sigma)."""
        mean, sigma = _fault(np.array([self.info]), np.array([self.score]), np.array([bound]), z)
        return float(mean[0]), float(sigma[0])

    def excluded_beyond(self, bound: float, z: float) -> float:
        """The largest |fault| [1] the data has not excluded at z sigma, at most ``bound``."""
        mean, sigma = self.fault(bound, z)
        return float(_excluded_beyond(mean, sigma, bound, z))


@dataclasses.dataclass(frozen=True, slots=True)
class Bank:
    """The hypotheses followed, one row each; arrays, not a list of Impacts, because every
    update and every published state touches all of them (the fusion benchmark: 4x the update
    time with one object per hypothesis). Never changed in place (the filter's bookkeeping is
    copy-on-write: the filter's history keeps the bank of every step).

    ``memo``: what follows from the rows alone (which sensors' readings carry each one, the newest
    onsets), worked out once and shared by the banks of the same rows: a transform that changes
    the numbers only (``_replace``) keeps it, one that adds or drops rows starts a new one. The
    memo, the slot copy (``_replace``) and the skipped masked sums (``updated``) make the bank's
    transforms 0.70-0.73x the CPU on the maglev set; any two of them 0.85-0.89x
    (docs/benchmarks.md)."""

    sensors: tuple[str, ...]
    onsets: np.ndarray   # (k,) [s]
    active: np.ndarray   # (k,) bool
    bounds: np.ndarray   # (k,) the fault's bound: z x scale_fault_sigma, or the fix gate's radius [1]
    E: np.ndarray        # (k, n) state error per unit fault
    info: np.ndarray     # (k,)
    score: np.ndarray    # (k,)
    offset: np.ndarray   # (k,) bool: an offset of a run of fixes (Impact.offset)
    transient: np.ndarray  # (k,) bool: a transient fault (Impact.transient)
    alone: np.ndarray    # (k,) bool: a transient fault's sensor read last with nothing but the motion model to see it
    groups: tuple = ()   # (k,) frozensets: the sensors whose readings carry each row's fault ({sensor}; a
                         # common-cause group's row: all its members)
    memo: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    def __len__(self) -> int:
        return len(self.sensors)

    def __getitem__(self, k: int) -> Impact:   # a view of hypothesis k
        return Impact(self.sensors[k], float(self.onsets[k]), self.E[k], float(self.info[k]), float(self.score[k]),
                      bool(self.active[k]), bool(self.offset[k]), bool(self.transient[k]))

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    def of(self, sensor: str) -> np.ndarray:
        """(k,) bool, read only: the hypotheses whose fault ``sensor``'s readings carry (its own rows,
        and those of the common-cause groups it belongs to)."""
        key = ("of", sensor)
        if key not in self.memo:
            self.memo[key] = _read_only(np.array([sensor in g for g in self.groups], dtype=bool))
        return self.memo[key]

    def carries(self, sensor: str) -> bool:
        """Whether ``sensor``'s readings carry the fault of any row (``of``)."""
        key = ("carries", sensor)
        if key not in self.memo:
            self.memo[key] = bool(self.of(sensor).any())
        return self.memo[key]

    def grouped(self) -> np.ndarray:
        """(k,) bool, read only: the rows of common-cause groups (more than one member)."""
        if "grouped" not in self.memo:
            self.memo["grouped"] = _read_only(np.array([len(g) > 1 for g in self.groups], dtype=bool))
        return self.memo["grouped"]

    def unchecked(self, checkers: frozenset) -> np.ndarray:
        """(k,) bool, read only: the rows whose members no speed source in ``checkers`` outside them checks."""
        key = ("unchecked", checkers)
        if key not in self.memo:
            self.memo[key] = _read_only(np.array([not (checkers - g) for g in self.groups], dtype=bool))
        return self.memo[key]

    def own_scales(self) -> tuple:
        """Per row, (sensor, onset [s]) where it is one sensor's own scale fault (neither an
        offset, nor transient, nor a common-cause group's), else None (``Prepared.scales``)."""
        if "own_scales" not in self.memo:
            self.memo["own_scales"] = tuple(
                (name, float(onset)) if not (offset or transient) and group == {name} else None
                for name, onset, offset, transient, group in zip(self.sensors, self.onsets, self.offset,
                                                                 self.transient, self.groups))
        return self.memo["own_scales"]

    def persistent(self) -> np.ndarray:
        """(k,) bool, read only: the rows of persistent faults (not ``transient``)."""
        if "persistent" not in self.memo:
            self.memo["persistent"] = _read_only(~self.transient)
        return self.memo["persistent"]

    def episode_begins(self, sensor: str, alone: bool) -> bool:
        """Whether a reading of ``sensor``, ``alone`` (nothing but the motion model sees it) or
        not, begins a transient-fault episode: it has no going-on row yet, or it reads alone
        where it did not before."""
        going_on = self.of(sensor) & self.transient & self.active
        return not going_on.any() or (alone and not np.any(going_on & self.alone))

    def last_onset_of(self, sensors) -> float:
        """The newest onset [s] of the persistent-fault hypotheses of ``sensors`` (-inf: none)."""
        key = ("last_onset", tuple(sensors))
        if key not in self.memo:
            own = [float(t) for s, t, once in zip(self.sensors, self.onsets, self.transient)
                   if s in sensors and not once]
            self.memo[key] = max(own, default=-math.inf)
        return self.memo[key]

    def _replace(self, **changes) -> "Bank":
        """This bank with the fields ``changes`` (the rows' numbers; ``memo`` kept): its slots set
        directly, without dataclasses.replace's checks (``Bank``: what it saves)."""
        new = object.__new__(Bank)
        for name in _BANK_FIELDS:
            object.__setattr__(new, name, changes[name] if name in changes else getattr(self, name))
        return new


_BANK_FIELDS = tuple(f.name for f in dataclasses.fields(Bank))


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a``, made read only (a mask shared by the banks of the same rows)."""
    a.flags.writeable = False
    return a


def _fault(info: np.ndarray, score: np.ndarray, bound: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """(mean, 1-sigma) of the faults the data allows (Impact.fault), per hypothesis."""
    prior = bound / z
    tested = info > 0.0
    safe = np.where(tested, info, 1.0)
    mean = np.where(tested, np.clip(score / safe, -bound, bound), 0.0)
    sigma = np.where(tested, np.minimum(prior, 1.0 / np.sqrt(safe)), prior)
    return mean, sigma


def _within_bound(mean: np.ndarray, sigma: np.ndarray, bound: np.ndarray, z: float,
                  offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, 1-sigma) of an offset fault (rows ``offset``) kept within its bound: the faults the
    data allows, mean +- z sigma, cut to +-bound, as their middle and half-width / z (an offset
    is never larger than the gate's radius; a mean at the bound with an untested spread would
    cover twice it). Scale-fault rows are left as they are."""
    lo, hi = np.maximum(mean - z * sigma, -bound), np.minimum(mean + z * sigma, bound)
    return np.where(offset, 0.5 * (lo + hi), mean), np.where(offset, 0.5 * (hi - lo) / z, sigma)


def _excluded_beyond(mean, sigma, bound, z: float):
    """The largest |fault| the data has not excluded at z sigma, at most ``bound`` (arrays or floats)."""
    return np.minimum(bound, np.abs(mean) + z * sigma)


def _covers(bank: Bank, z: float) -> np.ndarray:
    """Per hypothesis, the position error [m] of the largest fault not excluded: |e_0| x that size."""
    mean, sigma = _fault(bank.info, bank.score, bank.bounds, z)
    return np.abs(bank.E[:, 0]) * _excluded_beyond(mean, sigma, bank.bounds, z)


def _rows(bank: Bank, keep) -> Bank:
    keep = list(keep)
    return Bank(tuple(bank.sensors[k] for k in keep), bank.onsets[keep], bank.active[keep], bank.bounds[keep],
                bank.E[keep], bank.info[keep], bank.score[keep], bank.offset[keep], bank.transient[keep],
                bank.alone[keep], tuple(bank.groups[k] for k in keep))


def _joined(a: Bank, b: Bank) -> Bank:
    """The hypotheses of ``a`` followed by those of ``b``."""
    return Bank(a.sensors + b.sensors, *(np.concatenate([getattr(a, f), getattr(b, f)])
                                         for f in ("onsets", "active", "bounds", "E", "info", "score", "offset",
                                                   "transient", "alone")), a.groups + b.groups)


def _keeps_none(transform):
    """A bank transform that leaves "no hypothesis yet" (None) as it is."""
    @functools.wraps(transform)
    def wrapped(bank, *args):
        return None if bank is None else transform(bank, *args)
    return wrapped


def started(bank: Bank | None, bounds: dict[str, float], onset: float, n: int, max_onsets: int, z: float,
            offset: bool = False, members: dict | None = None) -> Bank:
    """``bank`` plus, per sensor of ``bounds`` (sensor or common-cause group -> fault bound; ``members``:
    group -> its sensors), a new hypothesis from
    ``onset`` [s] (e = 0; ``offset``: of a run of that sensor's fixes, else of its scale), and the fault that matters most so far ended at ``onset`` (a fault
    that ended leaves its error in the state, while its sensor's readings, right again, agree:
    followed as still going on, the data would exclude it). Beyond ``max_onsets`` for a sensor
    one is dropped: never one of the newest quarter of the active ones (a fault that began at a
    stop has put nothing in yet, and is the least tested once the train moves), else the one
    whose cover (|e_0| x the size not excluded) is smallest."""
    bank = _empty(n) if bank is None else bank
    for sensor, bound in bounds.items():
        covers = _covers(bank, z)
        going_on = [k for k in range(len(bank)) if bank.sensors[k] == sensor and bank.active[k]
                    and not bank.transient[k]]
        if going_on:
            largest = max(going_on, key=covers.__getitem__)
            if covers[largest] > 0.0:   # the same error and test, ended here
                ended = _rows(bank, [largest])
                bank = _joined(bank, dataclasses.replace(ended, active=np.zeros(1, bool)))
        bank = _joined(bank, _row(sensor, onset, bound, n, offset=offset, group=(members or {}).get(sensor)))
        covers = _covers(bank, z)
        own = [k for k in range(len(bank)) if bank.sensors[k] == sensor and not bank.transient[k]]
        drop = set()
        while len(own) - len(drop) > max_onsets:
            left = [k for k in own if k not in drop]
            newest = [k for k in left if bank.active[k]][-max(1, max_onsets // 4):]
            drop.add(min((k for k in left if k not in newest), key=covers.__getitem__))
        if drop:
            bank = _rows(bank, (k for k in range(len(bank)) if k not in drop))
    return bank


def _empty(n: int) -> Bank:
    """A bank without hypotheses, for states of dimension n."""
    return Bank((), np.zeros(0), np.zeros(0, bool), np.zeros(0), np.zeros((0, n)), np.zeros(0), np.zeros(0),
                np.zeros(0, bool), np.zeros(0, bool), np.zeros(0, bool), ())


def _row(sensor: str, onset: float, bound: float, n: int, offset: bool = False, transient: bool = False,
         group: frozenset | None = None) -> Bank:
    """One new active hypothesis of ``sensor`` (a common-cause group: of its members ``group``) from
    ``onset`` [s], e = 0."""
    return Bank((sensor,), np.array([onset]), np.ones(1, bool), np.array([bound]), np.zeros((1, n)), np.zeros(1),
                np.zeros(1), np.full(1, offset), np.full(1, transient), np.zeros(1, bool),
                (group or frozenset((sensor,)),))


def episode_started(bank: Bank | None, sensor: str, bound: float, onset: float, alone: bool, n: int,
                    max_rows: int, z: float) -> Bank:
    """A transient-fault episode of ``sensor`` may begin at ``onset`` [s] (``Bank.episode_begins``),
    of any size within ``bound``: its going-on row, if any, ends (its error stays in the state, its
    test goes on) and a new one starts, ``alone`` as the reading that begins it; beyond
    ``max_rows`` rows of the sensor the one with the smallest cover is dropped (never the new one).
    n: the state dimension."""
    bank = _empty(n) if bank is None else bank
    mine = bank.of(sensor) & bank.transient
    bank = bank._replace(active=np.where(mine, False, bank.active))
    bank = _joined(bank, _row(sensor, onset, bound, n, transient=True)._replace(alone=np.full(1, alone)))
    rows = [k for k in range(len(bank)) if bank.sensors[k] == sensor and bank.transient[k]]
    if len(rows) > max_rows:
        covers = _covers(bank, z)
        drop = min(rows[:-1], key=covers.__getitem__)
        bank = _rows(bank, (k for k in range(len(bank)) if k != drop))
    return bank


@_keeps_none
def predicted(bank: Bank, F: np.ndarray) -> Bank:
    """Each e moved by the transition F."""
    return bank._replace(E=bank.E.dot(F.T))


@_keeps_none
def updated(bank: Bank, fault_input: FaultInput | None, h: np.ndarray, K: np.ndarray, nu: float, S: float) -> Bank:
    """After a scalar update with row h, gain K (n,), innovation nu and its variance S, of a
    reading whose own fault per unit is ``fault_input`` (a fix of a sensor with an offset fault:
    its 1-sigma, checked), None for a reading that carries none. A transient fault is carried by
    its sensor's readings in their unseen share (whether the sensor read alone is kept:
    ``Bank.episode_begins``) and tested by independent fixes only."""
    g = -bank.E.dot(h)
    tests = bank.persistent() | (fault_input is not None and fault_input.independent)
    alone = bank.alone
    if fault_input is not None and not bank.carries(fault_input.sensor):
        # no row of its sensor (85 % of the maglev set's readings: the mm-wave fixes): the masked
        # sums below with nothing masked in, skipped (``Bank``: what it saves)
        g = g + 0.0   # as adding the masked zeros: a -0.0 becomes +0.0
    elif fault_input is not None:
        own = bank.of(fault_input.sensor)
        if not fault_input.in_groups:
            own = own & ~bank.grouped()
        delta = np.where(bank.transient, fault_input.per_unit * fault_input.unseen, fault_input.per_unit)
        g = g + np.where(own & bank.active, delta, 0.0)
        # against the motion model alone a ramp passes: no test (a group's members check none of its rows)
        if fault_input.relative:
            tests = tests & ~(own & bank.unchecked(fault_input.checkers))
        elif not fault_input.checked:
            tests = tests & ~own
        if fault_input.relative:
            alone = np.where(own & bank.transient, fault_input.unseen >= 1.0, alone)
    return bank._replace(E=bank.E + g[:, None] * K, info=bank.info + np.where(tests, g * g / S, 0.0),
                         score=bank.score + np.where(tests, g * nu / S, 0.0), alone=alone)


@_keeps_none
def states_set(bank: Bank, idx, value: float = 0.0) -> Bank:
    """The states ``idx`` were set by a policy, not by the readings: their error per unit fault
    is ``value`` (0: set to what the fault-free filter would have set them to)."""
    E = bank.E.copy()
    E[:, idx] = value
    return bank._replace(E=E)


@_keeps_none
def position_set_from_fix(bank: Bank, fix_bias_index: int | None, fault_input: FaultInput | None = None) -> Bank:
    """The position was taken from a fix alone (s = z - fix bias): its error per unit fault is
    minus that of the fix bias (0 without one), plus the fix's own offset per unit for the going-on
    offset hypotheses of its sensor (``fault_input``: the fix's 1-sigma, as ``updated``)."""
    E = bank.E.copy()
    E[:, 0] = -E[:, fix_bias_index] if fix_bias_index is not None else 0.0
    if fault_input is not None:
        own = bank.of(fault_input.sensor) & bank.active & bank.offset
        E[own, 0] += fault_input.per_unit
    return bank._replace(E=E)


@_keeps_none
def speed_set(bank: Bank, speed: float) -> Bank:
    """The speed was set from relative readings that may include the faulty sensor's: its error per
    unit scale fault is taken as the whole speed while the fault goes on (the fault's full share), 0
    once it ended or for a fix offset (no fix in it), and 0 for an unseen slip: a policy sets the
    speed from readings it compared (agreeing sources, the middle of disagreeing ones), whose
    disagreement its own hypotheses cover; the acceleration's as 0."""
    E = bank.E.copy()
    E[:, 1] = np.where(bank.active & ~bank.offset & ~bank.transient, abs(speed), 0.0)
    E[:, 2] = 0.0
    return bank._replace(E=E)


@_keeps_none
def begun_before(bank: Bank, onset: float, speed: float) -> Bank:
    """The common-cause groups' rows of ``onset`` [s], the first ones (the filter has just located
    the train), as faults that may have begun before it: the filter learnt its speed (``speed``
    [m/s]) from the very readings that carry them, so their error per unit fault is the whole
    speed, as ``speed_set`` has it. As a step at the onset they would be the wrong shape: the
    readings since show no change, and a check of their acceleration (an accelerometer's) would
    pass them. A single sensor's fault from before shows against the other speed sources, or, a
    lone source's, is covered by the lone-source solution (lone.py), whose speed holds it."""
    rows = (bank.onsets == onset) & bank.active & ~bank.offset & ~bank.transient & bank.grouped()
    E = bank.E.copy()
    E[:, 1] = np.where(rows, abs(speed), E[:, 1])
    E[:, 2] = np.where(rows, 0.0, E[:, 2])
    return bank._replace(E=E)


class Prepared(NamedTuple):
    """What ``cover`` needs of a bank, as plain floats: the published states between two
    measurements share it (the fusion benchmark: numpy's per-call overhead on a few rows was
    3x the rest of a published state)."""

    rows: tuple   # ((e0, e1, e2, fault mean, fault 1-sigma, an offset: bounded, not spread), ...)
    scales: tuple = ()  # per row: (sensor, onset [s]) of one sensor's own scale fault, else None


class LeftTo(NamedTuple):
    """The scale-fault hypotheses of one sensor that another cover holds: those of ``sensor`` that
    began after ``since`` [s] (the lone-source solution, lone.py: the motion model without that
    sensor from its state at ``since``, which holds under any fault of it since)."""

    sensor: str
    since: float


@_keeps_none
def prepared(bank: Bank, z: float) -> Prepared:
    """The bank's rows for ``cover`` (None: no hypothesis yet)."""
    mean, sigma = _within_bound(*_fault(bank.info, bank.score, bank.bounds, z), bank.bounds, z, bank.offset)
    return Prepared(tuple(zip(bank.E[:, 0].tolist(), bank.E[:, 1].tolist(), bank.E[:, 2].tolist(),
                              mean.tolist(), sigma.tolist(), bank.offset.tolist())), bank.own_scales())


def cover(bank: Bank | Prepared, dt: float, z: float, var_s: float, var_v: float,
          left_to: LeftTo | None = None) -> tuple[float, float]:
    """(position [m], speed [m/s]) half-widths of the interval that covers every hypothesis at dt
    [s] after the filter's state, whose own variances there are var_s [m^2], var_v [m^2/s^2]:
    per hypothesis the fault's mean effect plus z x (the filter's noise and the fault's spread,
    root-sum-squared), the largest over the hypotheses and the fault-free z sigma. An offset is a
    bounded bias, not a spread: its largest effect within mean +- z sigma (``_within_bound``) is
    added to the filter's z sigma (ARAIM's bias + K sigma). ``left_to``: the scale faults of one
    sensor that another published cover holds (``LeftTo``), left out: under such a fault the truth
    is in that cover too, so this one's width adds no integrity."""
    prep = bank if isinstance(bank, Prepared) else prepared(bank, z)
    sd_s, sd_v = math.sqrt(var_s), math.sqrt(var_v)
    half_s, half_v = z * sd_s, z * sd_v
    for k, (e0, e1, e2, mean, sigma, offset) in enumerate(prep.rows):
        if left_to is not None and _left(prep.scales[k], left_to):
            continue
        p, v = e0 + e1 * dt + 0.5 * e2 * dt * dt, e1 + e2 * dt
        if offset:
            half_s = max(half_s, abs(p) * (abs(mean) + z * sigma) + z * sd_s)
            half_v = max(half_v, abs(v) * (abs(mean) + z * sigma) + z * sd_v)
        else:
            half_s = max(half_s, abs(p * mean) + z * math.sqrt(var_s + (p * sigma) ** 2))
            half_v = max(half_v, abs(v * mean) + z * math.sqrt(var_v + (v * sigma) ** 2))
    return half_s, half_v


def _left(scale: tuple | None, left_to: LeftTo) -> bool:
    """Whether a row (its ``Prepared.scales`` entry) is one that ``left_to`` holds."""
    return scale is not None and scale[0] == left_to.sensor and scale[1] > left_to.since
