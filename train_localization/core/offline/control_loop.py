"""Speed control through the localisation, offline (seed 003 section 4.3).

``closed_loop`` steps dynamics (core/dynamics.py), the scenario's sensor simulators and
decoders, the fusion and the speed controller (core/control.py) together in increments of the
truth step: the sensor pipelines already take the truth state by state (core/pipeline.py), so
the loop hands them the state the dynamics reached instead of a precomputed trajectory, and
the controller acts on the newest fused state at every step; an optional ``supervisor``
(t, RunResult so far) -> brake commands its brake at each step.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from ..control import SpeedController, control_config
from ..convert import canonical
from ..dynamics import Dynamics
from ..fusion import FusionRunner, fusion_config
from ..pipeline import sensor_pipelines
from .feed import FusionFeed, RunResult


@dataclass
class ClosedLoopResult:
    """A closed-loop run, step by step, with its set-points, dynamics, controller and runner."""

    truth: list = field(default_factory=list)        # TruthState (chainage wrapped)
    distance: list = field(default_factory=list)     # unwrapped true distance [m]
    estimates: list = field(default_factory=list)    # Estimate
    commands: list = field(default_factory=list)     # (t [s], set-point [m/s], thrust command [N])
    fv_speed: list = field(default_factory=list)     # (t [s], F/V output [m/s]) of rig-loop receivers
    brakes: list = field(default_factory=list)       # (t [s], Brake) of the supervisor, when one is given
    measurements: list = field(default_factory=list)
    rejected: dict = field(default_factory=dict)
    setpoints: tuple = ()
    dynamics: object = None
    controller: object = None
    runner: object = None


def closed_loop(scenario, t_end: float | None = None, fusion_rate: float = 200.0,
                supervisor: Callable[[float, "RunResult"], int] | None = None) -> ClosedLoopResult:
    """Run a scenario with ``control`` in closed loop: dynamics -> sensors -> fusion -> PID -> dynamics.

    At each truth step (1 / truth_rate) the controller's command of the step before acts on the
    dynamics, the sensors simulate and decode the blocks the new state completes, the fusion
    takes their measurements and makes its states up to the step, and the controller acts on the
    newest of them. A scenario whose track gives no absolute position (the rig) states where
    the vehicle starts in its fusion tuning (``initial_position``, as the live fusion node's
    parameter); from there the fusion counts.

    ``supervisor`` (optional; e.g. the ETCS location function and the ATP supervision on the
    fused states): called at every truth step ``t`` [s] after the fusion, before the
    controller, with the RunResult so far (``estimates`` up to t); it returns the brake to
    command (Brake / AtpCommand.BRAKE_*), handed to ``SpeedController.set_brake`` and recorded
    in ``ClosedLoopResult.brakes``. Without it the loop is as before.
    """

    if not scenario.control:
        raise ValueError(f"scenario {scenario.name} has no 'control' section")
    params, setpoints = control_config(scenario.control)
    dyn = Dynamics(scenario.dynamics, scenario.track, scenario.start_position, scenario.start_speed)
    ctrl = SpeedController(params, setpoints, dyn.force_limit)
    pipes = sensor_pipelines(scenario)
    runner = FusionRunner(fusion_config(scenario), fusion_rate)
    run = RunResult(runner=runner)
    out = FusionFeed(runner, run, None, None, scenario.track)
    res = ClosedLoopResult(setpoints=setpoints, dynamics=dyn, controller=ctrl, runner=runner)
    rig_pipes = [p for p in pipes if p.spec.sensor == "rig_loop"]
    t_end = scenario.duration if t_end is None else t_end
    dt = 1.0 / scenario.truth_rate
    for k in range(int(round(t_end * scenario.truth_rate)) + 1):
        t = canonical(k * dt)
        if k:
            dyn.step(dt)
        state = dyn.state(t)
        res.truth.append(state)
        res.distance.append(dyn.distance)
        for pipe in pipes:
            for block in pipe.on_truth(state):
                out.decode(pipe, block, t)
        out.states(t)
        est = run.estimates[-1] if run.estimates else None
        if supervisor is not None:
            ctrl.set_brake(supervisor(t, run))
            dyn.set_brake(ctrl.brake_demand)
            res.brakes.append((t, ctrl.brake))
        if est is None:
            force = 0.0
        else:
            force = ctrl.update(t, est.speed, est.acceleration, est.speed_stddev)
        dyn.set_command(force)
        res.commands.append((t, ctrl.setpoint(t), force))
        for pipe in rig_pipes:
            res.fv_speed.append((t, pipe.decoder.stats["fv_speed"]))
    out.flush()
    res.estimates, res.measurements, res.rejected = run.estimates, run.measurements, run.rejected
    return res
