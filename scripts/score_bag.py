#!/usr/bin/env python3
"""Score a bag's fused states against its ground truth with the mcap library alone.

  python scripts/score_bag.py bags/*.mcap [--json]

An outside scorer: it reads the MCAP file with mcap's ROS 2 decoder (``mcap_ros2``, which
decodes with the schemas the bag carries) and PyYAML, and uses none of this project's code,
so that a consumer can check what the docs claim from a recording alone
(docs/integration.md, "Scoring a bag without the project").

Per train (every namespace with ``ground_truth/state`` and ``localization/state``), over the
states that claim a position (mode not INITIALISING) within the truth's time span:

* the truth at a state's stamp: the truth sample nearest in time, moved on by its speed and
  acceleration on its own section's axis (a truth sample and a state may lie on either side of a
  section boundary);
* **inside**: the truth's (track_id, position) lies in the state's interval
  ``[position_min, position_max]`` on the state's track_id, or, on another section, in the
  interval of one of the track hypotheses of the same stamp (``localization/tracks``: the state's
  interval covers them all; each restates its interval on every section of its ``path`` in
  ``path_min`` / ``path_max``). On a closed track (the scenario's ``closed: true``) positions
  compare modulo its length;
* **NOMINAL outside**: inside is false while the state claims NOMINAL;
* **NOMINAL on a wrong track**: a NOMINAL state whose track_id is not the truth's section and
  whose most probable hypothesis does not reach it either;
* **on the truth's track**: the state names the truth's section.

Per train with ETCS location reports (``localization/etcs``), over the reports that claim a
position (mode NOMINAL or DEGRADED):

* **ETCS inside**: the truth's front lies between the min and max safe front ends. On a network
  these are path distances: the truth's (track_id, position) is restated on the report's followed
  path (``path``, ``path_direction``, ``path_origin``), or, where that path does not hold the
  truth's section (it follows a switch the interlocking reports wrongly), taken as the truth's
  ``route_distance`` (the same frame: every path starts at the route's start);
* **overruns**: truth samples whose front lies beyond the train's end of authority (the
  scenario's ``atp: end_of_authority``, on ``end_of_authority_section`` on a network), and the
  **EOA margin**: how far short of it the last truth sample stands; the supervision's **trips**
  and highest status (``atp/command``).
"""
from __future__ import annotations

import argparse
import bisect
import json
import math
import sys
from collections import defaultdict

import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

TRUTH, STATE, TRACKS, SCENARIO = "/ground_truth/state", "/localization/state", "/localization/tracks", "/scenario"
ETCS, ATP = "/localization/etcs", "/atp/command"
INITIALISING, NOMINAL, DEGRADED = 0, 1, 2
STATUS_TRIP = 4


def stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def read(path: str) -> tuple[dict, dict, dict, dict, dict, dict]:
    """truth, states, tracks, ETCS reports, ATP commands (namespace -> [(stamp, msg)]) and
    scenarios (namespace or "" -> dict)."""
    streams = {suffix: defaultdict(list) for suffix in (TRUTH, STATE, TRACKS, ETCS, ATP)}
    scenarios = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        wanted = [c.topic for c in reader.get_summary().channels.values()
                  if c.topic.endswith((*streams, SCENARIO))]
        for _, channel, _, msg in reader.iter_decoded_messages(topics=wanted):
            topic = channel.topic
            for suffix, rows in streams.items():
                if topic.endswith(suffix):
                    rows[topic[: -len(suffix)]].append((stamp(msg), msg))
            if topic.endswith(SCENARIO):
                scenarios[topic[: -len(SCENARIO)]] = yaml.safe_load(msg.data)
    return (*streams.values(), scenarios)


def circumference(scenario: dict | None) -> float | None:
    """Length [m] of the scenario's track if it is closed (a ring), else None."""
    track = (scenario or {}).get("track")
    if isinstance(track, dict) and track.get("closed"):
        return float(track["length"])
    return None


class Truth:
    """A train's truth samples; ``at(t)``: (section, chainage) of its front at t."""

    def __init__(self, rows):
        rows = sorted(rows, key=lambda r: r[0])
        self.t = [t for t, _ in rows]
        self.msgs = [m for _, m in rows]

    def nearest(self, t: float):
        """(the truth sample nearest t, t minus its stamp [s])."""
        i = bisect.bisect_left(self.t, t)
        if i == len(self.t) or (i > 0 and t - self.t[i - 1] < self.t[i] - t):
            i -= 1
        return self.msgs[i], t - self.t[i]

    def at(self, t: float) -> tuple[str, float]:
        m, dt = self.nearest(t)
        return m.track_id, m.position + m.speed * dt + 0.5 * m.acceleration * dt * dt

    def route_at(self, t: float) -> float:
        """The front's distance along its route [m] at t (NaN without a route, or in a bag
        recorded before the truth carried one)."""
        m, dt = self.nearest(t)
        moved = m.speed * dt + 0.5 * m.acceleration * dt * dt
        return getattr(m, "route_distance", math.nan) + getattr(m, "route_direction", 0) * moved


def within(x: float, lo: float, hi: float, ring: float | None) -> bool:
    if ring:
        return any(lo <= x + k * ring <= hi for k in (-1, 0, 1))
    return lo <= x <= hi


def in_hypothesis(h, section: str, x: float) -> bool:
    """Whether a hypothesis's interval holds chainage x of ``section`` (a bag recorded before the
    hypotheses restated their interval on each section has it on the hypothesis's own only)."""
    pieces = zip(h.path, h.path_min, h.path_max) if hasattr(h, "path_min") else \
        [(h.track_id, h.position_min, h.position_max)]
    return any(sec == section and lo <= x <= hi for sec, lo, hi in pieces)


def score_train(truth_rows, state_rows, track_rows, ring: float | None) -> dict:
    truth = Truth(truth_rows)
    hyps = {t: m.hypotheses for t, m in track_rows}
    n = inside = nominal_outside = nominal_wrong = on_track = 0
    for t, m in state_rows:
        if m.mode == INITIALISING or not math.isfinite(m.position) or not truth.t[0] <= t <= truth.t[-1]:
            continue
        section, x = truth.at(t)
        listed = hyps.get(t, ())
        same = m.track_id == section
        ok = (same and within(x, m.position_min, m.position_max, ring)) or any(
            in_hypothesis(h, section, x) for h in listed)
        n += 1
        inside += ok
        on_track += same
        if m.mode == NOMINAL:
            nominal_outside += not ok
            nominal_wrong += not same and not (listed and section in listed[0].path)
    return {"states": n, "inside": inside / n if n else math.nan, "outside": n - inside,
            "nominal_outside": nominal_outside, "nominal_wrong_track": nominal_wrong,
            "on_truth_track": on_track / n if n else math.nan}


def train_entry(scenario: dict | None, ns: str) -> dict:
    """The scenario's entry of the train in namespace ``ns`` (a line's ``trains`` item, or the
    one-train scenario itself)."""
    scenario = scenario or {}
    for entry in scenario.get("trains") or ():
        if entry.get("name") == ns.strip("/"):
            return entry
    return scenario


def report_frame(report, truth: Truth, t: float) -> float:
    """The truth's front at t in the frame of a location report's front ends: on a network
    restated on the report's followed path (its route distance where that path lacks the
    section), on a single line its chainage."""
    section, chainage = truth.at(t)
    if not getattr(report, "path", ()):
        return chainage
    for sec, direction, origin in zip(report.path, report.path_direction, report.path_origin):
        if sec == section:
            return origin + direction * chainage
    return truth.route_at(t)


def beyond_eoa(m, atp: dict, route: list, orientation: int) -> float:
    """How far [m] a truth sample's front lies beyond the end of authority (<= 0: short of it;
    NaN on a section of the route other than the EOA's, before it)."""
    eoa, section = float(atp["end_of_authority"]), str(atp.get("end_of_authority_section") or "")
    if not section:
        return orientation * (m.position - eoa)
    if m.track_id == section:
        return m.route_direction * (m.position - eoa)
    past = route.index(m.track_id) > route.index(section) if m.track_id in route and section in route else False
    return math.inf if past else math.nan


def score_etcs(truth_rows, report_rows, command_rows, entry: dict) -> dict:
    """The ETCS location reports and the supervision of one train against its truth."""
    truth = Truth(truth_rows)
    n = inside = 0
    for t, r in report_rows:
        if r.mode not in (NOMINAL, DEGRADED) or not truth.t[0] <= t <= truth.t[-1]:
            continue
        front = report_frame(r, truth, t)
        lo, hi = sorted((r.min_safe_front_end, r.max_safe_front_end))
        n += 1
        inside += lo <= front <= hi
    out = {"reports": n, "etcs_inside": inside / n if n else math.nan, "etcs_outside": n - inside,
           "trips": sum(c.status == STATUS_TRIP for _, c in command_rows),
           "max_status": max((c.status for _, c in command_rows), default=None)}
    atp = entry.get("atp") or {}
    if atp.get("end_of_authority") is not None:
        moving = [m.speed for m in truth.msgs if abs(m.speed) > 0.1]
        orientation = 1 if not moving or moving[0] > 0 else -1
        route = [str(s) for s in (entry.get("route") or {}).get("sections", ())]
        beyond = [beyond_eoa(m, atp, route, orientation) for m in truth.msgs]
        out["overruns"] = sum(b > 0.0 for b in beyond if not math.isnan(b))
        out["eoa_margin"] = -beyond[-1] if beyond else math.nan
    return out


def score_bag(path: str) -> dict:
    """namespace -> scores of every train in the bag (with its ETCS scores where it has location
    reports)."""
    truth, states, tracks, reports, commands, scenarios = read(path)
    out = {}
    for ns in sorted(truth):
        if ns in states:
            scenario = scenarios.get(ns, scenarios.get(""))
            out[ns] = score_train(truth[ns], states[ns], tracks.get(ns, ()), circumference(scenario))
            if ns in reports:
                out[ns]["etcs"] = score_etcs(truth[ns], reports[ns], commands.get(ns, ()), train_entry(scenario, ns))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--json", action="store_true", help="one JSON object: bag -> namespace -> scores")
    args = ap.parse_args(argv)
    results = {bag: score_bag(bag) for bag in args.bags}
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for bag, trains in results.items():
        for ns, s in trains.items():
            print(f"{bag} {ns}: {s['states']} states, inside {100 * s['inside']:.3f} % ({s['outside']} outside, "
                  f"{s['nominal_outside']} NOMINAL), NOMINAL on a wrong track {s['nominal_wrong_track']}, "
                  f"on the truth's track {100 * s['on_truth_track']:.2f} %")
            e = s.get("etcs")
            if e:
                print(f"  ETCS: {e['reports']} reports, the truth within the safe front ends in "
                      f"{100 * e['etcs_inside']:.3f} % ({e['etcs_outside']} outside); trips {e['trips']}, highest "
                      f"status {e['max_status']}" + (f"; overruns {e['overruns']}, {e['eoa_margin']:.2f} m short of "
                                                     f"the EOA at the end" if "overruns" in e else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
