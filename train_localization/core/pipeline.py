"""One sensor device end to end, without ROS: truth -> raw blocks -> measurements.

``SensorPipeline`` is what a sensor node wraps (nodes/sensor.py) and what the
offline replay and the tests drive directly, so that all three run the same code
in the same order. In ingest mode only ``on_block`` is used.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace

from .measurements import Measurement
from .network.labels import SectionLabels
from .network.wayside import SectionSimulators, network_decoder
from .scenario import Scenario
from .truth import LineTruth, TruthBuffer, TruthState
from .vehicle import Vehicle
from .sensors import spec as sensor_spec
from .sensors.base import COMMON_PARAMS, SensorSpec, sensor_params
from .signals import BlockSequenceGuard, InputRejected, RawBlock
from .track import Track

# A decoder sees a block's times from ``SensorPipeline.origin`` on: a whole second before the
# first block when the stamps are a wall clock's (from REBASE_FROM on; about 1.8e9 s, where a
# float64 resolves 0.24 us and the decoders' fits of transition times lost up to 0.04 m/s); 0
# for the simulated and recorded time lines, which start near 0 (their results unchanged)
REBASE_FROM = 1.0e6   # [s]


class SensorPipeline:
    """Simulator (optional) + sequence guard + decoder of one device.

    ``rejected`` counts rejected blocks by reason; ``accepted`` counts decoded blocks.
    A block must come at the configured sample rate (``sample_rate``) and last at most
    ``max_block_duration``: the decoders' time and memory per block are bounded by the
    configuration, not by what a publisher sends.

    ``fleet`` (train name -> vehicle): a wayside device on a line, fed with every train's
    truth (``on_truth(state, train)``, scenario.LineTruth). ``network``: a wayside device on a
    network (core/network/wayside.py), its equipment on every section; simulated, each train's
    axles placed by its route (``routes``: train name -> TrackPath, the trains of ``fleet``).
    """

    def __init__(self, spec: SensorSpec, params: dict | None, track: Track, vehicle: Vehicle,
                 rng=None, simulate: bool = True, fleet: dict[str, Vehicle] | None = None,
                 network=None, routes: dict | None = None):
        self.spec = spec
        self.params = sensor_params(spec, params, vehicle)
        self.track = track
        if network is not None:
            self.decoder = network_decoder(spec, self.params, network)
        else:
            self.decoder = spec.decoder(self.params, track)
        # a train on a network: its reference fixes restated on their equipment's sections
        self.labels = SectionLabels(track) if getattr(track, "path", None) is not None and network is None else None
        self.sample_rate = float(self.params["sample_rate"] or spec.simulator.default_sample_rate)
        longest, most = float(self.params["max_block_duration"]), COMMON_PARAMS["max_block_duration"].limits[1]
        if not float(self.params["block_duration"]) <= longest <= most:
            raise ValueError(f"{spec.node}: max_block_duration {longest} s must lie in block_duration "
                             f"({self.params['block_duration']} s) .. {most:g} s")
        self.max_block_samples = math.ceil(longest * self.sample_rate)
        fleet_args = [list(fleet.values())] if fleet else []
        if not simulate:
            self.simulator = None
        elif network is not None:
            self.simulator = SectionSimulators(spec, self.params, network, vehicle, rng, *fleet_args,
                                               [routes[name] for name in fleet])
        else:
            self.simulator = spec.simulator(self.params, track, vehicle, rng, *fleet_args)
        self.truth = LineTruth(fleet) if fleet else TruthBuffer()
        self.guard = BlockSequenceGuard(spec.decoder.channels or None)
        self.origin: float | None = None   # [s] of the decoder's times (REBASE_FROM)
        self.rejected: Counter[str] = Counter()
        self.accepted = 0
        self.measurements_out = 0

    @property
    def unit_id(self) -> str:
        return self.decoder.unit_id

    def on_truth(self, state: TruthState, train: str | None = None) -> list[RawBlock]:
        """Feed one ground-truth state (of ``train``, for a wayside device on a line); returns the
        raw blocks now complete.

        Raises InputRejected (counted) for a state that is not newer than the last one, or of a
        train the device does not know."""
        buffer = self.truth
        if isinstance(self.truth, LineTruth):
            buffer = self.truth.buffers.get(train)
            if buffer is None:
                self.rejected["unknown_id"] += 1
                raise InputRejected("unknown_id", f"truth state of train {train!r}; trains: "
                                    f"{', '.join(self.truth.buffers)}")
        if buffer.latest is not None and state.stamp <= buffer.latest:
            reason = "duplicate" if state.stamp == buffer.latest else "stamp_back"
            self.rejected[reason] += 1
            raise InputRejected(reason, f"truth state at {state.stamp:.6f} s after {buffer.latest:.6f} s")
        buffer.add(state)
        return self.simulator.simulate(self.truth) if self.simulator else []

    def on_position(self, where) -> None:
        """Feed the train's position to a decoder that takes one (``set_position``: the
        accelerometer's gradient), its stamp in the decoder's time; ignored by the others.
        Raises InputRejected (counted) for a position the decoder refuses."""
        if not hasattr(self.decoder, "set_position"):
            return
        if self.origin is None:
            self.origin = float(math.floor(where.stamp)) if abs(where.stamp) >= REBASE_FROM else 0.0
        try:
            self.decoder.set_position(where._replace(stamp=where.stamp - self.origin))
        except InputRejected as exc:
            self.rejected[exc.reason] += 1
            raise

    def on_block(self, block: RawBlock) -> list[Measurement]:
        """Check and decode one raw block. Raises InputRejected (counted) for bad blocks."""
        try:
            if block.sensor != self.spec.sensor:
                raise InputRejected("sensor", f"block of sensor {block.sensor!r} sent to a {self.spec.sensor} decoder")
            if block.unit_id != self.decoder.unit_id:
                # one decoder decodes one device: another unit's blocks would be decoded twice
                raise InputRejected("unit_id", f"block of unit {block.unit_id!r}; this pipeline decodes unit "
                                    f"{self.decoder.unit_id!r} (parameter unit_id)")
            if abs(block.sample_rate - self.sample_rate) > 1e-9 * self.sample_rate:
                raise InputRejected("sample_rate", f"block at {block.sample_rate:g} Hz; the device is configured "
                                    f"for {self.sample_rate:g} Hz (parameter sample_rate)")
            if block.n_samples > self.max_block_samples:
                raise InputRejected("too_large", f"block of {block.n_samples} samples ({block.duration:g} s); at "
                                    f"most {self.max_block_samples} (parameter max_block_duration)")
            self.guard.check(block)
            if self.origin is None:
                self.origin = float(math.floor(block.t0)) if abs(block.t0) >= REBASE_FROM else 0.0
            out = self.decoder.decode(replace(block, t0=block.t0 - self.origin) if self.origin else block)
            if self.labels is not None:
                out = [self.labels(m) for m in out]
        except InputRejected as exc:
            self.rejected[exc.reason] += 1
            raise
        self.guard.commit(block)
        self.accepted += 1
        self.measurements_out += len(out)
        # whole-nanosecond stamps, as they will be in a message: live, offline and
        # replayed runs then see bit-identical measurements
        origin = self.origin
        return [m if (t := round((m.stamp + origin) * 1_000_000_000) / 1_000_000_000) == m.stamp
                else _with_stamp(m, t) for m in out]


def sensor_pipelines(scenario: Scenario) -> list[SensorPipeline]:
    """A simulating SensorPipeline per sensor of the scenario, each on its own random stream."""
    pipes = []
    for node, params in scenario.sensors.items():
        spec = sensor_spec(node)
        unit = (params or {}).get("unit_id") or spec.sensor
        pipes.append(SensorPipeline(spec, params, scenario.track, scenario.vehicle, scenario.rng(node, unit)))
    return pipes


def _with_stamp(m: Measurement, stamp: float) -> Measurement:
    """``dataclasses.replace(m, stamp=stamp)`` without its per-field __init__ call (a hot
    path: up to 200 measurements/s per sensor). The measurement types are frozen
    dataclasses with a plain __dict__ and no __post_init__."""
    new = object.__new__(type(m))
    fields = new.__dict__
    fields.update(m.__dict__)
    fields["stamp"] = stamp
    return new


@dataclass
class OfflineRun:
    blocks: list
    measurements: list
    rejected: list          # (t0 of the block [s], reason) of every rejected block
    pipe: SensorPipeline
    trajectory: object


def simulate_and_decode(node: str, scenario: Scenario, params: dict | None = None, t_end: float | None = None,
                        decode_track: Track | None = None, keep_going: bool = False) -> OfflineRun:
    """Simulate and decode one sensor over a scenario at its truth rate.

    ``decode_track`` gives the decoder another track than the simulator (e.g. one
    missing an id). A rejected block raises InputRejected unless ``keep_going``,
    which records it in ``rejected`` and goes on. The sensor node produces the
    same sequence live.
    """
    spec = sensor_spec(node)
    overrides = {**scenario.sensors.get(node, {}), **(params or {})}
    pipe = SensorPipeline(spec, overrides, scenario.track, scenario.vehicle,
                          scenario.rng(node, overrides.get("unit_id") or spec.sensor))
    if decode_track is not None:
        pipe.decoder = spec.decoder(pipe.params, decode_track)
    traj = scenario.trajectory()
    run = OfflineRun([], [], [], pipe, traj)
    t_end = scenario.duration if t_end is None else t_end
    for k in range(int(t_end * scenario.truth_rate) + 1):
        for block in pipe.on_truth(traj.state_at(k / scenario.truth_rate)):
            run.blocks.append(block)
            try:
                run.measurements.extend(pipe.on_block(block))
            except InputRejected as exc:
                if not keep_going:
                    raise
                run.rejected.append((block.t0, exc.reason))
    return run


def run_offline(node: str, scenario: Scenario, params: dict | None = None, t_end: float | None = None):
    """(blocks, measurements, pipeline) of simulate_and_decode; a rejected block raises."""
    run = simulate_and_decode(node, scenario, params, t_end)
    return run.blocks, run.measurements, run.pipe
