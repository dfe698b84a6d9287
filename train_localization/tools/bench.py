"""tl_bench: throughput benchmarks (figures for the README and issue notes).

  tl_bench sensors   decode throughput per sensor [samples/s] and its ratio to the
                     real-time need at 500 km/h (or the sensor's top speed)
  tl_bench replay    offline replay speed of every bag in bags/ [x real time], serial
                     and with decoding worker processes (tl_replay's default)
  tl_bench fusion    the fusion benchmark (train_localization.tools.bench_fusion)
  tl_bench flood     the live fusion node's states against a flood on one input
                     (train_localization.tools.bench_flood; --rates, --seconds)

Timings are wall-clock (sensors, fusion: one core); run on an idle machine and
repeat: shared machines are noisy.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import yaml

from ..core.paths import SOURCE_ROOT
from ..core.pipeline import SensorPipeline
from ..core.scenario import Scenario
from ..core.sensors import NODE_NAMES, spec

V500 = 500 / 3.6
# sensor -> (speed [m/s], parameter overrides): the top speed each device is specified for
SPEEDS = {
    "wheel_sensor": (83.0, {}),          # 10 kHz default resolves 60 ppr up to 300 km/h (wheel.py)
    "axle_counter": (83.0, {"heads": "AC00,AC01"}),  # conventional rail, 300 km/h
    "lzb_receiver": (83.0, {}),          # LZB serves conventional trains, ICE up to 300 km/h
    "track_circuit_receiver": (83.0, {}),  # UM71C high-speed line, 300 km/h
    "dgps_receiver": (30.6, {}),         # UTM-02 urban maglev, ~110 km/h (dgps.py)
    "tag_reader": (30.6, {}),            # the reader's window reads up to ~140 km/h (transponder.py)
    "checkin_loop": (30.0, {}),          # HSST urban maglev, ~110 km/h (checkin.py max_speed)
    "pole_position": (22.2, {}),         # M-Bahn, 80 km/h (pole_position.py)
    "rig_loop_receiver": (27.8, {"block_duration": 0.02}),  # seed 003 rig: 100 km/h, scenario_rig blocks
}


def _scenario(node: str, speed: float) -> Scenario:
    track = yaml.safe_load((SOURCE_ROOT / "config" / "track_test.yaml").read_text())
    track["length"] = 20000.0
    track["equipment"]["inpo_section"] = [{"id": "INPO01", "position": 10.0, "end": 19000.0, "period": 0.516}]
    track["equipment"]["pattern_belt"] = [{"id": "PB01", "position": 0.0, "end": 20000.0}]
    track["equipment"]["lzb_loop"] = [{"id": "L01", "position": 0.0, "end": 600.0},
                                      {"id": "L02", "position": 600.0, "end": 13300.0},
                                      {"id": "L03", "position": 13300.0, "end": 20000.0}]
    track["equipment"]["track_circuit"] = [{"every": 1500.0, "start": 500.0, "end": 17000.0, "id": "TC{n:02d}",
                                            "length": 1500.0, "system": "UM71C", "line": "T1"}]
    track["equipment"]["transponder_tag"] = [{"every": 100.0, "start": 50.0, "end": 19950.0, "id": "TG{n:03d}"}]
    track["equipment"]["structure"] = [{"id": "BR1", "type": "bridge", "start": 200.0, "end": 220.0}]
    # 32 blocks: two channels each, within a raw block's MAX_CHANNELS (signals.py)
    track["equipment"]["checkin_block"] = [{"every": 300.0, "start": 0.0, "end": 9300.0, "id": "B{n:02d}",
                                            "length": 300.0}]
    params = SPEEDS.get(node, (V500, {}))[1]
    return Scenario.from_dict({
        "name": f"bench_{node}", "seed": 1, "duration": 12.0, "track": track,
        "vehicle": {"type": "conventional", "length": 60.0, "axles": [2.5, 5.0, 30.0, 32.5]},
        "initial": {"position": 5.0, "speed": speed}, "profile": [{"speed": speed, "hold": 60.0}],
        "sensors": {node: params}})


def bench_sensors() -> list[dict]:
    rows = []
    for node in NODE_NAMES:
        speed = SPEEDS.get(node, (V500, {}))[0]
        sc = _scenario(node, speed)
        s = spec(node)
        params = sc.sensors[node]
        sim = SensorPipeline(s, params, sc.track, sc.vehicle, sc.rng(node, s.sensor))
        traj = sc.trajectory()
        blocks = []
        for k in range(int(sc.duration * sc.truth_rate) + 1):
            blocks.extend(sim.on_truth(traj.state_at(k / sc.truth_rate)))
        best = float("inf")
        for _ in range(3):
            dec = SensorPipeline(s, params, sc.track, sc.vehicle, simulate=False)
            t0 = time.perf_counter()
            for b in blocks:
                dec.on_block(b)
            best = min(best, time.perf_counter() - t0)
        samples = sum(b.data.size for b in blocks)
        need = blocks[0].sample_rate * blocks[0].data.shape[1]
        rate = samples / best
        rows.append({"sensor": node, "speed_kmh": speed * 3.6, "samples_per_s": rate,
                     "realtime_need": need, "ratio": rate / need, "blocks": len(blocks)})
    return rows


def bench_replay(repeat: int = 3) -> list[dict]:
    """Offline replay speed of every bag (best of ``repeat``), serial and parallel (tl_replay --serial / default)."""
    from ..core.offline import replay_line, scenario_from_bag
    from .replay import report_for
    rows = []
    for bag in sorted((SOURCE_ROOT / "bags").glob("*.mcap")):
        row = {"bag": bag.name}
        scenario = scenario_from_bag(bag)
        if scenario.line:   # a line's bag: every train and the wayside
            for key, parallel in (("serial", False), ("parallel", True)):
                walls = []
                for _ in range(repeat):
                    t0 = time.perf_counter()
                    replay_line(bag, scenario, parallel=parallel)
                    walls.append(time.perf_counter() - t0)
                wall = min(walls)
                row.update({"duration_s": scenario.duration, f"wall_s_{key}": wall,
                            f"factor_{key}": scenario.duration / wall})
            rows.append(row)
            continue
        for key, parallel in (("serial", False), ("parallel", True)):
            runs = [report_for(bag, parallel=parallel)[0] for _ in range(repeat)]
            best = min(runs, key=lambda r: r["wall_time_s"])
            row.update({"duration_s": best["duration_s"], f"wall_s_{key}": best["wall_time_s"],
                        f"factor_{key}": best["speed_factor"]})
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["sensors", "replay", "fusion", "flood"])
    args, rest = ap.parse_known_args(argv)
    if args.what == "flood":
        from . import bench_flood
        return bench_flood.main(rest)
    if args.what == "sensors":
        print(f"{'sensor':20s} {'speed km/h':>10s} {'decode samples/s':>17s} {'real-time need':>15s} {'ratio':>8s}")
        for r in bench_sensors():
            print(f"{r['sensor']:20s} {r['speed_kmh']:10.0f} {r['samples_per_s']:17.3e} "
                  f"{r['realtime_need']:15.0f} {r['ratio']:7.0f}x")
    elif args.what == "replay":
        print(f"offline replay (tl_replay), best of 3, x real time; {os.cpu_count()} CPU cores")
        print(f"{'':35s} {'--serial':>15s} {'worker processes':>23s}")
        print(f"{'bag':24s} {'bag time s':>10s} {'wall s':>7s} {'factor':>7s} {'wall s':>15s} {'factor':>7s}")
        for r in bench_replay():
            print(f"{r['bag']:24s} {r['duration_s']:10.1f} {r['wall_s_serial']:7.2f} {r['factor_serial']:6.0f}x "
                  f"{r['wall_s_parallel']:15.2f} {r['factor_parallel']:6.0f}x")
    else:
        from . import bench_fusion
        return bench_fusion.main([])
    return 0


if __name__ == "__main__":
    sys.exit(main())
