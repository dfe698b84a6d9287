"""Conditions the campaign's generators seldom draw, drawn on purpose (issue: integrity by
construction, not by the cases a campaign happened to draw).

Drawn after everything else of a run (``draw``), so that the rest of the run is the same
with or without them:

* ``tunnel_stop`` (families with a wheel and a radar): the run's last stop lies in a stretch
  without absolute references (no balise, no axle-counter head, 3-6 km before the stop but
  not before the train is halfway to it, 1.5-5 km after it) and the radar has a scale fault of 3-8 %, of either sign, from the
  restart for 30-60 s (the sign that reads like a traction slip of a driven axle as often
  as the other);
* ``worn_wheel``: the wheel's diameter off by 1.5-3 times its tolerance (a wheel worn beyond
  what its error model says);
* ``crawl``: the run's final stop replaced by a crawl at 0.1-0.28 m/s, below the radar's
  minimum speed (0.3 m/s by default: shunting, creeping to a stop marker);
* ``adversarial`` (every family with a position sensor): fixes injected into the delivered
  stream (``inject``): copies of real fixes that claim 1 um, copies naming references the
  track does not have, each 2-300 m off; or a run of 3-10 real fixes of one sensor moved by
  1-4 of their own 1-sigma, the same way (a consistent offset that passes every check of a
  single fix); or, where no other attack was drawn, a ``ramp``: a run of 5-20 real fixes moved
  by an offset that grows from nothing to 1-4 of their 1-sigma (no jump at its first fix);
* ``common_cause`` (``_common_cause``): sources that share a cause fail together;
* ``ramp`` (``_ramps``): persistent faults that grow slowly instead of stepping.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .measurements import PositionFix
from .track import Track

P_TUNNEL, P_WORN, P_CRAWL, P_ADVERSARIAL = 0.25, 0.1, 0.1, 0.1
P_COMMON_CAUSE, P_RAMP = 0.15, 0.15
# sensor nodes whose fixes name equipment of the track, and their classes
FIX_SENSORS = {"eurobalise_reader": "eurobalise", "axle_counter": "axle_counter", "tag_reader": "transponder",
               "lrl_scanner": "lrl", "inpo_receiver": "inpo", "lzb_receiver": "lzb", "mmwave_ranging": "mmwave",
               "mmwave_tdoa": "mmwave_tdoa",
               "dgps_receiver": "dgps", "track_circuit_receiver": "track_circuit", "checkin_loop": "checkin"}


def _last_stop(body: dict, trajectory) -> tuple[float, float, float] | None:
    """(restart time [s], front chainage [m], where the train was halfway to the stop [m]) of
    the run's last stop that the train leaves at least 5 s before the end, or None."""
    t, v = trajectory.t, trajectory.speed
    still = np.abs(v) < 0.01
    restarts = np.flatnonzero(still[:-1] & ~still[1:])
    restarts = [k for k in restarts if 1.0 < t[k] < body["duration"] - 5.0]
    if not restarts:
        return None
    k = restarts[-1]
    arrival = k
    while arrival > 0 and still[arrival - 1]:
        arrival -= 1
    x0 = body["initial"]["position"]
    return float(t[k]), float(x0 + trajectory.position[k]), float(x0 + trajectory.position[arrival // 2])


def _tunnel_stop(d, body: dict, trajectory, conditions: dict) -> None:
    stop = _last_stop(body, trajectory)
    before, after = d.u(3000.0, 6000.0), d.u(1500.0, 5000.0)
    size, sign, hold, ramp = d.u(0.03, 0.08), 1 if d.chance(0.5) else -1, d.u(30.0, 60.0), d.u(1.0, 10.0)
    ramped, delay = d.chance(0.5), d.u(0.0, 3.0)
    if stop is None:
        return
    t_restart, x_stop, x_half = stop
    # the tunnel begins after the train has had references (at the earliest halfway to the stop)
    lo, hi = max(x_stop - before, min(x_half, x_stop)), x_stop + after
    eq = body["track"]["equipment"]
    for kind in ("eurobalise", "axle_counter_head"):
        if kind in eq:
            eq[kind] = [item for item in eq[kind] if not lo <= item["position"] <= hi]
    axle = body["sensors"].get("axle_counter")
    if axle is not None:
        known = {h["id"] for h in eq.get("axle_counter_head", [])}
        listed = [h for h in str(axle.get("heads", "")).split(",") if h in known]
        if not listed and known:   # the unit must watch at least one head of the track
            listed = [min(eq["axle_counter_head"], key=lambda h: abs(h["position"] - x_stop))["id"]]
        axle["heads"] = ",".join(listed)
        axle["faults"] = ";".join(f for f in str(axle.get("faults", "")).split(";") if f.split("@")[0] in listed)
    t0 = t_restart + delay
    fault = f"{t0:.5g}-{t0 + hold:.5g}:{sign * size:.5g}" + (f":{ramp:.3g}" if ramped else "")
    body["sensors"]["doppler_radar"]["faults"] = fault
    conditions["tunnel_stop"] = {"from_m": lo, "to_m": hi, "restart_s": t_restart, "radar_fault": fault}


def _worn_wheel(d, body: dict, conditions: dict) -> None:
    wheel = body["sensors"]["wheel_sensor"]
    error = wheel["diameter_tolerance"] * d.u(1.5, 3.0) * (1 if d.chance(0.5) else -1)
    wheel["diameter_error"] = float(error)
    conditions["worn_wheel"] = {"diameter_error": wheel["diameter_error"]}


def _crawl(d, body: dict, conditions: dict) -> None:
    speed = d.u(0.1, 0.28)
    last = body["profile"][-1]
    if last["speed"] == 0.0:
        last["speed"] = speed
        conditions["crawl"] = {"speed": speed}


def _stations_near(d, body: dict, trajectory, kind: str, count: int) -> tuple[float, list[str]]:
    """(a time [s] in the run, the ids of ``count`` neighbouring ``kind`` items nearest the train
    then), drawn; ([], ...) if the track has fewer."""
    t0 = d.u(0.05, 0.8) * body["duration"]
    items = sorted(body["track"]["equipment"].get(kind, []), key=lambda it: it["position"])
    if len(items) < count:
        return t0, []
    front = float(np.interp(t0, trajectory.t, trajectory.position)) + body["initial"]["position"]
    k = int(np.argmin([abs(it["position"] - front) for it in items]))
    first = min(max(k - d.int(0, count - 1), 0), len(items) - count)
    return t0, [it["id"] for it in items[first:first + count]]


def _group_near(d, body: dict, trajectory, kind: str) -> tuple[float, list[str]]:
    """(a time [s] in the run, the members nearest the train then of the track's common-cause
    group of ``kind`` items that holds them), drawn: a declared group (core/common_cause.py)
    fails, whole or two of its members; without a declaration, 2-3 neighbouring items."""
    t0, near = _stations_near(d, body, trajectory, kind, 1)
    track = Track.from_dict({"track_id": "groups", "length": body["track"]["length"],
                             "equipment": {kind: body["track"]["equipment"].get(kind, [])},
                             "common_cause": body["track"].get("common_cause")})
    groups = [g.members for g in track.common_cause if near and near[0] in g.members]
    if not groups:
        return _stations_near(d, body, trajectory, kind, d.int(2, 3))
    members = list(groups[0])
    if len(members) > 2 and d.chance(0.5):   # two of them
        first = d.int(0, len(members) - 2)
        members = members[first:first + 2]
    return t0, members


def _add_faults(sensor: dict, faults: list[str]) -> None:
    sensor["faults"] = ";".join(filter(None, [str(sensor.get("faults", ""))] + faults))


def _common_cause(d, body: dict, trajectory, conditions: dict) -> None:
    """Sources that share a cause fail together, the same way (docs/campaign.md, "Common causes"):
    the TDOA stations of one timing node (a group the track declares) walk off at one rate (and
    the receiver clock jumps); the two-way-ranging stations of one calibration share one range
    bias; a low-adhesion stretch (wet rail, snow) makes every driven and braked axle slip
    and slide more while the radar's beam reads off, ramping in, at the same time."""
    sensors = body["sensors"]
    sign, hold = 1 if d.chance(0.5) else -1, d.u(5.0, 60.0)
    drawn = {}
    if "mmwave_tdoa" in sensors:
        t0, ids = _group_near(d, body, trajectory, "mmwave_station")
        rate, jump = sign * d.logu(0.1, 5.0), d.u(-1000.0, 1000.0)
        faults = [f"{i}@{t0:.5g}-{t0 + hold:.5g}:sync={rate:.4g}" for i in ids]
        faults.append(f"clock@{t0 + 0.5 * hold:.5g}-{body['duration'] + 1.0:.5g}:jump={jump:.4g}")
        _add_faults(sensors["mmwave_tdoa"], faults)
        drawn["timing"] = ";".join(faults)
    elif "mmwave_ranging" in sensors:
        t0, ids = _group_near(d, body, trajectory, "mmwave_station")
        bias = sign * d.u(0.3, 3.0)
        faults = [f"{i}@{t0:.5g}-{t0 + hold:.5g}:{bias:.4g}" for i in ids]
        _add_faults(sensors["mmwave_ranging"], faults)
        drawn["calibration"] = ";".join(faults)
    if "wheel_sensor" in sensors and "doppler_radar" in sensors and not sensors["doppler_radar"].get("faults"):
        wheel = sensors["wheel_sensor"]
        wheel["slip_rate"] = float(min(1.0, wheel.get("slip_rate", 0.05) * d.u(3.0, 10.0)))
        t0, size_k, ramp = d.u(0.05, 0.7) * body["duration"], sign * d.u(0.02, 0.06), d.u(5.0, 30.0)
        fault = f"{t0:.5g}-{t0 + ramp + hold:.5g}:{size_k:.4g}:{ramp:.3g}"
        sensors["doppler_radar"]["faults"] = fault
        drawn["low_adhesion"] = {"slip_rate": wheel["slip_rate"], "radar_fault": fault}
    if drawn:
        conditions["common_cause"] = drawn


def _ramps(d, body: dict, trajectory, conditions: dict) -> None:
    """Persistent faults that grow slowly instead of stepping (docs/campaign.md, "Ramps"): the
    radar's scale drifting off over 10-40 s; one TDOA station's timing walking off at
    0.02-0.5 ns/s (a slowly growing delay) for 20-90 s."""
    sensors = body["sensors"]
    drawn = {}
    if "doppler_radar" in sensors and not sensors["doppler_radar"].get("faults"):
        t0, ramp = d.u(0.05, 0.7) * body["duration"], d.u(10.0, 40.0)
        size = (1 if d.chance(0.5) else -1) * d.u(0.02, 0.08)
        fault = f"{t0:.5g}-{t0 + ramp + d.u(10.0, 60.0):.5g}:{size:.4g}:{ramp:.3g}"
        sensors["doppler_radar"]["faults"] = fault
        drawn["radar"] = fault
    if "mmwave_tdoa" in sensors:
        t0, ids = _stations_near(d, body, trajectory, "mmwave_station", 1)
        rate = (1 if d.chance(0.5) else -1) * d.logu(0.02, 0.5)
        if ids:
            fault = f"{ids[0]}@{t0:.5g}-{t0 + d.u(20.0, 90.0):.5g}:sync={rate:.4g}"
            _add_faults(sensors["mmwave_tdoa"], [fault])
            drawn["timing"] = fault
    if drawn:
        conditions["ramp"] = drawn


def draw(d, family: str, body: dict, conditions: dict, trajectory) -> dict | None:
    """Draw the run's hard conditions (module docstring) into ``body`` and ``conditions``;
    returns the adversarial injection for the delivery, or None. ``trajectory``: the run's
    motion from chainage 0 (core/scenario.py Trajectory). The common-cause and ramp draws come
    last, so that the earlier draws of a run stay what they were without them."""
    sensors = body["sensors"]
    relative_pair = "wheel_sensor" in sensors and "doppler_radar" in sensors
    if d.chance(P_TUNNEL) and relative_pair:
        _tunnel_stop(d, body, trajectory, conditions)
    if d.chance(P_WORN) and "wheel_sensor" in sensors:
        _worn_wheel(d, body, conditions)
    if d.chance(P_CRAWL) and "doppler_radar" in sensors:
        _crawl(d, body, conditions)
    fixes = [cls for node, cls in FIX_SENSORS.items() if node in sensors]
    attack = None
    if d.chance(P_ADVERSARIAL) and fixes:
        kind = ("claims", "unknown", "offset")[d.int(0, 2)]
        attack = {"kind": kind, "sensor": fixes[d.int(0, len(fixes) - 1)], "t0": d.u(0.2, 0.8) * body["duration"],
                  "count": d.int(3, 10), "offset": d.u(2.0, 300.0) if kind != "offset" else d.u(1.0, 4.0),
                  "sign": 1 if d.chance(0.5) else -1}
    if d.chance(P_COMMON_CAUSE):
        _common_cause(d, body, trajectory, conditions)
    if d.chance(P_RAMP):
        _ramps(d, body, trajectory, conditions)
    if attack is None and fixes and d.chance(P_ADVERSARIAL):
        # a run of real fixes moved by an offset that grows from nothing: no jump at its start
        attack = {"kind": "ramp", "sensor": fixes[d.int(0, len(fixes) - 1)], "t0": d.u(0.2, 0.8) * body["duration"],
                  "count": d.int(5, 20), "offset": d.u(1.0, 4.0), "sign": 1 if d.chance(0.5) else -1}
    if attack is not None:
        conditions["adversarial"] = dict(attack)
    return attack


def inject(arrivals: list, attack: dict | None) -> list:
    """(arrival, measurement) pairs with the adversarial fixes of ``attack`` (see ``draw``):
    added copies (``claims``, ``unknown``) or moved real fixes (``offset``, by ``offset`` of each
    fix's own 1-sigma), the first ``count`` fixes of ``sensor`` from ``t0`` [s]."""
    if not attack:
        return arrivals
    out, left = [], attack["count"]
    for t, m in arrivals:
        hit = left > 0 and isinstance(m, PositionFix) and m.sensor == attack["sensor"] and m.stamp >= attack["t0"]
        if not hit:
            out.append((t, m))
            continue
        left -= 1
        shift = attack["sign"] * attack["offset"]
        if attack["kind"] == "ramp":   # the k-th of n moved by k / n of the offset
            shift *= (attack["count"] - left) / attack["count"]
        if attack["kind"] in ("offset", "ramp"):
            out.append((t, replace(m, position=m.position + shift * m.position_stddev)))
            continue
        out.append((t, m))
        if attack["kind"] == "claims":
            out.append((t, replace(m, position=m.position + shift, position_stddev=1e-6)))
        else:
            out.append((t, replace(m, position=m.position + shift, reference_id=f"ZZ{m.reference_id}"[:64])))
    return out
