"""Randomised passages through the changeover section (seed 004 sections 4.1-4.2) and
their summary: the generator and the statistics behind ``tl_neutral``.

A campaign is a list of runs of 1-4 trains each. Per train: a type of passage.TYPES, an
entry speed uniform in 30-330 km/h, half of them changing speed in the section (towards a
speed up to 60 km/h away, 0.2-0.5 m/s^2), a direction; the next train of a run follows in
the same direction (70 %) or comes the other way. Headway: the next train's front reaches
its entry counting point ``gap`` after the previous train's rear has passed the far one:
close following 0-3 s (40 % of the following trains: the changeover is one route that a
train may enter once the train ahead has left it), otherwise 5-60 s; a train the other way
5-60 s (the route is set in the other direction). Detector noise per run: ballast 2-20 Ohm
km (wet .. dry), the track circuits' noise 0.01-0.04, the axle counter's white noise
0.01-0.04 and EMI spikes 0-0.02 per second and system (the model's default: 0.01). A spike
on one system of a head while a wheel passes it spoils the wheel's two-system sequence:
the axle is not counted, the section keeps a count, the changeover goes to its safe state.

Faults (optional, one per run in half of the runs): a poor-shunt train, a track circuit
stuck OCCUPIED (transmitter failed) from a random time of the run, an axle counter
DISTURBED by a missed axle of a train at a random head.
"""
from __future__ import annotations

from collections import Counter

import numpy as np

from .passage import TYPES, Run, RunResult, TrainSpec, near_section_window
from .catenary import Layout

KMH = 1.0 / 3.6
SPEED_RANGE = (30.0, 330.0)          # [km/h]
FAULT_KINDS = ("poor_shunt", "tc_stuck", "ac_disturbed")


# the layouts tl_neutral can run (catenary.PARAMS overrides): seed 004 section 4.2's 400 m track
# circuits next to the middle counting point (the default), or circuits over the whole 800 m blocks
LAYOUTS = {"seed": {}, "blocks": {"track_circuit_length": 800.0}}


def generate(passages: int, seed: int, faults: bool = False, layout: str = "seed") -> list[Run]:
    """Runs holding ``passages`` trains in all, drawn from ``seed``, on ``layout`` (LAYOUTS)."""
    rng = np.random.default_rng([seed, 4004])
    overrides = dict(LAYOUTS[layout])
    layout = Layout.from_params(overrides)
    span = layout.ac[2] - layout.ac[0]
    runs: list[Run] = []
    left = passages
    kinds = list(TYPES)
    while left > 0:
        n = int(min(left, rng.integers(1, 5)))
        left -= n
        trains: list[TrainSpec] = []
        direction = int(rng.choice((1, -1)))
        t_free = 30.0       # the first train is 150 m before its entry point at >= 0 s (12 s at 30 km/h)
        for k in range(n):
            if k:
                follow = rng.random() < 0.7
                if not follow:
                    direction = -direction
                    gap = rng.uniform(5.0, 60.0)
                else:
                    gap = rng.uniform(0.0, 3.0) if rng.random() < 0.4 else rng.uniform(5.0, 60.0)
            else:
                gap = 0.0
            v0 = rng.uniform(*SPEED_RANGE) * KMH
            v1 = None
            if rng.random() < 0.5:
                v1 = float(np.clip(v0 + rng.uniform(-60.0, 60.0) * KMH, SPEED_RANGE[0] * KMH, SPEED_RANGE[1] * KMH))
            kind = str(rng.choice(kinds))
            t = TrainSpec.of_type(kind, name=f"r{len(runs)}t{k}", direction=direction, entry_time=t_free + gap,
                                  speed=float(v0), final_speed=v1, accel=float(rng.uniform(0.2, 0.5)))
            trains.append(t)
            t_free = t.time_at(span + t.length)       # rear past the far counting point
        run = Run(trains, seed=int(rng.integers(0, 2 ** 31)), layout=dict(overrides),
                  track_circuit={"ballast_resistance": float(rng.uniform(2.0, 20.0)),
                                 "noise_sigma": float(rng.uniform(0.01, 0.04))},
                  axle_counter={"noise_sigma": float(rng.uniform(0.01, 0.04)),
                                "spike_rate": float(rng.uniform(0.0, 0.02))})
        if faults and rng.random() < 0.5:
            inject(run, str(rng.choice(FAULT_KINDS)), rng)
        runs.append(run)
    return runs


def inject(run: Run, kind: str, rng: np.random.Generator) -> str:
    """Add one fault of ``kind`` to the run; returns its description (also in run.label)."""
    layout = Layout.from_params(run.layout)
    k = int(rng.integers(0, len(run.trains)))
    train = run.trains[k]
    w0, w1 = near_section_window(train, layout)
    if kind == "poor_shunt":
        train.poor_shunt = True
        text = f"poor shunt: train {train.name}"
    elif kind == "tc_stuck":
        tc = str(rng.choice(("TC1", "TC2")))
        t = float(rng.uniform(max(w0, 0.0), w1))
        run.track_circuit["faults"] = f"{tc}@{t:.2f}:tx_failed"
        text = f"track circuit stuck OCCUPIED: {tc} from {t:.1f} s (transmitter failed)"
    elif kind == "ac_disturbed":
        head = str(rng.choice(("AC0", "AC1", "AC2")))
        train.ac_faults = f"{head}@{max(w0, 0.0):.2f}:missed"
        text = f"axle counter DISTURBED: {head} misses an axle of train {train.name}"
    else:
        raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
    run.label = text
    return text


def reason_kind(reason: str) -> str:
    """A safe-state reason without its section and states: the kind to count."""
    for key in ("SILENT", "DISTURBED", "degraded", "contradictory", "no detection", "occupied again", "at once",
                "following train"):
        if key in reason:
            return {"DISTURBED": "section DISTURBED", "degraded": "one system DISTURBED, the other detects",
                    "SILENT": "a system silent",
                    "contradictory": "contradiction beyond the tolerance", "no detection": "no detection",
                    "occupied again": "section occupied again during the changeover",
                    "at once": "both sections occupied from idle",
                    "following train": "hold: following train"}[key]
    return reason


def _dist(values: list[float]) -> dict:
    if not values:
        return {}
    a = np.asarray(values, dtype=float)
    return {"min": float(a.min()), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "mean": float(a.mean())}


def summarise(runs: list[Run], results: list[RunResult]) -> dict:
    """Counts and distributions over a campaign (JSON-able)."""
    passages = [p for r in results for p in r.passages]
    nominal = [(run, res) for run, res in zip(runs, results) if not getattr(run, "label", "")]
    faulty = [(run, res) for run, res in zip(runs, results) if getattr(run, "label", "")]

    def counts(pairs):
        reasons = Counter(reason_kind(why) for _, res in pairs for _, why in res.safe_entries)
        return {"runs": len(pairs), "passages": sum(len(run.trains) for run, _ in pairs),
                "short_circuits": sum(len(res.short_circuits) for _, res in pairs),
                "air_section_switchings": sum(len(res.air_switchings) for _, res in pairs),
                "safe_state_entries": dict(sorted(reasons.items())),
                "contradictions": sum(len(res.contradictions) for _, res in pairs)}

    by_fault: dict = {}
    for run, res in faulty:
        kind = run.label.split(":")[0]
        entry = by_fault.setdefault(kind, {"runs": 0, "safe_state": 0, "hold_only_or_none": 0, "short_circuits": 0,
                                           "air_section_switchings": 0})
        entry["runs"] += 1
        latched = [why for _, why in res.safe_entries if "following train" not in why]
        entry["safe_state" if latched else "hold_only_or_none"] += 1
        entry["short_circuits"] += len(res.short_circuits)
        entry["air_section_switchings"] += len(res.air_switchings)
    ratio = [p.dead_time / p.crossing_time for p in passages if p.crossing_time > 0]
    bands = {}
    for lo in range(30, 330, 60):
        sel = [p for p in passages if lo <= p.speed * 3.6 < lo + 60 or (lo == 270 and p.speed * 3.6 >= 330)]
        if sel:
            bands[f"{lo}-{lo + 60} km/h"] = {"passages": len(sel), "dead_time": _dist([p.dead_time for p in sel]),
                                             "crossing_time": _dist([p.crossing_time for p in sel])}
    worst = max(passages, key=lambda p: p.dead_time, default=None)
    return {
        "passages": len(passages),
        "runs": len(results),
        "directions": dict(Counter("A->B" if p.direction > 0 else "B->A" for p in passages)),
        "speed_kmh": _dist([p.speed * 3.6 for p in passages]),
        "nominal": counts(nominal),
        "faulty": counts(faulty) | {"faults": [run.label for run, _ in faulty], "by_fault": by_fault,
                                    "short_circuit_runs": [run.label for run, res in faulty if res.short_circuits]},
        "dead_time_s": _dist([p.dead_time for p in passages]),
        "crossing_time_s": _dist([p.crossing_time for p in passages]),
        "unfed_time_s": _dist([p.unfed_time for p in passages]),
        "dead_over_crossing": _dist(ratio),
        "by_speed": bands,
        "worst_dead_time": None if worst is None else {"train": worst.name, "kind": worst.kind,
                                                       "speed_kmh": worst.speed * 3.6, "dead_time": worst.dead_time,
                                                       "crossing_time": worst.crossing_time},
        "simulated_s": sum(r.duration for r in results),
        "runs_with_events": [
            {"run": i, "fault": run.label, "trains": [f"{t.name} {t.kind} {'A->B' if t.direction > 0 else 'B->A'} "
                                                      f"{t.speed * 3.6:.0f} km/h at {t.entry_time:.1f} s"
                                                      for t in run.trains],
             "short_circuits": res.short_circuits, "air_section_switchings": len(res.air_switchings),
             "safe_state": [f"{t:.2f} s: {why}" for t, why in res.safe_entries],
             "contradictions": [d.text() for d in res.contradictions]}
            for i, (run, res) in enumerate(zip(runs, results))
            if res.short_circuits or res.air_switchings or res.safe_entries or res.contradictions],
    }
