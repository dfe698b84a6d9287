"""The node graphs, in one place: used by tools/demo.py and launch/.

Each entry is (executable, node name, parameters). Everything runs in the
``/train`` namespace, with use_sim_time where the simulator or the replayer publishes /clock
(the on-board graph of a train fed from outside: on the host's clock unless told otherwise).
A line of several trains (``line_graph``) puts each node in its own namespace: each
train's sensor nodes and fusion in ``/<train>``, the wayside sensor nodes in ``/wayside``.
"""
from __future__ import annotations

NAMESPACE = "/train"


LEAN_EXCLUDE = ["/rosout", "/parameter_events", "/tf", f"{NAMESPACE}/localization/odometry"]


def lean_exclude(trains) -> list[str]:
    """LEAN_EXCLUDE of a line: what the fused states of the ``trains`` (names) determine."""
    return LEAN_EXCLUDE[:3] + [f"/{name}/localization/odometry" for name in trains]


def graph_options(sc) -> dict:
    """The optional nodes a scenario (core.scenario.Scenario) needs in ``demo_graph``: the speed
    controller for ``control``, the stator section controller for a track with stator sections,
    the ETCS location function for a track with ETCS data (``etcs``), the ATP supervision for
    ``atp`` (its parameters, the train's orientation)."""
    from .core.wayside.stator import KIND as STATOR_KIND
    atp = {**{"orientation": sc.orientation()}, **sc.atp} if sc.atp else None
    etcs = sc.network.etcs if sc.network is not None else sc.track.etcs   # a network's block, or the track's
    return {"controller": bool(sc.control), "stator": bool(sc.track.items(STATOR_KIND)),
            "etcs": bool(etcs) or atp is not None, "atp": atp}


def etcs_nodes(scenario: str, etcs: bool, atp: dict | None) -> list[tuple[str, str, dict]]:
    """(executable, name, parameters) of one train's ETCS location function (if ``etcs``) and
    its ATP supervision (if ``atp``: its parameters), on the simulation's clock."""
    nodes = []
    if etcs:
        nodes.append(("etcs_location", "etcs_location", {"scenario": scenario, "use_sim_time": True}))
    if atp is not None:
        nodes.append(("atp_supervision", "atp_supervision", {**atp, "use_sim_time": True}))
    return nodes


def demo_graph(scenario: str, sensors: list[str], bag: str, rate: float = 1.0,
               exclude: list[str] | None = None, record: bool = True,
               controller: bool = False, stator: bool = False, etcs: bool = False,
               atp: dict | None = None, fusion_rate: float | None = None) -> list[tuple[str, str, dict]]:
    """Recorder (if ``record``), one sensor node per entry of ``sensors`` (node names),
    fusion, the speed controller (if ``controller``: a scenario with a ``control`` section,
    whose simulator drives the vehicle by its traction command), the stator section
    controller (if ``stator``: a track with long-stator sections, core/wayside/stator.py,
    fed from the fused state), the ETCS location function (if ``etcs``: a track with ETCS
    data, core/etcs), the ATP supervision (if ``atp``: its parameters), simulator
    (``graph_options`` gives the flags of a scenario). ``fusion_rate``: the fusion's
    publish_rate [Hz] (default: the node's, 200 Hz).

    ``exclude``: topics the recorder leaves out (default: only /rosout and
    /parameter_events; LEAN_EXCLUDE also drops what the fused state determines).
    """
    from .core.sensors import spec
    classes = [spec(n).sensor for n in sensors]
    nodes = []
    if record:
        recorder = {"output": bag, "use_sim_time": True}
        if exclude:
            recorder["exclude"] = list(exclude)
        nodes.append(("recorder", "recorder", recorder))
    nodes += [(name, name, {"mode": "sim", "scenario": scenario, "use_sim_time": True}) for name in sensors]
    fusion = {"scenario": scenario, "sensors": classes, "use_sim_time": True}
    if fusion_rate is not None:
        fusion["publish_rate"] = float(fusion_rate)
    nodes.append(("fusion", "fusion", fusion))
    if controller:
        nodes.append(("speed_controller", "speed_controller", {"scenario": scenario, "use_sim_time": True}))
    if stator:
        nodes.append(("stator_section_controller", "stator_section_controller",
                      {"scenario": scenario, "use_sim_time": True}))
    nodes += etcs_nodes(scenario, etcs, atp)
    # the simulator starts once the recorder and every sensor node listen to the truth and the
    # fusion publishes (a fusion still starting would miss the first seconds of fused states)
    nodes.append(("simulator", "simulator", {"scenario": scenario, "rate": rate, "start_delay": 1.0,
                                             "wait_for_subscribers": len(sensors) + int(record),
                                             "wait_for_publisher": "localization/state"}))
    return nodes


def onboard_graph(scenario: str, sensors: list[str], out_bag: str, record: bool = True,
                  use_sim_time: bool = False, standard_inputs: dict | None = None) -> list[tuple[str, str, dict]]:
    """The on-board graph of a train whose raw sensor blocks come from outside: recorder (if
    ``record``), one sensor node per entry of ``sensors`` (node names) in ingest mode (it
    decodes what arrives on sensors/<sensor>/raw: the device drivers', or a bag player's),
    and the fusion. ``use_sim_time``: the nodes take their time from /clock (a player of
    recorded data publishes it) instead of the host's clock. ``standard_inputs``: the
    parameters of a standard_inputs node (docs/integration.md, "From your drivers") that feeds
    the fusion from the drivers' standard messages; a sensor of a class it publishes gets no
    ingest node, and the fusion takes its classes too (ValueError in one line for parameters
    that configure no input)."""
    from .core.sensors import spec
    from_standard = []
    if standard_inputs is not None:
        from .core.ingest.inputs import PARAMS, StandardInputs, input_values
        from .core.scenario import Scenario
        sc = Scenario.from_yaml(scenario)
        values = input_values({k: v for k, v in standard_inputs.items() if k in PARAMS})   # not the node's own
        from_standard = StandardInputs.build(values, sc.track, sc.sensors, sc.vehicle).sensor_classes()
    ingest = [n for n in sensors if spec(n).sensor not in from_standard]
    classes = list(dict.fromkeys([spec(n).sensor for n in ingest] + from_standard))
    nodes = []
    if record:
        nodes.append(("recorder", "recorder", {"output": out_bag, "use_sim_time": use_sim_time}))
    nodes += [(name, name, {"mode": "ingest", "scenario": scenario, "use_sim_time": use_sim_time})
              for name in ingest]
    if standard_inputs is not None:
        nodes.append(("standard_inputs", "standard_inputs",
                      {**standard_inputs, "scenario": scenario, "use_sim_time": use_sim_time}))
    nodes.append(("fusion", "fusion", {"scenario": scenario, "sensors": classes, "use_sim_time": use_sim_time}))
    return nodes


def replay_graph(bag: str, scenario: str, sensors: list[str], out_bag: str, rate: float = 1.0,
                 record: bool = True, namespace: str = NAMESPACE) -> list[tuple[str, str, dict]]:
    """The on-board graph (onboard_graph, on the bag's time: use_sim_time) and the replayer of
    ``bag`` (recorded under NAMESPACE): its raw topics, ground truth and scenario, moved to
    ``namespace``.

    The replayer publishes /clock from the bag's time line and starts once every sensor
    node (and the recorder) listens to what it plays and every node listens to /clock."""
    from .core.sensors import spec
    classes = [spec(n).sensor for n in sensors]
    played = [f"{NAMESPACE}/sensors/{c}/raw" for c in classes] + [f"{NAMESPACE}/ground_truth/state",
                                                                   f"{NAMESPACE}/scenario"]
    nodes = onboard_graph(scenario, sensors, out_bag, record, use_sim_time=True)
    replayer = {"bag": bag, "rate": rate, "topics": played,
                # one subscriber per raw topic (its sensor node), and the recorder on every played topic;
                # every node on /clock (the fusion listens to no played topic: without it, the first
                # seconds were played before it was up on a loaded machine)
                "wait_for_subscribers": len(classes) + (len(played) if record else 0),
                "wait_for_clock_subscribers": len(classes) + 1 + int(record),
                # the fusion has /clock from its creation, its inputs once set up (its state publisher,
                # its subscriptions to the sensor nodes' measurements: without them, on a loaded machine
                # the first seconds' measurements could go to nobody)
                "wait_for_publishers": [f"{namespace.rstrip('/')}/localization/state"],
                "wait_for_subscribed": [f"{namespace.rstrip('/')}/sensors/{spec(n).sensor}/{kind}" for n in sensors
                                        for kind in spec(n).outputs if kind != "sections"]}
    if namespace.rstrip("/") != NAMESPACE:
        replayer["remap"] = [f"{t}:={namespace.rstrip('/')}{t[len(NAMESPACE):]}" for t in played]
    nodes.append(("replayer", "replayer", replayer))
    return nodes


def line_graph(scenario: str, bag: str, rate: float = 1.0, record: bool = True,
               exclude: list[str] | None = None, fusion_rate: float | None = None) -> list[tuple[str, str, str, dict]]:
    """The graph of a line scenario (several trains), as (namespace, executable, node name,
    parameters): recorder (if ``record``) in /, per train its sensor nodes (ingest) and its
    fusion in /<train>, the wayside sensor nodes (ingest) and the association of their fixes
    with the trains in /wayside (with a changeover section also its combined detection and
    controller: ``wayside_occupancy``, ``neutral_section_controller``), per train with ETCS data or
    ``atp`` its ``etcs_location`` and ``atp_supervision`` (graph_options), and the simulator in
    /, which publishes every train's truth and the raw blocks of every device (the wayside
    ones see all trains; nodes/simulator.py). The sensor and fusion nodes take their train's
    part of the scenario from their namespace (Scenario.for_namespace). ``fusion_rate``: the
    fusions' publish_rate [Hz], default the node's."""
    from .core.scenario import WAYSIDE, Scenario
    from .core.sensors import spec
    line = Scenario.from_yaml(scenario)
    nodes = []
    if record:
        recorder = {"output": bag, "use_sim_time": True}
        if exclude:
            recorder["exclude"] = list(exclude)
        nodes.append(("/", "recorder", "recorder", recorder))
    ingest = {"mode": "ingest", "scenario": scenario, "use_sim_time": True}
    for name, train in line.trains.items():
        nodes += [(f"/{name}", node, node, dict(ingest)) for node in train.sensors]
        classes = [spec(n).sensor for n in [*train.sensors, *line.wayside]]
        fusion = {"scenario": scenario, "sensors": classes, "use_sim_time": True}
        if fusion_rate is not None:
            fusion["publish_rate"] = float(fusion_rate)
        nodes.append((f"/{name}", "fusion", "fusion", fusion))
        # a train with ETCS data on its track or network, or supervised (``atp``): its location
        # function and its supervision, as in demo_graph (the speed controller is not run on a line)
        options = graph_options(train)
        nodes += [(f"/{name}", *node) for node in etcs_nodes(scenario, options["etcs"], options["atp"])]
    nodes += [(f"/{WAYSIDE}", node, node, dict(ingest)) for node in line.wayside]
    site = line.changeover_site()
    if site is not None:
        # the changeover section's combined detection and its controller (nodes/wayside.py), on the
        # wayside sensor nodes' section reports; the controller's ABB commands go on changeover/abb*
        voting = {"sections": site.section_strings(), **line.changeover.get("occupancy", {}), "use_sim_time": True}
        nodes.append((f"/{WAYSIDE}", "wayside_occupancy", "wayside_occupancy", dict(voting)))
        nodes.append((f"/{WAYSIDE}", "neutral_section_controller", "neutral_section_controller",
                      {**voting, **line.changeover.get("controller", {})}))
    # wayside fixes to the train that explains them, into its namespace (nodes/association.py)
    nodes.append((f"/{WAYSIDE}", "association", "association", {"scenario": scenario, "use_sim_time": True}))
    # the simulator starts once every sensor node listens to its raw blocks and the recorder to
    # every truth and raw topic
    raw_topics = sum(len(tr.sensors) for tr in line.trains.values()) + len(line.wayside)
    subscribers = raw_topics + (raw_topics + len(line.trains) if record else 0)
    nodes.append(("/", "simulator", "simulator", {"scenario": scenario, "rate": rate, "start_delay": 1.0,
                                                  "wait_for_subscribers": subscribers}))
    return nodes


def ros_args(name: str, params: dict, namespace: str = NAMESPACE) -> list[str]:
    """Command-line ROS arguments for one node."""
    args = ["--ros-args", "-r", f"__ns:={namespace}", "-r", f"__node:={name}"]
    for key, value in params.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, (list, tuple)):   # strings quoted: YAML flow items may hold ':'
            value = "[" + ",".join(f"'{v}'" if isinstance(v, str) else str(v) for v in value) + "]"
        args += ["-p", f"{key}:={value}"]
    return args
