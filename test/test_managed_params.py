"""Managed (lifecycle) nodes declare every parameter before configure: a manager lists them and
sets them while the node is unconfigured; configure takes what was set, the scenario's value
for the rest, and makes them read-only (over DDS)."""
from __future__ import annotations

from conftest import ROOT, ask, lifecycle_replies, spin_until

NS = ["-r", "__ns:=/train"]


def _client(node, srv, name):
    client = node.create_client(srv, name)
    assert spin_until(node, client.service_is_ready, 60.0), name
    return client


def _names(node, client) -> set[str]:
    from rcl_interfaces.srv import ListParameters
    reply = ask(node, client, ListParameters.Request())
    assert reply is not None
    return set(reply.result.names)


def _set(node, client, name: str, value: float):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
    return ask(node, client, SetParameters.Request(parameters=[Parameter(name=name, value=value)])).results[0]


def _get(node, client, name: str) -> float:
    from rcl_interfaces.srv import GetParameters
    return ask(node, client, GetParameters.Request(names=[name])).values[0].double_value


def _configure(node, change) -> bool:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    future = change.call_async(ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE)))
    assert spin_until(node, future.done, 30.0)
    return future.result().success


def test_managed_sensor_nodes_list_and_take_every_parameter_before_configure(ros_context, start_node):
    """gyro and mmwave_tdoa (they listed 3 parameters before configure, 16 after): the same
    names before and after; block_duration set while unconfigured is what configure takes;
    max_range, not set, is the scenario's (1,400 m: config/scenario_mlx_tdoa.yaml), and
    neither can be set once configured."""
    from lifecycle_msgs.srv import ChangeState
    from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters

    scenario = str(ROOT / "config" / "scenario_mlx_tdoa.yaml")
    procs = {"gyro": start_node("gyro", "--ros-args", *NS, "-p", "managed:=true", "-p", "mode:=ingest"),
             "mmwave_tdoa": start_node("mmwave_tdoa", "--ros-args", *NS, "-p", "managed:=true",
                                       "-p", "mode:=ingest", "-p", f"scenario:={scenario}")}
    node = ros_context.create_node("probe_managed_params", namespace="/train")
    try:
        for exe, proc in procs.items():
            lister = _client(node, ListParameters, f"{exe}/list_parameters")
            setter = _client(node, SetParameters, f"{exe}/set_parameters")
            getter = _client(node, GetParameters, f"{exe}/get_parameters")
            change = node.create_client(ChangeState, f"{exe}/change_state")
            assert lifecycle_replies(node, change), proc.output()
            before = _names(node, lister)
            assert {"mode", "scenario", "track", "future_tolerance", "block_duration"} <= before, before
            assert len(before) >= 16, before
            assert _set(node, setter, "block_duration", 0.1).successful
            assert _configure(node, change), proc.output()
            assert _names(node, lister) == before
            assert _get(node, getter, "block_duration") == 0.1
            refused = _set(node, setter, "block_duration", 0.2)
            assert not refused.successful and "read-only" in refused.reason.lower()
            if exe == "mmwave_tdoa":
                assert _get(node, getter, "max_range") == 1400.0
            assert proc.interrupt() == 0, proc.output()
    finally:
        node.destroy_node()


def test_the_managed_fusion_lists_and_takes_every_parameter_before_configure(ros_context, start_node):
    """The fusion declares before configure its own parameters, the tuning, the error-model
    fields of every sensor class and the network's; configure adds none, takes a tuning value
    and an error-model field set while unconfigured, and makes them read-only."""
    from lifecycle_msgs.srv import ChangeState
    from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters

    proc = start_node("fusion", "--ros-args", *NS, "-p", "managed:=true", "-p", "sensors:=[doppler]")
    node = ros_context.create_node("probe_managed_fusion", namespace="/train")
    try:
        lister = _client(node, ListParameters, "fusion/list_parameters")
        setter = _client(node, SetParameters, "fusion/set_parameters")
        getter = _client(node, GetParameters, "fusion/get_parameters")
        change = node.create_client(ChangeState, "fusion/change_state")
        assert lifecycle_replies(node, change), proc.output()
        before = _names(node, lister)
        assert {"scenario", "sensors", "history", "max_input_rate", "doppler.scale_sigma", "eurobalise.timeout",
                "start_section"} <= before, sorted(before)
        assert _set(node, setter, "history", 3.0).successful
        assert _set(node, setter, "doppler.scale_sigma", 0.01).successful
        assert _configure(node, change), proc.output()
        assert _names(node, lister) == before
        assert _get(node, getter, "history") == 3.0 and _get(node, getter, "doppler.scale_sigma") == 0.01
        assert "error model of doppler overridden: scale_sigma=0.01" in proc.output()
        refused = _set(node, setter, "history", 4.0)
        assert not refused.successful and "read-only" in refused.reason.lower()
        assert proc.interrupt() == 0, proc.output()
    finally:
        node.destroy_node()
