"""Typed records of the ETCS location function and its consumers (docs/etcs.md); the messages
EtcsLocation, EtcsEvent and AtpCommand carry the same fields (core/etcs/convert in the nodes)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum


class Reaction(IntEnum):
    """Q_LINKREACTION of a linked balise group (SUBSET-026 section 3.16.2.3 / 7.5.1.113)."""
    NONE = 0
    SERVICE_BRAKE = 1
    TRAIN_TRIP = 2


class EventKind(IntEnum):
    """What an EtcsEvent reports (values of EtcsEvent.KIND_*)."""
    LRBG = 0
    OUTSIDE_WINDOW = 1
    MISSED_LINKED_GROUP = 2
    WRONG_DIRECTION = 3
    NOT_LINKED = 4
    UNKNOWN_GROUP = 5
    ODOMETER_IMPAIRED = 6
    ODOMETER_RESTORED = 7
    REFERENCE_REJECTED = 8


class QDirLrbg(IntEnum):
    """Q_DIRLRBG: the train's orientation against the LRBG's (EtcsLocation.Q_DIRLRBG_*)."""
    REVERSE = 0
    NOMINAL = 1
    UNKNOWN = 2


@dataclass(frozen=True)
class PathSection:
    """One section of the path a report on a network follows (docs/network.md, "ETCS on a
    network"): chainage c [m] of ``section`` lies at path distance ``origin + direction * c`` [m]
    (``direction`` +1 where the path runs along the section's chainage)."""
    section: str
    direction: int
    origin: float

    def distance(self, chainage: float) -> float:
        """Path distance [m] of ``chainage`` [m] on the section."""
        return self.origin + self.direction * chainage


@dataclass(frozen=True)
class LocationReport:
    """One ETCS location report (EtcsLocation). Chainages [m]; ``ahead`` is the train's orientation.
    On a network ``track_id`` is the network's, the front ends are path distances along ``path``
    and ``lrbg_track_id`` the section the LRBG lies on."""
    t: float                       # time of validity [s]
    track_id: str
    nid_lrbg: str                  # "" before the first LRBG
    d_lrbg: float                  # estimated front end from the LRBG along its orientation [m]; NaN without
    q_dirlrbg: QDirLrbg
    q_locacc: float                # Q_LOCACC of the LRBG [m]; NaN without
    l_doubtover: float             # [m] >= 0
    l_doubtunder: float            # [m] >= 0
    estimated_front_end: float     # chainage [m]
    min_safe_front_end: float      # chainage [m], least far ahead
    max_safe_front_end: float      # chainage [m], furthest ahead
    v_est: float                   # along the train's orientation [m/s]
    v_ura: float                   # [m/s] >= 0
    odometer_impaired: bool
    previous_lrbgs: tuple[str, ...]  # newest first
    mode: int                      # TrainState.MODE_* of the fused state
    lrbg_track_id: str = ""        # the LRBG's section (on a single line its track); "" without an LRBG
    path: tuple[PathSection, ...] = ()   # on a network: the followed path (travel order); () on a single line

    def path_distance(self, section: str, chainage: float) -> float | None:
        """Path distance [m] of ``chainage`` on ``section`` along the report's path (its first
        passage), None if the path does not contain the section."""
        step = next((p for p in self.path if p.section == section), None)
        return None if step is None else step.distance(chainage)

    @property
    def has_position(self) -> bool:
        """True when the report claims a position (a fused state that is NOMINAL or DEGRADED)."""
        return self.mode in (1, 2) and math.isfinite(self.min_safe_front_end) and math.isfinite(self.max_safe_front_end)


@dataclass(frozen=True)
class LocationEvent:
    """One EtcsEvent: a linking or odometer-monitoring event and the reaction it asks for."""
    t: float                       # [s]
    kind: EventKind
    nid_bg: str
    reaction: Reaction
    detail: str
