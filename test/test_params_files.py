"""Every example params file of config/params/ starts its node as its header says, and names
only parameters the node declares (every one of them, but for the fusion's hand-written one)."""
from __future__ import annotations

import ast
import subprocess
import time

from conftest import ROOT, NodeProcess, ask, spin_until

PARAMS_DIR = ROOT / "config" / "params"
BATCH = 6            # nodes started at once (2 cores: each import costs about a second of CPU)
START_TIMEOUT = 90.0   # [s] for a batch to answer list_parameters on a loaded host
# what rclpy declares in every node, not the node's own
ROS_PARAMETERS = {"use_sim_time", "start_type_description_service"}


class _NodeIn(NodeProcess):
    """A node run from the directory ``cwd``."""

    def __init__(self, exe: str, args: list[str], log, cwd):
        from train_localization.tools.demo import executable
        self.log_path = log
        self._log = open(log, "w")
        self.proc = subprocess.Popen([executable(exe)] + args, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True, cwd=cwd)


def _setup_nodes() -> set[str]:
    """The executables of setup.py's NODES."""
    setup = ast.parse((ROOT / "setup.py").read_text())
    return set(next(ast.literal_eval(st.value) for st in setup.body
                    if isinstance(st, ast.Assign) and getattr(st.targets[0], "id", "") == "NODES"))


def _header_command(path) -> list[str]:
    """The command line of the file's header, ``ros2 run train_localization <exe> <args>``."""
    header = path.read_text().splitlines()[1]
    prefix = "# ros2 run train_localization "
    assert header.startswith(prefix), f"{path.name}: header {header!r}"
    words = header[len(prefix):].split()
    assert words[0] == path.stem and words[1:] == ["--ros-args", "--params-file", f"config/params/{path.name}"], header
    return words


def _file_keys(path) -> set[str]:
    """(The parameter names the file sets: top level of its ros__parameters, a nested mapping
    as <name>.<field>; those it names in a comment, unset: their default is the scenario's)."""
    import re
    import yaml
    params = yaml.safe_load(path.read_text())["/**"]["ros__parameters"]
    keys = set()
    for name, value in params.items():
        keys |= {f"{name}.{k}" for k in value} if isinstance(value, dict) else {name}
    return keys, set(re.findall(r"^    # (\w+): .*\(unset: the scenario's\)$", path.read_text(), re.M))


def test_every_node_has_an_example_that_starts_it_as_its_header_says(ros_context, tmp_path):
    """Run from a directory that has the repository's config/ and bags/ (the header's relative
    paths; a recorder's output lands there), in batches: each node comes up (answers
    list_parameters), declares every parameter its file names (all it has, but the fusion's
    nested error-model fields), and exits 0 on SIGINT."""
    from rcl_interfaces.srv import ListParameters
    from train_localization.core.sensors import NODE_NAMES

    files = sorted(PARAMS_DIR.glob("*.yaml"))
    assert {f.stem for f in files} == _setup_nodes() | set(NODE_NAMES)
    for name in ("config", "bags"):
        (tmp_path / name).symlink_to(ROOT / name)
    probe = ros_context.create_node("probe_params_files")
    try:
        for start in range(0, len(files), BATCH):
            batch = files[start:start + BATCH]
            procs = {}
            for path in batch:
                words = _header_command(path)
                procs[path.stem] = _NodeIn(words[0], words[1:], tmp_path / f"{path.stem}.log", tmp_path)
            try:
                clients = {exe: probe.create_client(ListParameters, f"/{exe}/list_parameters") for exe in procs}
                deadline = time.monotonic() + START_TIMEOUT
                for exe, client in clients.items():
                    up = spin_until(probe, lambda: client.service_is_ready() or procs[exe].proc.poll() is not None,
                                    max(deadline - time.monotonic(), 1.0))
                    assert up and procs[exe].proc.poll() is None, f"{exe}: {procs[exe].output()}"
                    reply = ask(probe, client, ListParameters.Request())
                    assert reply is not None, exe
                    declared = set(reply.result.names) - ROS_PARAMETERS
                    keys, unset = _file_keys(PARAMS_DIR / f"{exe}.yaml")
                    assert keys <= declared, f"{exe}: the file sets undeclared {sorted(keys - declared)}"
                    if exe != "fusion":
                        assert declared == keys | unset, f"{exe}: not in its file {sorted(declared - keys - unset)}"
                for exe, proc in procs.items():
                    assert proc.interrupt(30.0) == 0, f"{exe}: {proc.output()}"
            finally:
                for proc in procs.values():
                    if proc.proc.poll() is None:
                        proc.proc.kill()
                        proc.proc.wait()
    finally:
        probe.destroy_node()
