"""The fusion's cost as a run grows: against the run's length and against the number of trains
on one line (``bench_fusion --lengths``, ``bench_fusion --trains``). CPU seconds of this process
(time.process_time, not wall time; a loaded host still spreads it by 10-20 %), the simulation of
the sensors not timed.

  run length   one train's measurements simulated once for the longest run (the scenario's track
               repeated end to end, ``tiled_track``, its last speed held), then fused in order for
               each shorter run on the same measurements up to its end: the CPU per simulated second
               must not grow with the run (the history, the bank and the bookkeeping bounded).
  trains       the first 1, 2, 4 ... trains of a line scenario: every train's measurements and the
               wayside's decoded once, then the line's fusion timed (every train's FusionFeed and the
               association of the wayside fixes, core/offline/line.py LineFusion), as simulate_line
               drives it.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np

from ..core.fusion import Mode, fusion_config
from ..core.offline import fuse_arrivals, scenario_measurements
from ..core.offline.line import LineFusion, LineSimulation
from ..core.offline.topics import WAYSIDE_NAMESPACE
from ..core.scenario import Scenario
from ..core.signals import InputRejected


@dataclass(frozen=True)
class Cost:
    """The CPU time of fusing ``simulated`` seconds of ``measurements``."""

    label: str
    simulated: float      # [s] of simulated time
    measurements: int
    cpu: float            # [s] of CPU time (process time)

    @property
    def per_second(self) -> float:
        """CPU seconds per simulated second [1]."""
        return self.cpu / self.simulated

    def row(self, base: "Cost | None" = None) -> str:
        ratio = f"{self.per_second / base.per_second:>9.2f}" if base is not None else f"{'':>9}"
        return (f"{self.label:<14} {self.simulated:>8.0f} {self.measurements:>9d} {self.cpu:>8.2f} "
                f"{1000 * self.per_second:>10.2f} {1 / self.per_second:>10.1f} "
                f"{1e6 * self.cpu / max(self.measurements, 1):>8.1f} {ratio}")


HEADER = (f"{'run':<14} {'sim s':>8} {'meas':>9} {'CPU s':>8} {'CPU ms/s':>10} {'x real':>10} {'us/meas':>8} "
          f"{'vs first':>9}")


def tiled_track(track: dict, copies: int) -> dict:
    """The track description ``track`` repeated ``copies`` times end to end: its alignment and every
    piece of equipment shifted by k x its length (ids suffixed ``_k`` from the second copy on)."""
    length = float(track["length"])
    out = copy.deepcopy(track)
    out["length"] = length * copies
    out["alignment"] = [dict(s) for _ in range(copies) for s in track.get("alignment", []) or []]
    out["equipment"] = {}
    for kind, entries in (track.get("equipment", {}) or {}).items():
        tiled = []
        for k in range(copies):
            for entry in entries or []:
                e = dict(entry)
                for key in ("position", "start", "end"):
                    if key in e:
                        e[key] = float(e[key]) + k * length
                if k and "id" in e:
                    e["id"] = f"{e['id']}_{k}"
                tiled.append(e)
        out["equipment"][kind] = tiled
    return out


def lengthened(scenario: Scenario, duration: float) -> Scenario:
    """One-train ``scenario`` run for ``duration`` [s]: its track tiled to what its top speed covers
    in that time (and one track length more), its profile's last step held to the end."""
    data = copy.deepcopy(scenario.description)
    track = data["track"]
    top = max([abs(float(s.get("speed", 0.0))) for s in data.get("profile", [])]
              + [abs(float((data.get("initial") or {}).get("speed", 0.0)))])
    copies = math.ceil(top * duration / float(track["length"])) + 1
    data["track"] = tiled_track(track, copies)
    data["duration"] = duration
    if data.get("profile"):
        data["profile"][-1] = {**data["profile"][-1], "hold": duration}
    return Scenario.from_dict(data, source=scenario.source)


def run_length_costs(scenario: Scenario, lengths: list[float], repeat: int = 1, log=print) -> list[Cost]:
    """The in-order fusion's CPU time on the first ``lengths`` [s] of one simulated run of
    ``scenario`` lengthened to the longest; each the least of ``repeat`` runs."""
    longest = max(lengths)
    long_run = lengthened(scenario, longest)
    t0 = time.perf_counter()
    arrivals = scenario_measurements(long_run, longest)
    log(f"{scenario.name} lengthened to {longest:.0f} s ({long_run.track.length / 1000:.0f} km of track): "
        f"{len(arrivals)} measurements (simulation {time.perf_counter() - t0:.0f} s, not timed)")
    config = fusion_config(long_run)
    costs = []
    for length in lengths:
        part = [(t, m) for t, m in arrivals if t <= length]
        runs = [fuse_arrivals(config, part, length) for _ in range(repeat)]
        costs.append(Cost(f"{length:.0f} s", length, len(part), min(sum(r[2:]) for r in runs)))
    log(f"  the {longest:.0f} s run: {sanity(long_run, runs[-1][1])}")
    return costs


def sanity(scenario: Scenario, estimates: list) -> str:
    """What tells that a lengthened run's fusion works as on the scenario itself: the states by
    mode, the largest position error and whether the truth stayed inside the interval."""
    traj = scenario.trajectory()
    modes: dict[str, int] = {}
    worst, outside = 0.0, 0
    for e in estimates:
        modes[Mode(e.mode).name] = modes.get(Mode(e.mode).name, 0) + 1
        if np.isfinite(e.position):
            s = traj.state_at(e.stamp).position
            worst = max(worst, abs(e.position - s))
            outside += not e.position_min <= s <= e.position_max
    return f"states by mode {modes}, largest position error {worst:.3f} m, {outside} states with the truth outside"


def line_of(scenario: Scenario, trains: int) -> Scenario:
    """Line ``scenario`` with its first ``trains`` trains only (the wayside as it is)."""
    data = copy.deepcopy(scenario.description)
    if len(data["trains"]) < trains:
        raise ValueError(f"{scenario.name} has {len(data['trains'])} trains, not {trains}")
    data["trains"] = data["trains"][:trains]
    return Scenario.from_dict(data, source=scenario.source)


def line_inputs(scenario: Scenario, duration: float) -> list[tuple]:
    """Per truth step of a line: (t, {train: truth}, [(namespace, measurements or the
    InputRejected of a block), ...]) with every block decoded (not timed later)."""
    sim = LineSimulation(scenario)
    steps = []
    for k in range(sim.steps(duration)):
        t, truths, blocks = sim.step(k)
        decoded = []
        for ns, pipe, block in blocks:
            try:
                decoded.append((ns, pipe.on_block(block)))
            except InputRejected as exc:
                decoded.append((ns, exc))
        steps.append((t, truths, decoded))
    return steps


def fuse_line(scenario: Scenario, steps: list[tuple], fusion_rate: float = 200.0) -> tuple[LineFusion, float]:
    """The line's fusion of decoded ``steps`` (``line_inputs``) as ``simulate_line`` drives it;
    returns it and its CPU time [s]."""
    c0 = time.process_time()
    line = LineFusion(scenario, fusion_rate, None, None)
    outs = {out.namespace: out for out in line.outs.values()}
    for t, truths, decoded in steps:
        for name, state in truths.items():
            line.truth(name, state, 0)
        for ns, ms in decoded:
            out = outs.get(ns)
            if isinstance(ms, InputRejected):
                (out or line).reject(ms)
            elif out is not None:
                out.take(ms, t)
            elif ns == WAYSIDE_NAMESPACE:
                line.wayside(ms, t)
        line.states(t)
    line.flush()
    return line, time.process_time() - c0


def train_count_costs(scenario: Scenario, counts: list[int], duration: float, repeat: int = 1,
                      log=print) -> list[Cost]:
    """The line's fusion CPU time with the first ``counts`` trains of line ``scenario`` over
    ``duration`` [s]; each the least of ``repeat`` runs."""
    costs = []
    for n in counts:
        line = line_of(scenario, n)
        t0 = time.perf_counter()
        steps = line_inputs(line, duration)
        measurements = sum(len(ms) for _, _, decoded in steps for _, ms in decoded if not isinstance(ms, InputRejected))
        log(f"{n} train(s): {measurements} measurements (simulation {time.perf_counter() - t0:.0f} s, not timed)")
        cpu = min(fuse_line(line, steps)[1] for _ in range(repeat))
        costs.append(Cost(f"{n} train(s)", duration, measurements, cpu))
    return costs


def print_costs(costs: list[Cost], per: list[int] | None = None) -> None:
    """The table of ``costs``, each against the first (``per``: divided by these counts first,
    the cost per train)."""
    print(HEADER)
    for k, c in enumerate(costs):
        print(c.row(costs[0] if k else None))
    if per:
        base = costs[0].per_second / per[0]
        print("per train: " + ", ".join(f"{n}: {1000 * c.per_second / n:.2f} CPU ms/s ({c.per_second / n / base:.2f})"
                                        for c, n in zip(costs, per)))


__all__ = ["Cost", "tiled_track", "lengthened", "run_length_costs", "line_of", "line_inputs", "fuse_line",
           "train_count_costs", "print_costs"]
