"""Randomised runs of several trains through drawn station throats with wayside axle
counters: the association of the heads' fixes with the trains' track hypotheses
(docs/network.md, "Wayside equipment"), behind ``python -m train_localization.tools.network_line``.

A run (``generate``, from its seed alone):

  network    a station throat of draw.py (crossovers, turnouts, passing loops, junctions,
             parallel tracks 4-5 m apart, a quarter of the sections' chainages reversed)
  heads      axle-counter heads on every section (``place_heads``): HEAD_BEYOND m past the
             clearance point on each leg a switch's B port leaves by (the fouling point an
             interlocking's switch section ends at), HEAD_BEFORE m before each switch on the
             leg its A port joins, and along the rest of each section every 250-600 m; none
             where the trains stand at the start (the counter starts CLEAR); one device of at
             most MAX_HEADS heads (a raw block's channels), those on the routes first
  trains     2-3 conventional trains (campaign.py ``draw_train``) standing one behind the other
             on the start section, 20-150 m apart; each starts from rest 5-40 s after the one
             ahead, with an acceleration and top speed no higher than its (close following
             over the same heads, never catching up), and takes a drawn route of its own
             (either way at each facing switch), its facing switches reported wrong by the
             interlocking with probability campaign.P_SWITCH_WRONG, else unknown with
             campaign.P_SWITCH_UNKNOWN; all brake to a stop at the same time at the end
  on board   wheel, Doppler and Eurobalise reader across their ranges (campaign.py's
             draws: slips, radar dropouts and scale faults, telegram errors), a DGPS in half
             the runs, a yaw-rate gyro on campaign.P_GYRO of the trains
  wayside    the axle counter of every head (``front_first``: no train backs), its noise and
             EMI spikes drawn, and in a third of the runs one injected miscount: a missed
             wheel or a spurious axle at a head of the leader's route

``run`` simulates it (core/offline/line.py simulate_line: the trains' sensors and fusions, the
wayside device, the association) and scores it (core/report.py line_report: the fixes used,
ambiguous, unexplained and given to a train that did not cause them; per train
network_scores). ``summarise`` adds the runs up against the goals: no fix to a wrong train,
no state NOMINAL on a wrong track, the truth inside the interval in >= 99.9 % of the states.
"""
from __future__ import annotations

import time
import traceback

from ..campaign import (P_GYRO, P_SWITCH_UNKNOWN, P_SWITCH_WRONG, Draw, draw_dgps, draw_doppler, draw_reader,
                        draw_train, draw_wheel_sensor, rounded)
from ..report import jsonable
from ..signals import MAX_CHANNELS
from .draw import draw_network, pick_route
from .model import Network
from .path import route_path

HEAD_BEYOND = 5.0       # [m] past a switch's clearance point
HEAD_BEFORE = 20.0      # [m] before a switch's point on its A leg
HEAD_SPACING = (250.0, 600.0)   # [m] between the heads along a section
HEAD_CLEARANCE = 30.0   # [m] a head keeps from another and from a section's ends
TRAINS = (2, 3)
P_DGPS, P_MISCOUNT = 0.5, 1.0 / 3.0
INSIDE_TARGET = 0.999
MAX_HEADS = MAX_CHANNELS // 2   # heads of one device: two channels each in one raw block


def place_heads(d: Draw, net: Network, clear: tuple[str, float, int]) -> dict[str, list[dict]]:
    """Section id -> its heads ({id, position [m]}), ids H1, H2, ... in the network's order of
    sections and along each. ``clear``: (section, chainage [m], direction of travel): no head
    on that section behind the chainage + HEAD_CLEARANCE, where the trains stand when the
    counter starts CLEAR (a counter cannot know the axles standing in its sections)."""
    marks: dict[str, list[float]] = {sid: [] for sid in net.sections}
    for node in net.switches():
        for port, end in node.ports.items():
            length = net.section(end.section).length
            offset = node.clearance + HEAD_BEYOND if port != "A" else HEAD_BEFORE
            if offset + 1.0 >= length:
                continue     # a crossover shorter than its clearance: the heads of its neighbours
            marks[end.section].append(offset if end.end == "begin" else length - offset)
    for sid, sec in net.sections.items():
        x = d.u(*HEAD_SPACING)
        while x < sec.length - HEAD_CLEARANCE:
            if all(abs(x - m) >= HEAD_CLEARANCE for m in marks[sid]):
                marks[sid].append(x)
            x += d.u(*HEAD_SPACING)
    section, chainage, direction = clear
    marks[section] = [x for x in marks[section] if (x - chainage) * direction > HEAD_CLEARANCE]
    heads, n = {}, 0
    for sid in net.sections:
        for x in sorted(marks[sid]):
            n += 1
            heads.setdefault(sid, []).append({"id": f"H{n}", "position": rounded(x, 8)})
    return heads


def generate(seed: int) -> dict:
    """The scenario dict of run ``seed`` (``Scenario.from_dict`` loads it) with its drawn
    conditions under ``campaign``."""
    d = Draw(seed)
    n_trains = d.int(*TRAINS)
    vehicles = [draw_train(d) for _ in range(n_trains)]
    gaps = [d.u(20.0, 150.0) for _ in range(n_trains - 1)]
    duration = d.u(70.0, 120.0)
    v_top = d.u(30.0, 80.0) / 3.6
    accel, decel = d.u(0.4, 1.0), d.u(0.6, 1.2)
    rear = sum(v["length"] for v in vehicles) + sum(gaps)
    start = rounded(rear + d.u(30.0, 100.0), 8)
    reach = v_top * duration
    drawn = draw_network(d, f"line_{seed}", start, reach + 300.0, reach)
    heads = place_heads(d, drawn.model, (drawn.start_section, drawn.start_chainage, drawn.start_direction))
    for entry in drawn.network["sections"]:
        if entry["id"] in heads:
            entry.setdefault("equipment", {})["axle_counter_head"] = heads[entry["id"]]
    first = drawn.model.section(drawn.start_section)
    brake_at = duration - v_top / decel - 3.0
    trains, front, wait, routes = [], start, 0.0, []
    v, a = v_top, accel
    for k, vehicle in enumerate(vehicles):
        if k:
            front -= vehicles[k - 1]["length"] + gaps[k - 1]
            wait += d.u(5.0, 40.0)
            v, a = v * d.u(0.7, 1.0), a * d.u(0.7, 1.0)
        sections = pick_route(d, drawn.routes)
        path = route_path(drawn.model, sections, drawn.start_direction)
        reported = {}
        for node, way in path.ways().items():
            if d.chance(P_SWITCH_WRONG):
                reported[node] = "B2" if way == "B1" else "B1"
            elif d.chance(P_SWITCH_UNKNOWN):
                reported[node] = ""
        sensors = {"wheel_sensor": draw_wheel_sensor(d, v_top, vehicle["wheel_diameter"]),
                   "doppler_radar": draw_doppler(d, duration), "eurobalise_reader": draw_reader(d, v_top, (0.1, 0.5))}
        if d.chance(P_GYRO):
            sensors["gyro"] = {"noise_density": d.logu(5.0e-5, 1.0e-3), "bias_sigma": d.logu(1.0e-4, 3.0e-3),
                               "scale_sigma": d.u(0.002, 0.02)}
        hold = max(1.0, brake_at - wait - v / a - 3.0)
        chainage = front if drawn.start_direction > 0 else first.length - front
        route = {"sections": sections, "direction": drawn.start_direction}
        if reported:
            route["reported"] = reported
        trains.append({"name": f"t{k + 1}", "vehicle": vehicle,
                       "initial": {"position": rounded(chainage, 8), "speed": 0.0}, "route": route, "sensors": sensors,
                       "profile": [{"speed": 0.0, "hold": rounded(wait)},
                                   {"speed": rounded(v), "accel": rounded(a), "hold": rounded(hold)},
                                   {"speed": 0.0, "decel": decel}]})
        routes.append(sections)
    if d.chance(P_DGPS):
        dgps = draw_dgps(d, duration)
        for tr in trains:
            tr["sensors"]["dgps_receiver"] = dict(dgps)
    counter = {"front_first": True, "noise_sigma": d.u(0.01, 0.04), "spike_rate": d.u(0.0, 0.02)}
    travelled = list(dict.fromkeys(sid for r in routes for sid in r))
    listed = [h["id"] for sid in travelled for h in heads.get(sid, [])]
    device = [h["id"] for items in heads.values() for h in items]
    if len(device) > MAX_HEADS:   # one device: the heads of the routes, along them
        device = listed[:MAX_HEADS]
        counter["heads"] = ",".join(device)
    miscount = ""
    on_route = [h for sid in routes[0] for h in (x["id"] for x in heads.get(sid, [])) if h in device]
    if on_route and d.chance(P_MISCOUNT):
        head = on_route[d.int(0, len(on_route) - 1)]
        miscount = f"{head}@{rounded(d.u(0.0, 0.8) * duration, 5)}:{'missed' if d.chance(0.5) else 'extra'}"
        counter["faults"] = miscount
    conditions = {"trains": n_trains, "device_heads": len(device), "gaps_m": gaps,
                  "top_speed_kmh": rounded(v_top * 3.6),
                  "network": drawn.shape, "routes": routes, "heads": sum(len(h) for h in heads.values()),
                  "dgps": "dgps_receiver" in trains[0]["sensors"], "miscount": miscount,
                  "reported": {tr["name"]: tr["route"].get("reported", {}) for tr in trains}}
    return {"name": f"network_line_{seed}", "seed": d.seed(), "duration": duration, "truth_rate": 100.0,
            "track": drawn.network, "trains": trains, "wayside": {"sensors": {"axle_counter": counter}},
            "campaign": {"family": "network_line", "seed": int(seed), "conditions": conditions}}


def run(seed: int, fusion_rate: float = 50.0) -> dict:
    """Run ``seed`` and score it: a JSON-serialisable dict; never raises (an error entry
    carries the traceback)."""
    from ..offline import simulate_line
    from ..report import association_check
    from ..scenario import Scenario
    from .scoring import PublishedState, network_scores
    c0 = time.process_time()
    out = {"seed": int(seed)}
    try:
        data = generate(seed)
        out["conditions"] = data["campaign"]["conditions"]
        sc = Scenario.from_dict(data)
        result = simulate_line(sc, fusion_rate=fusion_rate)
        out["association"] = association_check(result)
        out["trains"] = {}
        for name, train_run in result.trains.items():
            train = sc.trains[name]
            scores = network_scores(train.route, [s.stamp for s in train_run.truth],
                                    [s.position for s in train_run.truth],
                                    [PublishedState.of_estimate(e) for e in train_run.estimates])
            scores["contradicted"] = train_run.runner.counters()["switches_contradicted"]
            out["trains"][name] = scores
        out["wayside_rejected"] = dict(result.rejected)
        out["head_fixes"] = sum(1 for m in result.wayside if getattr(m, "reference_id", ""))
    except Exception as exc:   # a failing run is a result of the campaign, not its end
        out["error"] = f"{type(exc).__name__}: {exc}"
        out["traceback"] = traceback.format_exc()
    out["cpu_s"] = time.process_time() - c0
    return jsonable(out)


def summarise(results: list[dict]) -> dict:
    """The runs added up: fixes by outcome and those given to a wrong train, states NOMINAL
    on a wrong track, the truth inside the interval (all states and the worst train), track
    selectivity and switch ways, against the goals."""
    ok = [r for r in results if "error" not in r]
    trains = [(r["seed"], name, t) for r in ok for name, t in r["trains"].items() if t.get("claimed")]
    assoc = {k: sum(r["association"][k] for r in ok) for k in ("offered", "used", "ambiguous", "unexplained",
                                                                 "wrong_train")}
    claimed = sum(t["claimed"] for _, _, t in trains)
    on_track = sum(t["claimed"] * t["on_true_track"] for _, _, t in trains)
    inside = sum(t["claimed"] * t["on_true_track"] * t["inside"] for _, _, t in trains
                 if t["inside"] == t["inside"])
    parallel = sum(t["parallel_states"] for _, _, t in trains)
    ways = sum(t["switch_ways"] for _, _, t in trains)
    worst = min(trains, key=lambda x: x[2]["inside"], default=None)
    out = {
        "runs": len(results), "errors": [[r["seed"], r["error"]] for r in results if "error" in r],
        "trains": len(trains), "association": assoc,
        "runs_wrong_train": [[r["seed"], r["association"]["wrong_train"]] for r in ok
                             if r["association"]["wrong_train"]],
        "nominal_wrong_track": sum(t["nominal_wrong_track"] for _, _, t in trains),
        "trains_nominal_wrong_track": [[s, n, t["nominal_wrong_track"]] for s, n, t in trains
                                       if t["nominal_wrong_track"]],
        "inside_fraction": inside / on_track if on_track else None,
        "worst_train": [worst[0], worst[1], worst[2]["inside"]] if worst else None,
        "true_hypothesis_outside": sum(t["true_hypothesis_outside"] for _, _, t in trains),
        "selectivity": sum(t["parallel_correct"] for _, _, t in trains) / parallel if parallel else None,
        "switch_ways": [sum(t["switch_ways_resolved"] for _, _, t in trains), ways],
        "states": claimed,
        "cpu_s": sum(r["cpu_s"] for r in results),
    }
    out["checks"] = {"no_fix_to_a_wrong_train": assoc["wrong_train"] == 0,
                     "none_nominal_wrong_track": out["nominal_wrong_track"] == 0,
                     "inside": out["inside_fraction"] is not None and out["inside_fraction"] >= INSIDE_TARGET,
                     "no_errors": not out["errors"]}
    return out
