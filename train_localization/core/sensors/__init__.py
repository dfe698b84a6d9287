"""Registry of the sensor kinds: node name -> SensorSpec (imported lazily)."""
from __future__ import annotations

import importlib

from .base import SensorSpec

# node name -> module defining SPEC
_MODULES = {
    "doppler_radar": "doppler",
    "wheel_sensor": "wheel",
    "eurobalise_reader": "eurobalise",
    "lrl_scanner": "lrl",
    "inpo_receiver": "inpo",
    "pattern_belt": "pattern_belt",
    "mmwave_ranging": "mmwave",
    "mmwave_tdoa": "mmwave_tdoa",
    "axle_counter": "axle_counter",
    "lzb_receiver": "lzb",
    "track_circuit_receiver": "track_circuit",
    "dgps_receiver": "dgps",
    "tag_reader": "transponder",
    "coil_counter": "coil_counter",
    "emf_observer": "emf_observer",
    "checkin_loop": "checkin",
    "pole_position": "pole_position",
    "rig_loop_receiver": "rig_loop",
    "gyro": "gyro",
    "accelerometer": "accelerometer",
}

NODE_NAMES = tuple(_MODULES)


def sensor_classes() -> dict[str, str]:
    """Sensor node name -> its sensor class (the topic key sensors/<class>/...), every kind."""
    return {node: spec(node).sensor for node in NODE_NAMES}


def spec(node: str) -> SensorSpec:
    """The SensorSpec of a sensor node name; KeyError lists the known ones."""
    if node not in _MODULES:
        raise KeyError(f"unknown sensor {node!r}; known: {', '.join(NODE_NAMES)}")
    return importlib.import_module(f"{__name__}.{_MODULES[node]}").SPEC
