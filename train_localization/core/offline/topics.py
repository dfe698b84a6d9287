"""The topics and namespaces of an offline run's bags: those of the live graph."""
from __future__ import annotations

from ...graph import NAMESPACE   # the graph's namespace: the bags carry its topics
from ..scenario import WAYSIDE, Scenario

SCENARIO_TOPIC = f"{NAMESPACE}/scenario"
TRUTH_TOPIC = f"{NAMESPACE}/ground_truth/state"
FUSED_TOPIC = f"{NAMESPACE}/localization/state"
TRACKS_TOPIC = "localization/tracks"           # a train on a network: its track hypotheses
INTERLOCKING_TOPIC = "interlocking/switches"   # ... and the switch positions reported for it


LINE_SCENARIO_TOPIC = "/scenario"        # the scenario of a line's bag (every train and the wayside)
WAYSIDE_NAMESPACE = f"/{WAYSIDE}"


def raw_topic(sensor: str, namespace: str = NAMESPACE) -> str:
    """Bag topic of a sensor class's raw blocks."""
    return f"{namespace}/sensors/{sensor}/raw"


def train_namespace(scenario: Scenario) -> str:
    """Namespace of a train's graph: /train for a one-train scenario, /<name> on a line."""
    return f"/{scenario.train_name}" if scenario.line else NAMESPACE
