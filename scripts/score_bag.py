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
INITIALISING, NOMINAL = 0, 1


def stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def read(path: str) -> tuple[dict, dict, dict, dict]:
    """truth, states, tracks (namespace -> [(stamp, msg)]) and scenarios (namespace or "" -> dict)."""
    truth, states, tracks, scenarios = defaultdict(list), defaultdict(list), defaultdict(list), {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        wanted = [c.topic for c in reader.get_summary().channels.values()
                  if c.topic.endswith((TRUTH, STATE, TRACKS, SCENARIO))]
        for _, channel, _, msg in reader.iter_decoded_messages(topics=wanted):
            topic = channel.topic
            for suffix, rows in ((TRUTH, truth), (STATE, states), (TRACKS, tracks)):
                if topic.endswith(suffix):
                    rows[topic[: -len(suffix)]].append((stamp(msg), msg))
            if topic.endswith(SCENARIO):
                scenarios[topic[: -len(SCENARIO)]] = yaml.safe_load(msg.data)
    return truth, states, tracks, scenarios


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

    def at(self, t: float) -> tuple[str, float]:
        i = bisect.bisect_left(self.t, t)
        if i == len(self.t) or (i > 0 and t - self.t[i - 1] < self.t[i] - t):
            i -= 1
        m, dt = self.msgs[i], t - self.t[i]
        return m.track_id, m.position + m.speed * dt + 0.5 * m.acceleration * dt * dt


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


def score_bag(path: str) -> dict:
    """namespace -> scores of every train in the bag."""
    truth, states, tracks, scenarios = read(path)
    out = {}
    for ns in sorted(truth):
        if ns in states:
            ring = circumference(scenarios.get(ns, scenarios.get("")))
            out[ns] = score_train(truth[ns], states[ns], tracks.get(ns, ()), ring)
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
