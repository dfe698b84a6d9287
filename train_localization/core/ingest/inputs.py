"""The standard inputs of a train's drivers: their parameters and the ingests they configure.

One input per message type, each switched on by naming its topic (robot_localization's
``odom0`` / ``imu0``, here by type), each read against the error model of the project's sensor
kind it stands for: the same parameters (a scenario's ``sensors:`` entry or a sensor params
file, the fusion's too) floor its 1-sigma, and its measurements go where that sensor's would
(sensors/<class>/<kind>), so the fusion takes them unchanged (docs/integration.md, "From your
drivers").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..sensors import spec
from ..sensors.base import Param, check_declared, sensor_params
from . import records
from .imu import ImuIngest, ImuMount
from .navsat import NavSatIngest
from .speed import SpeedIngest

SPEED_SENSORS = ("wheel_sensor", "doppler_radar")

PARAMS = {
    "navsat.topic": Param("", "sensor_msgs/NavSatFix topic of a GNSS receiver; empty: no GNSS input"),
    "navsat.sensor": Param("dgps_receiver", "sensor kind whose model (parameters) reads the fixes; they go out on "
                                            "sensors/dgps/position"),
    "navsat.min_status": Param(1, "least NavSatStatus.status of a fix used: 0 FIX (autonomous), 1 SBAS, 2 GBAS "
                                  "(the DGPS error model is that of differential fixes)", (0, 2)),
    "imu.topic": Param("", "sensor_msgs/Imu topic; empty: no IMU input"),
    "imu.yaw_rate": Param(True, "publish the body's yaw rate as the gyro's (sensors/gyro/yaw_rate: the track "
                                "selection on a network), read by the gyro's parameters"),
    "imu.acceleration": Param(False, "publish the longitudinal acceleration as the accelerometer's "
                                     "(sensors/accelerometer/acceleration), read by the accelerometer's parameters; "
                                     "its gradient is placed by the TrainState of imu.position_topic"),
    "imu.position_topic": Param("localization/state", "TrainState topic that places the gradient for "
                                                      "imu.acceleration"),
    "imu.mount_rpy": Param([0.0, 0.0, 0.0], "roll, pitch, yaw [rad] of the IMU's frame in base_link (REP-145: "
                                            "the driver reports in its own frame)"),
    "imu.block_duration": Param(0.1, "IMU samples per decoded block [s]", (0.005, 10.0)),
    "imu.temperature": Param(25.0, "the IMU's temperature [degC] (sensor_msgs/Imu has none): bounds the "
                                   "accelerometer's temperature drift", (-40.0, 85.0)),
    "odometry.topic": Param("", "nav_msgs/Odometry topic of a speed odometer (its twist); empty: none"),
    "odometry.sensor": Param("wheel_sensor", "its sensor kind: wheel_sensor (distance increments, "
                                             "sensors/wheel/distance) or doppler_radar (speed, sensors/doppler/speed)"),
    "twist.topic": Param("", "geometry_msgs/TwistWithCovarianceStamped topic of a speed odometer; empty: none"),
    "twist.sensor": Param("doppler_radar", "its sensor kind: doppler_radar or wheel_sensor"),
    "direction": Param(1, "+1: base_link's x axis points towards increasing chainage (along the route on a "
                          "network); -1: against it", (-1, 1)),
    "max_gap": Param(1.0, "two speed messages of a wheel input further apart than this give no distance "
                          "increment [s]", (0.01, 60.0)),
}
check_declared(PARAMS, "ingest PARAMS")
# the ROS type of each input's messages (pkg/msg/Type)
NAVSAT_TYPE, IMU_TYPE = "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/Imu"
SPEED_TYPES = {"odometry": ("nav_msgs/msg/Odometry", records.twist_from_odometry),
               "twist": ("geometry_msgs/msg/TwistWithCovarianceStamped", records.twist_from_twist_stamped)}


def input_values(given: dict) -> dict:
    """Every PARAMS value: ``given`` (PARAMS name -> value) over the defaults. ValueError in one
    line for a name that is none of PARAMS."""
    unknown = sorted(set(given) - set(PARAMS))
    if unknown:
        raise ValueError(f"standard inputs: unknown parameters {unknown}; known: {sorted(PARAMS)}")
    return {name: given.get(name, p.default) for name, p in PARAMS.items()}


@dataclass(frozen=True)
class InputReader:
    """How one input topic is read: its messages' ROS type, the record of a message (admission,
    core/ingest/records.py) and the measurements of a record (its ingest)."""

    typename: str
    parse: Callable
    ingest: Callable

    def read(self, msg, admit: Callable = lambda record: None) -> list:
        """The measurements of one message, each validated (core/measurements.py); InputRejected
        with the reason for a message refused by its record's admission, by ``admit(record)`` (a
        node's clock: future stamps) or by the ingest. ``[]``: withheld (counted in the ingest's
        stats) or a block not yet complete."""
        record = self.parse(msg)
        admit(record)
        out = self.ingest(record)
        for m in out:
            m.validate()
        return out


@dataclass
class StandardInputs:
    """The ingests of the inputs named in ``values`` (PARAMS name -> value): topic -> ingest."""

    navsat: dict
    imu: dict
    speed: dict

    @classmethod
    def build(cls, values: dict, track, sensors: dict, vehicle) -> "StandardInputs":
        """``sensors``: sensor node name -> its parameter overrides (a scenario's, or a sensor
        params file's). ValueError in one line for what cannot be built."""
        direction = int(values["direction"])
        if direction not in (-1, 1):
            raise ValueError(f"parameter 'direction' must be 1 or -1, not {direction}")

        def params_of(node: str) -> dict:
            return sensor_params(spec(node), sensors.get(node, {}), vehicle)
        navsat, imu, speed = {}, {}, {}
        if values["navsat.topic"]:
            node = values["navsat.sensor"]
            if spec(node).sensor != "dgps":
                raise ValueError(f"parameter 'navsat.sensor': {node} is no GNSS receiver (dgps_receiver)")
            navsat[values["navsat.topic"]] = NavSatIngest(params_of(node), track, int(values["navsat.min_status"]))
        if values["imu.topic"]:
            rpy = [float(v) for v in values["imu.mount_rpy"]]
            if len(rpy) != 3:
                raise ValueError(f"parameter 'imu.mount_rpy' needs roll, pitch, yaw, not {rpy}")
            if not (values["imu.yaw_rate"] or values["imu.acceleration"]):
                raise ValueError("imu.topic is set but neither imu.yaw_rate nor imu.acceleration")
            imu[values["imu.topic"]] = ImuIngest(
                track, ImuMount(*rpy), float(values["imu.block_duration"]), float(values["imu.temperature"]),
                params_of("gyro") if values["imu.yaw_rate"] else None,
                params_of("accelerometer") if values["imu.acceleration"] else None, direction)
        for kind in ("odometry", "twist"):
            if not values[f"{kind}.topic"]:
                continue
            node = values[f"{kind}.sensor"]
            if node not in SPEED_SENSORS:
                raise ValueError(f"parameter '{kind}.sensor' must be one of {', '.join(SPEED_SENSORS)}, not {node!r}")
            p = params_of(node)
            model = spec(node).error_model(p, track, vehicle)
            speed[values[f"{kind}.topic"]] = (kind, SpeedIngest(model, p["unit_id"] or model.sensor, direction,
                                                                float(values["max_gap"])))
        if not (navsat or imu or speed):
            raise ValueError("no input configured: set at least one of navsat.topic, imu.topic, odometry.topic, "
                             "twist.topic")
        return cls(navsat, imu, speed)

    def readers(self) -> dict[str, InputReader]:
        """topic -> its InputReader, for every input configured."""
        out = {topic: InputReader(NAVSAT_TYPE, records.gnss_fix_from_msg,
                                  lambda r, i=ing: [f for f in [i.fix(r)] if f is not None])
               for topic, ing in self.navsat.items()}
        out.update({topic: InputReader(IMU_TYPE, records.imu_sample_from_msg, ing.add)
                    for topic, ing in self.imu.items()})
        out.update({topic: InputReader(*SPEED_TYPES[kind], ing.add) for topic, (kind, ing) in self.speed.items()})
        return out

    def sensor_classes(self) -> list[str]:
        """The sensor classes whose measurements these inputs publish (the fusion's ``sensors``)."""
        out = ["dgps"] * bool(self.navsat)
        for ing in self.imu.values():
            out += ["gyro"] * (ing.gyro is not None) + ["accelerometer"] * (ing.accelerometer is not None)
        out += [ing.model.sensor for _, ing in self.speed.values()]
        return list(dict.fromkeys(out))
