"""Passages of trains through a changeover section, with the wayside detection simulated
by the sensor models of core/sensors (track_circuit, axle_counter: their simulators, noise,
faults and decoders), the combined occupancy, the changeover controller and the catenary
events (seed 004 sections 4.1-4.2).

Trains are rigid bodies: a length, axle offsets and raised-pantograph offsets behind the
front, a direction (+1: A -> B, increasing chainage), the time their front passes the
outer counting point they enter by, and a speed that goes from ``speed`` towards
``final_speed`` with ``accel``. A run (``Run``) is a list of such trains; ``simulate``
drives the detection block by block (0.05 s), decodes, votes, lets the controller switch
the ABBs, then counts the catenary events on a 2 ms grid.

Several trains at once: the track-circuit receivers see the axles of every train (the
simulator's axle positions are those of all trains); the axle-counter heads' damping is
the sum over the wheels of every train (one noise-free simulator per train, with the
heads' survey error and gains of the one device simulator that adds the noise, drift and
EMI spikes). A poor-shunt train is a 'poor_shunt' fault of the circuits over the time it
is on them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..measurements import SectionOccupancy
from ..vehicle import Vehicle
from ..sensors import axle_counter as acm
from ..sensors import track_circuit as tcm
from ..sensors.base import resolve_params
from ..signals import RawBlock
from ..track import Track
from .catenary import Layout, Switching, effective, events, pantograph_chainages
from .neutral_section import CONTROLLERS
from .occupancy import PARAMS as OCC_PARAMS, CombinedOccupancy, SectionMap

BLOCK = 0.05          # [s] raw block of both systems; the controller runs at every block end
CHUNK = 1.0           # [s] raw signal simulated at once (then cut into blocks)
GRID = 0.002          # [s] catenary event grid (0.18 m at 330 km/h; air sections are 50 m)
CAR = 25.0            # [m] car length of the generated trains (bogies 17.5 m apart, 2.5 m wheelbase)

# Train types (public figures, rounded; the raised pantographs as they usually run):
# KTX-I 20 cars 388 m, the trailing power car's pantograph (the front one is fed by the
# roof line: modelled as one pantograph); KTX-Sancheon 10 cars 201 m, one pantograph;
# EMU-320 8 cars 200 m, one pantograph on car 2 from the rear; two EMU-320 coupled
# (400 m), one pantograph per unit, no roof bus between the units; a 400 m train with its
# pantograph 25 m behind the front (the worst case for the middle changeover).
TYPES = {
    "KTX": (388.0, (373.0,), False),
    "KTX-Sancheon": (201.0, (186.0,), False),
    "EMU-320": (200.0, (160.0,), False),
    "EMU-320x2": (400.0, (160.0, 360.0), False),
    "front-pantograph-400": (400.0, (25.0,), False),
}


def car_axles(length: float) -> tuple[float, ...]:
    """Axle offsets behind the front [m]: 25 m cars, 4 axles each."""
    cars = max(1, int(round(length / CAR)))
    scale = length / (cars * CAR)
    return tuple(scale * (CAR * k + a) for k in range(cars) for a in (2.5, 5.0, 20.0, 22.5))


@dataclass
class TrainSpec:
    name: str
    direction: int                       # +1 A -> B (increasing chainage), -1 B -> A
    entry_time: float                    # front at the outer counting point it enters by [s]
    speed: float                         # at entry [m/s] (> 0)
    length: float = 388.0
    pantographs: tuple[float, ...] = (373.0,)   # raised, offsets behind the front [m]
    roof_bus: bool = False
    axles: tuple[float, ...] = ()        # offsets behind the front [m]; empty: car_axles(length)
    final_speed: float | None = None     # approached with accel [m/s]; None = constant speed
    accel: float = 0.3                   # [m/s^2]
    poor_shunt: bool = False             # its axles do not shunt the track circuits
    ac_faults: str = ""                  # axle_counter faults on this train's wheels ('HEAD@T:missed')
    kind: str = ""

    @classmethod
    def of_type(cls, kind: str, **kw) -> "TrainSpec":
        length, pans, roof = TYPES[kind]
        return cls(length=length, pantographs=pans, roof_bus=roof, kind=kind, **kw)

    def __post_init__(self):
        if not self.axles:
            self.axles = car_axles(self.length)
        if self.direction not in (1, -1) or not self.speed > 0.0:
            raise ValueError(f"train {self.name}: direction must be +1 or -1 and speed > 0")

    def distance(self, tau: np.ndarray) -> np.ndarray:
        """Distance run since the entry [m] at tau = t - entry_time (constant speed before)."""
        tau = np.asarray(tau, dtype=float)
        v0 = self.speed
        v1 = v0 if self.final_speed is None else self.final_speed
        if v1 == v0 or self.accel <= 0.0:
            return v0 * tau
        a = math.copysign(self.accel, v1 - v0)
        ts = (v1 - v0) / a
        tt = np.clip(tau, 0.0, ts)
        return np.where(tau < 0.0, v0 * tau, v0 * tt + 0.5 * a * tt ** 2 + v1 * np.maximum(tau - ts, 0.0))

    def time_at(self, dist: float) -> float:
        """Time [s] at which the front has run ``dist`` metres past the entry."""
        lo, hi = -1e5, 1e5
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if float(self.distance(mid)) < dist:
                lo = mid
            else:
                hi = mid
        return self.entry_time + hi

    def speed_at(self, tau: float) -> float:
        v0 = self.speed
        v1 = v0 if self.final_speed is None else self.final_speed
        if v1 == v0 or tau <= 0.0:
            return v0
        return v0 + math.copysign(min(self.accel * tau, abs(v1 - v0)), v1 - v0)


@dataclass
class Run:
    """Trains through one changeover section, with the detection's parameters and faults."""

    trains: list[TrainSpec]
    seed: int = 0
    layout: dict = field(default_factory=dict)          # catenary.PARAMS overrides
    track_circuit: dict = field(default_factory=dict)   # track_circuit overrides (faults: 'TC1@T:tx_failed')
    axle_counter: dict = field(default_factory=dict)    # axle_counter overrides (faults: 'AC1@T:extra')
    occupancy: dict = field(default_factory=dict)       # occupancy.PARAMS overrides
    controller: dict = field(default_factory=dict)      # neutral_section.PARAMS overrides
    controller_kind: str = "staged"                     # neutral_section.CONTROLLERS: "staged" or "seed"
    command_latency: float = 0.01                       # decision -> ABB gate signal [s] (assumption)
    drop: tuple[str, ...] = ()                          # systems whose reports are lost ("axle_counter", ...)
    label: str = ""                                     # the injected fault, if any


# The changeover's track circuits pick up after 0.5 s (the line's 1.5 s default rides through a
# momentary loss of shunt; here the axle counter holds the section meanwhile, seed 004 section 4.2)
TC_DEFAULTS = {"pickup_delay": 0.5, "orientation": 1, "block_duration": BLOCK}
AC_DEFAULTS = {"block_duration": BLOCK}


@dataclass
class PassageResult:
    name: str
    kind: str
    direction: int
    speed: float                    # at entry [m/s]
    dead_time: float                # no traction power on the neutral section [s]
    unfed_time: float               # what an unfed neutral section would cost [s]
    crossing_time: float            # front pantograph's time over the neutral section [s]


@dataclass
class RunResult:
    passages: list[PassageResult]
    short_circuits: list[dict]
    air_switchings: list[dict]
    safe_entries: list[tuple[float, str]]
    commands: list
    switchings: list[Switching]
    transitions: list
    disagreements: list
    contradictions: list
    occupancy_log: list              # (stamp, {section: (state, tc, ac)}) on every change
    controller_status: dict
    duration: float


class _Circuits(tcm.TrackCircuitSimulator):
    """The track-circuit receivers seeing the axles of several trains (``axles_now`` (n, k),
    set before each block)."""

    axles_now: np.ndarray

    def axle_positions(self, position: np.ndarray) -> np.ndarray:
        return np.sort(self.axles_now, axis=1)


def _front(train: TrainSpec, layout: Layout, times: np.ndarray) -> np.ndarray:
    entry = layout.ac[0] if train.direction > 0 else layout.ac[2]
    return entry + train.direction * train.distance(times - train.entry_time)


def near_section_window(train: TrainSpec, layout: Layout) -> tuple[float, float]:
    """Times [s] the train is near the section: front 150 m before the entry counting point
    until its rear is 150 m past the far one."""
    span = layout.ac[2] - layout.ac[0]
    return train.time_at(-150.0), train.time_at(span + train.length + 150.0)


def simulate(run: Run) -> RunResult:
    layout = Layout.from_params(run.layout)
    track = Track.from_dict(layout.track_dict())
    rng = np.random.default_rng(run.seed)
    seeds = rng.integers(0, 2 ** 32, size=3 + len(run.trains))
    trains = run.trains
    windows = [near_section_window(t, layout) for t in trains]
    t_start = math.floor((min(w[0] for w in windows) - 1.0) / BLOCK) * BLOCK
    t_end = max(w[1] for w in windows) + 8.0

    # track circuits: poor-shunt trains -> poor_shunt faults of both circuits while they pass
    tc_over = {**TC_DEFAULTS, **run.track_circuit}
    faults = [f for f in str(tc_over.get("faults", "")).split(";") if f.strip()]
    for t, (w0, w1) in zip(trains, windows):
        if t.poor_shunt:
            w0 = max(w0, 0.0)    # fault times are >= 0: let the runs start at 0 s or later
            faults += [f"TC1@{w0:.3f}-{w1:.3f}:poor_shunt", f"TC2@{w0:.3f}-{w1:.3f}:poor_shunt"]
    tc_over["faults"] = ";".join(faults)
    tc_params = resolve_params(tcm.PARAMS, tc_over)
    circuits = _Circuits(tc_params, track, Vehicle(axles=(0.0,)), np.random.default_rng(seeds[0]))
    tc_dec = tcm.TrackCircuitDecoder(tc_params, track)

    # axle counter: the device (noise, drift, spikes, spurious axles) plus one noise-free
    # simulator per train for its wheels
    ac_params = resolve_params(acm.PARAMS, {**AC_DEFAULTS, **run.axle_counter})
    device = acm.AxleCounterSimulator(ac_params, track, Vehicle(axles=()), np.random.default_rng(seeds[1]))
    quiet = {**AC_DEFAULTS, **{k: v for k, v in run.axle_counter.items() if k != "faults"},
             "noise_sigma": 0.0, "drift_sigma": 0.0, "spike_rate": 0.0}
    wheel_sims = []
    for k, t in enumerate(trains):
        p = resolve_params(acm.PARAMS, {**quiet, "orientation": t.direction, "faults": t.ac_faults})
        sim = acm.AxleCounterSimulator(p, track, Vehicle(axles=tuple(t.axles)), np.random.default_rng(seeds[3 + k]))
        sim.head_pos, sim.gain = device.head_pos, device.gain
        wheel_sims.append(sim)
    ac_dec = acm.AxleCounterDecoder(ac_params, track)

    combined = CombinedOccupancy(SectionMap.fig6(), resolve_params(OCC_PARAMS, run.occupancy))
    ctrl = CONTROLLERS[run.controller_kind](run.controller)
    n_tc = circuits.samples_per_block
    n_ac = device.samples_per_block
    axle_off = [np.asarray(t.axles, dtype=float) for t in trains]
    occ_log: list = []
    last_states = None
    switchings: list[Switching] = []
    per_chunk = int(round(CHUNK / BLOCK))
    nchunks = int(math.ceil((t_end - t_start) / CHUNK))
    nblocks = nchunks * per_chunk
    tc_rate, ac_rate = circuits.sample_rate, device.sample_rate
    for kc in range(nchunks):
        c0 = t_start + kc * CHUNK
        active = [k for k, (w0, w1) in enumerate(windows) if w0 - 1.0 <= c0 + CHUNK and c0 <= w1 + 1.0]
        # raw signals of the chunk (simulated at once, decoded block by block)
        times = c0 + np.arange(n_tc * per_chunk) / tc_rate
        xs = [(_front(trains[k], layout, times)[:, None] - trains[k].direction * axle_off[k][None, :])
              for k in active]
        circuits.axles_now = np.concatenate(xs, axis=1) if xs else np.full((len(times), 1), -1.0e6)
        zero = times * 0.0
        tc_data = circuits._quantise(np.array(circuits.samples(times, zero, zero, zero), dtype=float))
        times = c0 + np.arange(n_ac * per_chunk) / ac_rate
        zero = times * 0.0
        ac_data = np.array(device.samples(times, zero, zero, zero), dtype=float)
        for k in active:
            ac_data += wheel_sims[k].samples(times, _front(trains[k], layout, times), zero + trains[k].direction, zero)
        ac_data = device._quantise(ac_data)
        for j in range(per_chunk):
            kb = kc * per_chunk + j
            t0 = c0 + j * BLOCK
            now = t0 + BLOCK
            tc_block = RawBlock.from_samples("track_circuit", circuits.unit_id, kb, t0, tc_rate, circuits.channels,
                                             circuits.units, tc_data[j * n_tc:(j + 1) * n_tc])
            ac_block = RawBlock.from_samples("axle_counter", device.unit_id, kb, t0, ac_rate, device.channels,
                                             device.units, ac_data[j * n_ac:(j + 1) * n_ac])
            for system, dec, block in (("track_circuit", tc_dec, tc_block), ("axle_counter", ac_dec, ac_block)):
                for m in dec.decode(block):
                    if isinstance(m, SectionOccupancy) and system not in run.drop:
                        combined.update(m)
            sections = combined.evaluate(now)
            states = {s.section_id: (s.state, s.tc, s.ac) for s in sections}
            if states != last_states:
                occ_log.append((now, states))
                last_states = states
            for cmd in ctrl.update(now, sections):
                switchings.append(effective(cmd.stamp, cmd.switch, cmd.on, run.command_latency,
                                            layout.params["supply_frequency"]))

    # catenary events on a fine grid
    grid = np.arange(t_start, t_start + nblocks * BLOCK + GRID, GRID)
    pans = {}
    for t in trains:
        pans[t.name] = pantograph_chainages(_front(t, layout, grid), t.direction, t.pantographs)
    report = events(layout, switchings, grid, pans, {t.name: t.roof_bus for t in trains})
    passages = []
    neutral = layout.params["neutral_length"]
    for t in trains:
        # front pantograph's time from entering to leaving the neutral section proper
        lead = min(t.pantographs)
        far = layout.air1[1] if t.direction > 0 else layout.air2[0]
        entry = layout.ac[0] if t.direction > 0 else layout.ac[2]
        d0 = abs(far - entry) + lead
        crossing = t.time_at(d0 + neutral) - t.time_at(d0)
        passages.append(PassageResult(t.name, t.kind, t.direction, t.speed, report.dead[t.name],
                                      report.unfed[t.name], crossing))
    return RunResult(passages, report.short_circuits, report.air_switchings, list(ctrl.safe_entries),
                     list(ctrl.commands), switchings, list(ctrl.transitions), list(combined.records),
                     combined.contradictions(),
                     occ_log, ctrl.status(), float(nblocks * BLOCK))
