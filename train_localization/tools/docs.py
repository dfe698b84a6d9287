"""Markdown tables of every sensor node's parameters (kept in docs/nodes.md) and the example
params files of every node but the fusion (config/params/<node>.yaml).

  python -m train_localization.tools.docs            # print the tables
  python -m train_localization.tools.docs --write    # update docs/nodes.md and config/params
test/test_readme.py checks that docs/nodes.md holds exactly this text between the
markers ``<!-- sensor-params:begin/end -->`` and ``<!-- fusion-params:begin/end -->``.
"""
from __future__ import annotations

from dataclasses import replace

from ..core.sensors import NODE_NAMES, spec
from ..core.sensors.base import COMMON_PARAMS, Param
from ..nodes.common import FUTURE_TOLERANCE

BEGIN, END = "<!-- sensor-params:begin -->", "<!-- sensor-params:end -->"
FUSION_BEGIN, FUSION_END = "<!-- fusion-params:begin -->", "<!-- fusion-params:end -->"


def _value(v) -> str:
    return f"`{v!r}`" if not isinstance(v, str) else f"`\"{v}\"`"



def sensor_params_markdown() -> str:
    from ..nodes.sensor import NODE_PARAMS
    timeout = NODE_PARAMS["input_timeout"]
    lines = ["Common to every sensor node: `mode` (`\"sim\"` | `\"ingest\"`), `scenario` (YAML: track, "
             "vehicle, seed, overrides), `track` (YAML, when no scenario), `future_tolerance` (double, "
             f"default {FUTURE_TOLERANCE} s, 0.001 .. 3600: a raw block (ingest) or a truth state (sim) stamped further "
             "ahead of the node clock is refused as `future`; on the wall clock, a truth state further ahead of the "
             "truth's own time, the last one taken plus the wall time since: a simulator's truth is not in the wall "
             f"clock's time), `input_timeout` (double, default {timeout.default} s, {timeout.limits[0]:g} .. "
             f"{timeout.limits[1]:g}: no raw block (ingest) or truth state (sim) received for this long while "
             "active, none since activation included, and the node's /diagnostics are WARN, saying so), and:", "",
             "| parameter | default | meaning |", "|---|---|---|"]
    lines += [f"| `{n}` | {_value(p.default)} | {p.meaning} |" for n, p in COMMON_PARAMS.items()]
    for node in NODE_NAMES:
        s = spec(node)
        outs = ", ".join(f"`sensors/{s.sensor}/{o}`" if o != "sections" else "`wayside/sections`" for o in s.outputs)
        lines += ["", f"#### `{node}` — {s.description}", "",
                  f"Seeds: {', '.join(s.seeds)}. Raw: `sensors/{s.sensor}/raw`. Output: {outs}.", "",
                  "| parameter | default | meaning |", "|---|---|---|"]
        lines += [f"| `{n}` | {_value(p.default)} | {p.meaning.replace('|', '/')} |" for n, p in s.params.items()]
    return "\n".join(lines) + "\n"


def _field_rows(fields_, base) -> list[str]:
    """Table rows of a config's fields: name, default in ``base``, description with its limits."""
    rows = []
    for f in fields_:
        limits = f.metadata.get("limits")
        doc = f.metadata.get("doc", "") + (f" [{limits[0]:g} .. {limits[1]:g}]" if limits else "")
        rows.append(f"| `{f.name}` | {_value(getattr(base, f.name))} | {doc.replace('|', '/')} |")
    return rows


def fusion_params_markdown() -> str:
    """Parameters of the fusion node beyond scenario/track/sensors/publish_rate/frames:
    every global tuning field of core.fusion.FusionConfig, then the per-sensor error-model
    fields (nested parameters ``<sensor>.<field>``)."""
    from dataclasses import fields

    from ..core.fusion import FusionConfig
    from ..core.sensors.base import ErrorModel
    lines = ["| parameter | default | meaning |", "|---|---|---|"]
    lines += _field_rows([f for f in FusionConfig.tuning_fields() if f.name != "track_id"], FusionConfig())
    names = ", ".join(f"`{f.name}`" for f in fields(ErrorModel) if f.name not in ("sensor", "measures"))
    lines += ["", "Per configured sensor, the fields of its own error model (core/sensors/base.py "
              f"`ErrorModel`) are nested parameters `<sensor>.<field>`: {names} (`faults` as a comma-separated "
              "string). Their defaults are the sensor's own model; a different value (a params file, `-p "
              "doppler.scale_sigma:=0.01`) overrides it and is logged at start-up."]
    from ..core.network.config import NetworkConfig
    lines += ["", "On a network (a scenario whose track has `sections`, docs/network.md), also the track-selective "
              "fusion's (core/network/config.py `NetworkConfig`; `start_section` and `start_direction` default to the "
              "train's route):", "", "| parameter | default | meaning |", "|---|---|---|"]
    lines += _field_rows(fields(NetworkConfig), NetworkConfig())
    return "\n".join(lines) + "\n"


# the track of a sensor node's example where the default one has none of its equipment
EXAMPLE_TRACKS = {"checkin_loop": "config/track_hsst.yaml", "track_circuit_receiver": "config/track_highspeed.yaml"}
# what the example of a node that is no sensor node sets beyond the defaults: the inputs it needs to start
EXAMPLES = {
    "simulator": {"scenario": "config/scenario_demo.yaml"},
    "replayer": {"bag": "bags/stop_and_go.mcap"},
    "speed_controller": {"scenario": "config/scenario_etcs_stop.yaml"},
    "association": {"scenario": "config/scenario_line_conventional.yaml"},
    "standard_inputs": {"scenario": "config/scenario_drivers.yaml", "navsat.topic": "/gnss/fix",
                        "imu.topic": "/imu/data", "odometry.topic": "/wheel/odometry"},
    "nmea_ingest": {"udp.port": 10110},
    "can_ingest": {"interface": "virtual"},   # starts anywhere; socketcan vcan0 / can0 on a real bus
}
# the ``managed`` parameter of the lifecycle nodes (nodes/common.py ManagedNode) in their tables
MANAGED = {"managed": Param(False, "true: a lifecycle manager configures and activates the node")}


def _header(node: str, what: str) -> list[str]:
    """The first lines of a params file: ``what`` it holds, the command that runs it."""
    return [f"# {what} (generated: python -m train_localization.tools.docs --write).",
            f"# ros2 run train_localization {node} --ros-args --params-file config/params/{node}.yaml",
            "# Keyed /** : applies to the node whatever its name and namespace (one node per file).",
            "/**:", "  ros__parameters:"]


def sensor_params_file(node: str) -> str:
    """Example ROS params file of a sensor node: every parameter at its default, described."""
    s = spec(node)
    track = EXAMPLE_TRACKS.get(node, "config/track_conventional.yaml")
    from ..nodes.sensor import NODE_PARAMS
    lines = _header(node, f"Parameters of the {node} node at their defaults")
    own = {**NODE_PARAMS, "track": replace(NODE_PARAMS["track"], default=track)}
    lines += [f"    {name}: {_yaml_value(p.default)}  # {p.meaning}" for name, p in own.items()]
    lines.append("    managed: false  # true: a lifecycle manager configures and activates the node")
    for name, p in {**COMMON_PARAMS, **s.params}.items():
        if isinstance(p.default, list) and not p.default:
            continue   # an empty list has no ROS parameter type: the default applies
        value = _yaml_value(p.default)
        lines.append(f"    {name}: {value}  # {p.meaning}")
    return "\n".join(lines) + "\n"


def node_tables() -> dict[str, tuple[dict, tuple]]:
    """Every node that is neither a sensor node nor the fusion: (its parameter table, name ->
    core Param, as the node declares them; the names whose default is the scenario's)."""
    from ..nodes import (association, atp_supervision, can_ingest, etcs_location, nmea_ingest, recorder, replayer,
                         simulator, speed_controller, standard_inputs, stator, wayside)
    return {"simulator": (simulator.PARAMS, ()), "recorder": (recorder.PARAMS, ()),
            "replayer": (replayer.PARAMS, ()), "wayside_occupancy": (wayside.OCCUPANCY_PARAMS, ()),
            "neutral_section_controller": (wayside.CONTROLLER_PARAMS, ()),
            "crosscheck": (wayside.CROSSCHECK_PARAMS, ()),
            "association": (association.PARAMS, association.SCENARIO_DEFAULTS),
            "speed_controller": (speed_controller.PARAMS, speed_controller.SCENARIO_DEFAULTS),
            "stator_section_controller": (stator.PARAMS, ()), "etcs_location": (etcs_location.PARAMS, ()),
            "atp_supervision": (atp_supervision.PARAMS, ()),
            "standard_inputs": ({**standard_inputs.NODE_PARAMS, **MANAGED}, ()),
            "nmea_ingest": ({**nmea_ingest.PARAMS, **MANAGED}, ()),
            "can_ingest": ({**can_ingest.PARAMS, **MANAGED}, ())}


def node_params_file(node: str) -> str:
    """Example ROS params file of a node of node_tables(): every parameter described, at its
    default but for the example's inputs (EXAMPLES); one whose default is the scenario's is a
    comment (set, it would override the scenario)."""
    params, from_scenario = node_tables()[node]
    example = EXAMPLES.get(node, {})
    lines = _header(node, f"Parameters of the {node} node at their defaults" + (", with an example's inputs"
                                                                               if example else ""))
    for name, p in params.items():
        value = _yaml_value(example.get(name, p.default))
        if name in from_scenario:
            lines.append(f"    # {name}: {value}  # {p.meaning} (unset: the scenario's)")
        else:
            lines.append(f"    {name}: {value}  # {p.meaning}")
    return "\n".join(lines) + "\n"


def _yaml_value(v) -> str:
    """A parameter default in YAML that every parser reads with its type (a float keeps a
    '.' in its mantissa: PyYAML reads 5e-05 as a string)."""
    import json
    import math
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        if math.isnan(v):
            return ".nan"
        if math.isinf(v):
            return ".inf" if v > 0 else "-.inf"
        text = repr(v)
        mantissa, e, exponent = text.partition("e")
        return (mantissa if "." in mantissa else mantissa + ".0") + (e + exponent if e else "")
    return json.dumps(v)


# the fusion's example: a choice of sensors and tuning, and the nested form of the per-sensor
# error-model overrides (its parameters are tabled in docs/nodes.md)
FUSION_EXAMPLE = """\
    track: config/track_conventional.yaml
    sensors: [doppler, wheel, eurobalise, axle_counter]
    publish_rate: 200.0          # [Hz], (0, 1000]; may change at run time
    map_frame: map
    base_frame: base_link
    odom_frame: ""               # set (e.g. odom) when another source publishes odom -> base_link
    hold_late_inputs: false      # true: inputs wait for their sensors' declared latency (states that late)
    confidence: 0.999            # probability of [position_min, position_max]; 0.5 .. 1 - 1e-9
    lost_stddev: 100.0           # [m] position 1-sigma above which the mode is LOST; 0.01 .. 1e6
    history: 2.0                 # [s] how late a measurement may be; 0.01 .. 60
    # per-sensor error model: only what differs from the sensor's own model is an override
    doppler:
      scale_sigma: 0.004         # 1-sigma scale error of this radar (its datasheet; default 0.005)
      timeout: 1.0               # [s] longest silence while in use
    wheel:
      faults: "slip,slide"       # fault modes the filter checks for
"""


def params_files() -> dict[str, str]:
    """config/params/<node>.yaml for every node."""
    files = {f"{node}.yaml": sensor_params_file(node) for node in NODE_NAMES}
    files.update({f"{node}.yaml": node_params_file(node) for node in node_tables()})
    files["fusion.yaml"] = "\n".join(_header("fusion", "Example parameters of the fusion node: sensors, tuning, error-model overrides")) + "\n" + FUSION_EXAMPLE
    return files


def splice(text: str, begin: str, end: str, body: str) -> str:
    """``text`` with the part between the markers replaced by ``body``."""
    head, rest = text.split(begin, 1)
    return head + begin + "\n" + body + end + rest.split(end, 1)[1]


if __name__ == "__main__":
    import sys
    from ..core.paths import SOURCE_ROOT
    readme = SOURCE_ROOT / "docs" / "nodes.md"
    if sys.argv[1:] == ["--write"]:
        text = splice(readme.read_text(), BEGIN, END, sensor_params_markdown())
        readme.write_text(splice(text, FUSION_BEGIN, FUSION_END, fusion_params_markdown()))
        for name, body in params_files().items():
            (SOURCE_ROOT / "config" / "params" / name).write_text(body)
    else:
        print(sensor_params_markdown() + "\n" + fusion_params_markdown(), end="")
