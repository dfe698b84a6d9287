"""Scenario description and the ground-truth motion it produces.

A scenario (YAML in config/) names a track, a vehicle, a speed profile, the sensors
with their parameter overrides, and a random seed. The same scenario and seed give
bit-identical truth and sensor output (random streams are derived from the seed and
the device name, never from the order in which devices are created).

Speed profile: a list of legs run in order. Each leg drives the speed towards
``speed`` [m/s] (signed; a reversal passes through 0) with at most ``accel``
[m/s^2] when speeding up and ``decel`` [m/s^2] when slowing down, the acceleration
changing at most by ``jerk`` [m/s^3]; once there it holds the speed for ``hold``
[s]. ``speed: 0`` with ``hold`` is a stop with a dwell time.

Several trains on one line (``trains:``): each entry has its own ``name``, ``vehicle``,
``initial``, ``profile``, on-board ``sensors`` and ``fusion``; the top-level
``wayside: {sensors: ...}`` lists the wayside equipment, which sees every train. Each
train's graph lives in the namespace ``/<name>``, the wayside in ``/wayside``. A
scenario without ``trains:`` is one train named ``train`` (namespace ``/train``).
``Scenario.train(name)`` is one train's scenario: what a one-train run needs (its
vehicle, profile, on-board sensors, fusion, its own random streams).

ATP: ``atp`` gives the supervision of the train to an end of authority (the parameters of
core/etcs/supervision.py, ``end_of_authority`` among them); with ``control`` the supervision's
brake acts on the motion (core/etcs/supervised_run.py, the atp_supervision node).

Drivers' standard messages: ``standard_inputs`` (the standard_inputs node's input parameters,
core/ingest/inputs.py PARAMS: ``navsat.topic``, ``imu.topic``, ``odometry.topic``, ...) names the
topics on which the train's sensors come as sensor_msgs/NavSatFix, Imu, nav_msgs/Odometry, read
with the models of its ``sensors``; the replay of a recording of them reads those topics
(core/offline/replay.py).

Closed loop: instead of ``profile`` a scenario may give ``control`` (a speed controller and
its set-points, core/control.py) and ``dynamics`` (the vehicle's drive and resistance,
core/dynamics.py); its motion then comes from ``core.offline.closed_loop`` (offline) or from
the simulator node integrating the controller's traction command, not from ``trajectory``.

Loading checks every block through the check of the subsystem that owns it (sensor names
and placement: core/sensors; control, dynamics, atp, changeover, network devices: their
modules), imported at the top: the subsystems take the data they share with the scenario from
core/truth.py and core/vehicle.py, never from this module, so no import cycle runs through it
(test/test_imports.py).
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from . import paths
from .control import control_config
from .dynamics import DYNAMICS_PARAMS
from .etcs.supervision import supervision_params
from .ingest.inputs import StandardInputs, input_values
from .network.model import Network, NetworkError, is_network
from .network.path import route_path, route_track
from .network.wayside import WAYSIDE_KINDS, check_device
from .sensors import NODE_NAMES, spec as sensor_spec
from .sensors.base import resolve_params
from .track import Track
from .truth import Leg, LineTruth, Trajectory, TruthBuffer, TruthState
from .vehicle import Vehicle
from .wayside.changeover import ChangeoverError, Site

# the data of a scenario kept in their own modules (the subsystems use them without the scenario)
__all__ = ["Leg", "LineTruth", "NETWORK_SENSORS", "Scenario", "ScenarioError", "TRAIN", "Trajectory", "TruthBuffer",
           "TruthState", "Vehicle", "WAYSIDE"]


class ScenarioError(ValueError):
    """A scenario that cannot be run, with the reason."""


TRAIN = "train"          # the name (and namespace) of the train of a one-train scenario
WAYSIDE = "wayside"      # the namespace of the wayside equipment of a line
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")   # a train name is a ROS namespace token


@dataclass
class Scenario:
    name: str
    track: Track
    vehicle: Vehicle
    legs: list[Leg]
    duration: float
    seed: int = 0
    start_position: float = 0.0
    start_speed: float = 0.0
    truth_rate: float = 100.0            # ground_truth/state rate [Hz]
    sensors: dict[str, dict] = field(default_factory=dict)  # sensor node name -> parameters
    fusion: dict = field(default_factory=dict)  # FusionConfig overrides (core/fusion/config.py)
    source: Path | None = None
    description: dict = field(default_factory=dict, repr=False)  # the YAML, track inlined
    control: dict = field(default_factory=dict)    # closed-loop speed control (core/control.py); {} = profile
    dynamics: dict = field(default_factory=dict)   # drive and resistance parameters (core/dynamics.py)
    atp: dict = field(default_factory=dict)        # ATP supervision to an end of authority (core/etcs/supervision.py)
    standard_inputs: dict = field(default_factory=dict)  # the drivers' standard topics (core/ingest/inputs.py)
    # name -> one train's scenario: {train_name: self} but for a line (set by from_dict)
    trains: dict[str, "Scenario"] = field(default_factory=dict, init=False, repr=False, compare=False)
    wayside: dict[str, dict] = field(default_factory=dict)  # wayside sensor node name -> parameters
    association: dict = field(default_factory=dict)  # core/association.py Associator overrides
    changeover: dict = field(default_factory=dict)   # wayside changeover section (core/wayside/changeover.py)
    line: bool = False          # described with ``trains:`` (even a single one): namespaces /<name>
    train_name: str = TRAIN     # the train this scenario drives (one-train scenarios and train views)
    rng_prefix: tuple = ()      # random streams of a line's train: prefixed by its name
    # on a network (core/network, docs/network.md): the network, the train's route through it
    # (a TrackPath; ``track`` is then its route line) and the switch positions the interlocking
    # reports for it (switch -> "B1"/"B2", "" unknown)
    network: object = field(default=None, repr=False, compare=False)
    route: object = field(default=None, repr=False, compare=False)
    interlocking: dict = field(default_factory=dict)

    def __post_init__(self):
        self.trains = {self.train_name: self}

    @property
    def train_names(self) -> list[str]:
        return list(self.trains)

    def train(self, name: str) -> "Scenario":
        """One train's scenario (itself for a one-train scenario); ScenarioError if unknown."""
        if name not in self.trains:
            raise ScenarioError(f"no train {name!r} in scenario {self.name}; trains: {', '.join(self.trains)}")
        return self.trains[name]

    def for_namespace(self, namespace: str) -> "Scenario":
        """The scenario a node in ``namespace`` runs: on a line, the train of that name (its
        vehicle, on-board sensors, fusion) or, in /wayside, the wayside equipment (as a
        scenario whose sensors are the wayside ones); a one-train scenario in any namespace."""
        if not self.line:
            return self
        name = namespace.strip("/").split("/")[-1]
        if name == WAYSIDE:
            return Scenario(name=f"{self.name}/{WAYSIDE}", track=self.track, vehicle=self.wayside_vehicle(), legs=[],
                            duration=self.duration, seed=self.seed, truth_rate=self.truth_rate,
                            sensors=dict(self.wayside), source=self.source, description=self.description,
                            line=True, train_name=WAYSIDE, rng_prefix=(WAYSIDE,), network=self.network)
        if name not in self.trains:
            raise ScenarioError(f"namespace {namespace!r} names no train of scenario {self.name} (trains: "
                                f"{', '.join(self.trains)}) and is not /{WAYSIDE}")
        return self.trains[name]

    def changeover_site(self):
        """The line's changeover section (core/wayside/changeover.py Site), or None."""
        if not self.changeover:
            return None
        return Site.from_config(self.changeover, self.track)

    def wayside_vehicle(self) -> Vehicle:
        """The vehicle whose data the wayside decoders take by default (axle layout): the
        trains' own if they all have the same, else a vehicle without axles (no layout: the
        decoders cover what they cannot identify; a scenario can give the parameters)."""
        vehicles = [tr.vehicle for tr in self.trains.values()]
        return vehicles[0] if all(v == vehicles[0] for v in vehicles) else Vehicle(kind="mixed")

    def to_yaml(self) -> str:
        """Self-contained YAML of the scenario (track inlined): recorded into bags."""
        return yaml.safe_dump(self.description, sort_keys=False)

    def rng(self, *names: str) -> np.random.Generator:
        """Independent random stream for one device, stable across runs and orderings."""
        digest = hashlib.sha256("/".join(self.rng_prefix + names).encode()).digest()
        return np.random.default_rng([int(self.seed), int.from_bytes(digest[:8], "little")])

    def trajectory(self, dt: float = 1e-3) -> "Trajectory":
        if len(self.trains) > 1 or self.trains.get(self.train_name) is not self:
            raise ScenarioError(f"scenario {self.name} has several trains: take one train's trajectory "
                                f"(scenario.train(name).trajectory())")
        if self.control:
            raise ScenarioError(f"scenario {self.name} runs under closed-loop control: its motion comes from "
                                "core.offline.closed_loop or the simulator node, not from a profile")
        traj = Trajectory.from_legs(self.legs, self.start_position, self.start_speed, self.duration, dt)
        if self.track.closed:
            traj.period = self.track.length
        return traj

    @classmethod
    def from_yaml(cls, path: str | Path) -> "Scenario":
        path = paths.resolve(path)
        try:
            with open(path, encoding="utf-8") as fh:
                data = yaml.safe_load(fh)
        except OSError as exc:
            raise ScenarioError(f"cannot read scenario {path}: {exc.strerror}") from None
        return cls.from_dict(data, source=path)

    @classmethod
    def from_dict(cls, data: dict, source: Path | None = None) -> "Scenario":
        if not isinstance(data, dict):
            raise ScenarioError("a scenario is a mapping of keys (name, track, duration, ...)")
        try:
            track_data = _track_data(data["track"], source)
            network = _network(track_data) if is_network(track_data) else None
            track = None if network else Track.from_dict(track_data)
            common = dict(name=str(data.get("name", source.stem if source else "scenario")), track=track,
                          duration=float(data["duration"]), seed=int(data.get("seed", 0)),
                          truth_rate=float(data.get("truth_rate", 100.0)), source=source,
                          description={**data, "track": track_data})
            if "trains" not in data:
                fields = _train_fields(data)
                if network:
                    fields.update(_route_fields(data, network, TRAIN, fields))
                    common.pop("track")
                scenario = cls(**common, **fields)
            else:
                scenario = _line(cls, data, common, network)
        except KeyError as exc:
            raise ScenarioError(f"scenario lacks the key {exc}") from None
        except (TypeError, AttributeError) as exc:
            raise ScenarioError(f"scenario has a malformed entry: {exc}") from None
        if scenario.duration <= 0:
            raise ScenarioError("scenario duration must be > 0 s")
        for train in scenario.trains.values():
            if not 0 <= train.start_position <= train.track.length:
                what = f"train {train.train_name}: " if scenario.line else ""
                raise ScenarioError(f"{what}initial position {train.start_position} m is off the track")
        if scenario.line:
            _check_line(scenario)
        for train in scenario.trains.values():
            if train.control:
                try:
                    control_config(train.control)
                    resolve_params(DYNAMICS_PARAMS, train.dynamics)
                except ValueError as exc:
                    raise ScenarioError(f"scenario {scenario.name}: {exc}") from None
            if train.atp:
                try:
                    supervision_params(train.atp)
                except ValueError as exc:
                    raise ScenarioError(f"scenario {scenario.name}: atp: {exc}") from None
            if train.standard_inputs:
                try:
                    StandardInputs.build(input_values(train.standard_inputs), train.track, train.sensors,
                                         train.vehicle)
                except ValueError as exc:
                    raise ScenarioError(f"scenario {scenario.name}: standard_inputs: {exc}") from None
        return scenario

    def orientation(self) -> int:
        """+1 if the train runs towards increasing chainage, -1 if decreasing: the sign of its
        first moving speed (a train starts front first), +1 if it never moves."""
        for v in [self.start_speed] + [leg.speed for leg in self.legs]:
            if abs(v) > 1e-9:
                return 1 if v > 0 else -1
        return 1

    def extent(self) -> tuple[float, float]:
        """(lowest, highest) chainage [m] the train covers at the start (front and length); on a
        network, chainage of the first route section."""
        front, tail = self.start_position, self.start_position - self.orientation() * self.vehicle.length
        if self.route is not None:
            step = self.route.steps[0]
            front, tail = step.chainage(front + self.route.begin), step.chainage(tail + self.route.begin)
        return min(front, tail), max(front, tail)

    def start_section(self) -> str:
        """The section the train starts on: its route's first on a network, else its track."""
        return self.route.steps[0].section if self.route is not None else self.track.track_id


def _track_data(track_ref, source: Path | None) -> dict:
    if isinstance(track_ref, dict):
        return track_ref
    track_path = Path(track_ref)
    if not track_path.is_absolute() and source is not None and (source.parent / track_path.name).exists():
        track_path = source.parent / track_path.name
    with open(paths.resolve(track_path), encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def _train_fields(data: dict) -> dict:
    """The Scenario fields of one train: vehicle, profile, initial state, sensors, fusion, and
    the closed-loop control and dynamics (instead of a profile)."""
    veh = data.get("vehicle", {}) or {}
    vehicle = Vehicle(kind=str(veh.get("type", "conventional")), length=float(veh.get("length", 200.0)),
                      axles=tuple(float(a) for a in veh.get("axles", ()) or ()),
                      wheel_diameter=float(veh.get("wheel_diameter", 0.92)),
                      pantographs=tuple(float(a) for a in veh.get("pantographs", ()) or ()),
                      roof_bus=bool(veh.get("roof_bus", False)))
    bad = [a for a in vehicle.pantographs if not 0.0 <= a <= vehicle.length]
    if bad:
        raise ScenarioError(f"vehicle: pantograph offsets {bad} are not on the vehicle (0..{vehicle.length:g} m "
                            "behind the front)")
    control = dict(data.get("control", {}) or {})
    # a closed-loop train (``control``) needs no profile
    legs = [Leg(**{k: float(v) for k, v in leg.items()})
            for leg in (data.get("profile", []) if control else data["profile"]) or []]
    init = data.get("initial", {}) or {}
    return dict(vehicle=vehicle, legs=legs, start_position=float(init.get("position", 0.0)),
                start_speed=float(init.get("speed", 0.0)),
                sensors={name: dict(params or {}) for name, params in (data.get("sensors", {}) or {}).items()},
                fusion=dict(data.get("fusion", {}) or {}),
                control=control, dynamics=dict(data.get("dynamics", {}) or {}), atp=dict(data.get("atp", {}) or {}),
                standard_inputs=dict(data.get("standard_inputs", {}) or {}))


def _network(track_data: dict):
    """The Network of a track description with ``sections`` (ScenarioError in one line)."""
    try:
        return Network.from_dict(track_data)
    except NetworkError as exc:
        raise ScenarioError(f"network: {exc}") from None


# on-board sensors that work on a network (the equipment they need is of
# core/network/path.py ROUTE_KINDS; a 2-D fix is projected onto the whole network)
NETWORK_SENSORS = ("wheel_sensor", "doppler_radar", "eurobalise_reader", "tag_reader", "dgps_receiver", "gyro")
_ROUTE_KEYS = {"sections", "direction", "reported"}


def _route_fields(data: dict, network, name: str, fields: dict) -> dict:
    """A train's route through a network (``route:``): its TrackPath, route line (the
    scenario's ``track``), start (``initial.position`` is the chainage on the first section)
    and the switch positions the interlocking reports (the ways the route takes, unless
    ``reported`` says otherwise: a wrong way, or "" for unknown)."""
    what = f"train {name}: " if name != TRAIN else ""
    route = data.get("route")
    if not isinstance(route, dict) or "sections" not in route:
        raise ScenarioError(f"{what}on a network a train needs 'route: {{sections: [<section>, ...]}}'")
    unknown = set(route) - _ROUTE_KEYS
    if unknown:
        raise ScenarioError(f"{what}route: unknown keys {sorted(unknown)}; known: {sorted(_ROUTE_KEYS)}")
    others = [s for s in fields["sensors"] if s not in NETWORK_SENSORS]
    if others:
        on_sections = [n for n in NODE_NAMES if sensor_spec(n).sensor in WAYSIDE_KINDS]   # wayside on a network
        wayside = [s for s in others if s in on_sections]
        if wayside:
            raise ScenarioError(f"{what}{', '.join(wayside)}: wayside equipment, it sees every train (list it under "
                                f"wayside: sensors:)")
        raise ScenarioError(f"{what}sensors {others} do not work on a network yet; those that do: "
                            f"{', '.join(NETWORK_SENSORS)} on board, {', '.join(on_sections)} as wayside "
                            f"equipment")
    try:
        path = route_path(network, [str(x) for x in route["sections"] or []], int(route.get("direction", 1)))
        track = route_track(path, f"{network.network_id}:{name}")
    except NetworkError as exc:
        raise ScenarioError(f"{what}{exc}") from None
    switches = {n.node_id for n in network.switches()}
    reported = {**path.ways(), **{str(k): str(v or "") for k, v in (route.get("reported") or {}).items()}}
    for node, way in reported.items():
        if node not in switches:
            raise ScenarioError(f"{what}route: reported names {node!r}, which is no point switch of the network")
        if way not in ("B1", "B2", ""):
            raise ScenarioError(f"{what}route: reported way {way!r} of {node} must be B1, B2 or '' (unknown)")
    first = path.steps[0]
    chainage = fields["start_position"]
    if not 0.0 <= chainage <= first.length:
        raise ScenarioError(f"{what}initial position {chainage} m is off its first section {first.section} "
                            f"(0..{first.length:g} m)")
    return dict(network=network, route=path, track=track, interlocking=reported,
                start_position=first.distance(chainage) - path.begin)


def _line(cls, data: dict, common: dict, network=None) -> Scenario:
    """A scenario of several trains (``trains:`` list, ``wayside:`` equipment)."""
    entries = data["trains"]
    if not isinstance(entries, list) or not entries:
        raise ScenarioError("'trains' must be a non-empty list of trains")
    wayside_data = data.get("wayside", {}) or {}
    wayside = {name: dict(params or {}) for name, params in (wayside_data.get("sensors", {}) or {}).items()}
    if network and wayside_data.get("changeover"):
        raise ScenarioError("a changeover section on a network is not supported yet")
    trains = {}
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise ScenarioError(f"train {k}: an entry of 'trains' is a mapping, not {entry!r}")
        name = str(entry.get("name", ""))
        if not _NAME.match(name) or name == WAYSIDE:
            raise ScenarioError(f"train {k}: name {name!r} must be a letter then letters, digits or '_' "
                                f"(its ROS namespace), not {WAYSIDE!r}")
        if name in trains:
            raise ScenarioError(f"train name {name!r} is used twice")
        fields = _train_fields(entry)
        train_common = {**common, "name": f"{common['name']}/{name}"}
        if network:
            fields.update(_route_fields(entry, network, name, fields))
            train_common.pop("track")
        trains[name] = cls(**train_common, **fields, wayside=wayside, line=True, train_name=name, rng_prefix=(name,))
    first = next(iter(trains.values()))
    if network:   # the line's own track (what its wayside would see): the first train's route line
        common = {**common, "track": first.track}
    scenario = cls(**common, network=network, vehicle=first.vehicle, legs=[], sensors={}, fusion={}, wayside=wayside,
                   association=dict(data.get("association", {}) or {}),
                   changeover=dict(wayside_data.get("changeover", {}) or {}), line=True, train_name="")
    scenario.trains = trains
    return scenario


def _check_line(scenario: Scenario) -> None:
    """Sensors where they belong, and no two trains on the same metres at the start."""
    for node in scenario.wayside:
        try:
            sp = sensor_spec(node)
        except KeyError as exc:
            raise ScenarioError(f"wayside: {exc.args[0]}") from None
        if not sp.simulator.sees_all_trains:
            raise ScenarioError(f"wayside: {node} is on-board equipment (list it under a train's sensors)")
        if scenario.network is not None:
            try:
                check_device(sp, scenario.wayside[node] or {}, scenario.network)
            except NetworkError as exc:
                raise ScenarioError(f"wayside: {exc}") from None
    for train in scenario.trains.values():
        for node in train.sensors:
            try:
                sp = sensor_spec(node)
            except KeyError as exc:
                raise ScenarioError(f"train {train.train_name}: {exc.args[0]}") from None
            if sp.simulator.sees_all_trains:
                raise ScenarioError(f"train {train.train_name}: {node} is wayside equipment: on a line it "
                                    f"sees every train (list it under wayside: sensors:)")
    if scenario.changeover:
        try:
            scenario.changeover_site()
        except ChangeoverError as exc:
            raise ScenarioError(f"wayside: {exc}") from None
        if not any(tr.vehicle.pantographs for tr in scenario.trains.values()):
            raise ScenarioError("wayside: a changeover section needs trains with pantographs (vehicle: pantographs:)")
    ordered = sorted(scenario.trains.values(), key=lambda tr: (tr.start_section(), tr.extent()))
    for a, b in zip(ordered, ordered[1:]):
        if a.start_section() == b.start_section() and b.extent()[0] < a.extent()[1]:
            raise ScenarioError(f"trains {a.train_name} and {b.train_name} overlap at the start "
                                f"({a.extent()[0]:.1f}..{a.extent()[1]:.1f} m and "
                                f"{b.extent()[0]:.1f}..{b.extent()[1]:.1f} m)")
