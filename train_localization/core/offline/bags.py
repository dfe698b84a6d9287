"""What a bag of an offline run records besides the topics' data: the scenario (written first,
read back to replay the bag) and a network train's interlocking."""
from __future__ import annotations

from pathlib import Path

import yaml

from .. import convert
from ..bagio import BagReader, BagWriter, typestore
from ..scenario import Scenario
from .topics import INTERLOCKING_TOPIC, LINE_SCENARIO_TOPIC, SCENARIO_TOPIC


def string_message(text: str):
    """A std_msgs/String of ``text`` (the scenario's YAML on its topic)."""
    return typestore().types["std_msgs/msg/String"](data=text)


def write_interlocking(writer: BagWriter, mc, scenario: Scenario, namespace: str) -> None:
    """The interlocking's switch positions of a train on a network, at t = 0 (latched live)."""
    if scenario.network is not None:
        writer.write(f"{namespace}/{INTERLOCKING_TOPIC}", convert.switch_positions_to_msg(mc, 0.0, scenario.interlocking), 0)


def scenario_from_bag(bag: str | Path) -> Scenario:
    """The scenario a bag was made from (its /train/scenario topic)."""
    with BagReader(bag) as reader:
        return _recorded_scenario(reader)


def _recorded_scenario(reader) -> Scenario:
    for _, typename, _, data in reader.cdr([SCENARIO_TOPIC, LINE_SCENARIO_TOPIC]):
        return Scenario.from_dict(yaml.safe_load(reader.deserialize(data, typename).data))
    raise ValueError(f"{reader.path} has no {SCENARIO_TOPIC} or {LINE_SCENARIO_TOPIC} topic: give the scenario "
                     f"explicitly")
