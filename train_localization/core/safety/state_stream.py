"""One stream of states (fused states, ETCS reports) as a consumer admits it: the stream's
checks (admission.py) and then the kinematic plausibility (plausibility.py), in that order, so
that a refused state moves neither the stream's order nor the motion reference."""
from __future__ import annotations

from ..measurements import MAX_CHAINAGE, MAX_SPEED
from ..signals import InputRejected
from .admission import StreamAdmission, StreamLimits
from .plausibility import Motion, MotionGate

CHAINAGE, SPEED = (-MAX_CHAINAGE, MAX_CHAINAGE), (-MAX_SPEED, MAX_SPEED)   # any train's [m], [m/s]


def claim_checks(s) -> dict:
    """StreamAdmission.check's keyword checks of a state ``s`` that claims a position (attributes
    ``position``, ``position_min``, ``position_max`` [m], ``speed``, ``speed_stddev`` [m/s]):
    every number finite (``nan``), the interval and the speed within any train's
    (``implausible``)."""
    return {"values": {"position": s.position, "position_min": s.position_min, "position_max": s.position_max,
                       "speed": s.speed, "speed_stddev": s.speed_stddev},
            "limits": {"position_min": CHAINAGE, "position_max": CHAINAGE, "speed": SPEED,
                       "speed_stddev": (0.0, MAX_SPEED)}}


class StateStream:
    """``admit(motion, now, ...)`` -> None (admitted) or the refusal (counted by reason in
    ``refused``); ``stale(now)`` once nothing was admitted for the time-out. ``motion``: what
    the state says of the front (plausibility.Motion); the keyword checks are
    StreamAdmission.check's (values, ids, sizes, limits)."""

    def __init__(self, name: str, limits: StreamLimits | None = None, gate: MotionGate | None = None):
        self.stream = StreamAdmission(name, limits)
        self.gate = gate or MotionGate()

    @property
    def refused(self):
        return self.stream.refused

    @property
    def admitted(self) -> int:
        return self.stream.admitted

    def admit(self, motion: Motion, now: float | None, **checks) -> InputRejected | None:
        try:
            self.stream.check(motion.t, now, **checks)
            self.gate.check(motion)
        except InputRejected as exc:
            return self.stream.refuse(exc)
        self.stream.accept(motion.t, now)
        self.gate.accept(motion)
        return None

    def waiting_since(self, now: float) -> None:
        self.stream.waiting_since(now)

    def silence(self, now: float) -> float:
        return self.stream.silence(now)

    def stale(self, now: float) -> bool:
        return self.stream.stale(now)
