"""ament_python package train_localization (README.md: install and the nodes it installs)."""
import ast
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "train_localization"

# One executable per node, installed under lib/train_localization/ (setup.cfg) so
# that `ros2 run train_localization <name>` finds it.
NODES = {
    "simulator": "train_localization.nodes.simulator:main",
    "fusion": "train_localization.nodes.fusion:main",
    "recorder": "train_localization.nodes.recorder:main",
    "replayer": "train_localization.nodes.replayer:main",
    "wayside_occupancy": "train_localization.nodes.wayside:main_occupancy",
    "neutral_section_controller": "train_localization.nodes.wayside:main_controller",
    "crosscheck": "train_localization.nodes.wayside:main_crosscheck",
    "association": "train_localization.nodes.association:main",
    "speed_controller": "train_localization.nodes.speed_controller:main",
    "stator_section_controller": "train_localization.nodes.stator:main",
    "etcs_location": "train_localization.nodes.etcs_location:main",
    "atp_supervision": "train_localization.nodes.atp_supervision:main",
    "standard_inputs": "train_localization.nodes.standard_inputs:main",
    "nmea_ingest": "train_localization.nodes.nmea_ingest:main",
    "can_ingest": "train_localization.nodes.can_ingest:main",
}


def _sensor_nodes() -> list[str]:
    """The sensor node names of the registry (``_MODULES`` of train_localization/core/sensors/
    __init__.py), read without importing the package (its dependencies may not be installed)."""
    source = Path(__file__).resolve().parent / PACKAGE / "core" / "sensors" / "__init__.py"
    for stmt in ast.parse(source.read_text(encoding="utf-8")).body:
        if isinstance(stmt, ast.Assign) and getattr(stmt.targets[0], "id", "") == "_MODULES":
            return list(ast.literal_eval(stmt.value))
    raise RuntimeError(f"{source}: no _MODULES registry")


SENSOR_NODES = _sensor_nodes()
TOOLS = {
    "tl_demo": "train_localization.tools.demo:main",
    "tl_replay": "train_localization.tools.replay:main",
    "tl_bench": "train_localization.tools.bench:main",
    "tl_campaign": "train_localization.tools.campaign:main",
    "tl_bag": "train_localization.tools.bag:main",
    "tl_fuzz": "train_localization.tools.fuzz:main",
    "tl_neutral": "train_localization.tools.neutral_campaign:main",
    "tl_rig": "train_localization.tools.rig:main",
}

console_scripts = [f"{name} = {target}" for name, target in NODES.items()]
console_scripts += [f"{name} = train_localization.nodes.sensor:main_{name}" for name in SENSOR_NODES]
console_scripts += [f"{name} = {target}" for name, target in TOOLS.items()]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.py")),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml")),
        ("share/" + PACKAGE + "/config/params", glob("config/params/*.yaml")),
        ("share/" + PACKAGE + "/config/devices", glob("config/devices/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="train_localization developers",
    maintainer_email="dev@train-localization.invalid",
    description="Along-track train localisation: physics-level sensor nodes, Kalman fusion, MCAP replay.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": console_scripts},
)
