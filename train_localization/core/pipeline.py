"""One sensor device end to end, without ROS: truth -> raw blocks -> measurements.

``SensorPipeline`` is what a sensor node wraps (nodes/sensor.py) and what the
offline replay and the tests drive directly, so that all three run the same code
in the same order. In ingest mode only ``on_block`` is used.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import replace

from .measurements import Measurement
from .scenario import Scenario, TruthBuffer, TruthState, Vehicle
from .sensors import spec as sensor_spec
from .sensors.base import SensorSpec, resolve_params
from .signals import BlockSequenceGuard, InputRejected, RawBlock
from .track import Track


class SensorPipeline:
    """Simulator (optional) + sequence guard + decoder of one device.

    ``rejected`` counts rejected blocks by reason; ``accepted`` counts decoded blocks.
    """

    def __init__(self, spec: SensorSpec, params: dict | None, track: Track, vehicle: Vehicle,
                 rng=None, simulate: bool = True):
        self.spec = spec
        params = dict(params or {})
        if "wheel_diameter" in spec.params and "wheel_diameter" not in params:
            params["wheel_diameter"] = vehicle.wheel_diameter  # the decoder's nominal diameter
        self.params = resolve_params(spec.params, params)
        self.track = track
        self.decoder = spec.decoder(self.params, track)
        self.simulator = spec.simulator(self.params, track, vehicle, rng) if simulate else None
        self.truth = TruthBuffer()
        self.guard = BlockSequenceGuard(spec.decoder.channels or None)
        self.rejected: Counter[str] = Counter()
        self.accepted = 0
        self.measurements_out = 0

    @property
    def unit_id(self) -> str:
        return self.decoder.unit_id

    def on_truth(self, state: TruthState) -> list[RawBlock]:
        """Feed one ground-truth state; returns the raw blocks now complete."""
        self.truth.add(state)
        return self.simulator.simulate(self.truth) if self.simulator else []

    def on_block(self, block: RawBlock) -> list[Measurement]:
        """Check and decode one raw block. Raises InputRejected (counted) for bad blocks."""
        try:
            if block.sensor != self.spec.sensor:
                raise InputRejected("sensor", f"block of sensor {block.sensor!r} sent to a {self.spec.sensor} decoder")
            self.guard.check(block)
            out = self.decoder.decode(block)
        except InputRejected as exc:
            self.rejected[exc.reason] += 1
            raise
        self.accepted += 1
        self.measurements_out += len(out)
        # whole-nanosecond stamps, as they will be in a message: live, offline and
        # replayed runs then see bit-identical measurements
        return [replace(m, stamp=round(m.stamp * 1_000_000_000) / 1_000_000_000) for m in out]


def run_offline(node: str, scenario: Scenario, params: dict | None = None, t_end: float | None = None):
    """Simulate and decode one sensor over a scenario at its truth rate.

    Returns (blocks, measurements, pipeline). Used by tests and benchmarks; the
    simulator node and sensor node produce the same sequence live.
    """
    spec = sensor_spec(node)
    overrides = {**scenario.sensors.get(node, {}), **(params or {})}
    pipe = SensorPipeline(spec, overrides, scenario.track, scenario.vehicle,
                          scenario.rng(node, overrides.get("unit_id") or spec.sensor))
    traj = scenario.trajectory()
    blocks, measurements = [], []
    t_end = scenario.duration if t_end is None else t_end
    n = int(t_end * scenario.truth_rate) + 1
    for k in range(n):
        for block in pipe.on_truth(traj.state_at(k / scenario.truth_rate)):
            blocks.append(block)
            measurements.extend(pipe.on_block(block))
    return blocks, measurements, pipe
