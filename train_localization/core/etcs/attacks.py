"""The attacks of the randomised supervised stops (``tools/etcs_stops.py --attacks``;
docs/reliability.md): what an attacker on the same DDS domain publishes to the chain behind the
fusion, drawn per run. The supervisor of core/etcs/supervised_run.py injects the ETCS ones where
the nodes would receive them; ``stator_under_attack`` runs the long-stator controller of seed 000
(core/wayside/stator.py) on the run's fused states with spoofed ones among them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KMH = 1.0 / 3.6


# what an attacker on the DDS domain publishes in the randomised stops (``Attack.kind``)
ATTACKS = ("state_ahead", "standstill_report", "far_group", "unknown_flood", "silent_linked", "stator_spoof")


@dataclass(frozen=True)
class Attack:
    """One attack of a run: ``kind`` (ATTACKS) from ``t`` [s]; ``ahead`` [s] a spoofed state's
    stamp ahead of the clock; ``group`` the far group a spoofed fix names, ``consistent`` its
    position at that group (else at the train); ``rate`` [1/s] and ``duration`` [s] of a flood
    (of unknown balise ids, or of spoofed states ``offset`` [m] from the train to the stator
    controller)."""
    kind: str
    t: float
    ahead: float = 0.0
    offset: float = 0.0
    group: str = ""
    consistent: bool = False
    rate: float = 0.0
    duration: float = 0.0


def draw_attacks(seed: int, data: dict) -> tuple[Attack, ...]:
    """The attacks of randomised stop ``seed`` (``draw_stop``'s scenario dict ``data``, whose
    reader may be given silent groups): each kind of ATTACKS with probability 1/2, at least one;
    drawn from a generator of their own, so the run's line, train and faults are those without."""
    rng = np.random.default_rng([seed, 48])
    d = data["draw"]
    v_top = d["top_speed_kmh"] * KMH
    t_brake = (d["eoa_distance"] - v_top ** 2 / (2.0 * d["assumed_deceleration"])) / v_top
    kinds = [k for k in ATTACKS if rng.random() < 0.5] or [ATTACKS[int(rng.integers(0, len(ATTACKS)))]]
    groups = sorted({b["group"] for b in data["track"]["equipment"]["eurobalise"]})
    start = data["initial"]["position"]
    out = []
    for kind in kinds:
        if kind == "state_ahead":
            out.append(Attack(kind, float(rng.uniform(5.0, max(6.0, t_brake))), ahead=float(10 ** rng.uniform(0.5, 6.0))))
        elif kind == "standstill_report":
            out.append(Attack(kind, 0.0))
        elif kind == "far_group":
            far = [g for g, b in ((b["group"], b) for b in data["track"]["equipment"]["eurobalise"])
                   if abs(b["position"] - start) > 5000.0] or groups[-1:]
            out.append(Attack(kind, float(rng.choice([0.5, rng.uniform(10.0, max(11.0, t_brake))])),
                              group=str(far[int(rng.integers(0, len(far)))]), consistent=bool(rng.random() < 0.5)))
        elif kind == "unknown_flood":
            out.append(Attack(kind, float(rng.uniform(5.0, max(6.0, t_brake))), rate=float(rng.uniform(700.0, 5000.0)),
                              duration=5.0))
        elif kind == "stator_spoof":
            out.append(Attack(kind, float(rng.uniform(5.0, max(6.0, t_brake))), offset=float(rng.choice([-1.0, 1.0]))
                              * float(rng.uniform(500.0, 5000.0)), rate=1000.0, duration=2.0))
        else:       # two linked groups on the way, silent one after the other
            eoa = data["atp"]["end_of_authority"]
            way = [g for g in groups if start + 50.0 < _group_position(data, g) < eoa - 50.0]
            if len(way) >= 2:
                k = int(rng.integers(0, len(way) - 1))
                silent = ",".join(f"{g}{s}" for g in way[k:k + 2] for s in "ab")
                reader = data["sensors"]["eurobalise_reader"]
                reader["silent_balises"] = ",".join(filter(None, (reader.get("silent_balises", ""), silent)))
                out.append(Attack(kind, 0.0, group=",".join(way[k:k + 2])))
    return tuple(out)


def _group_position(data: dict, group: str) -> float:
    return min(b["position"] for b in data["track"]["equipment"]["eurobalise"] if b["group"] == group)


VEHICLE_LENGTH = 200.0      # [m] the train of the drawn stops (draw_stop)


def stator_under_attack(loop, orientation: int, attack: Attack) -> dict:
    """The long-stator sectional feeding (core/wayside/stator.py) of the run's line, laid in
    sections of the least length the controller needs at the run's top speed, fed from the run's
    fused states (``loop``: offline.ClosedLoopResult) with and without ``attack``'s spoofed states
    (``rate`` per second for ``duration`` s, ``ahead`` m from the fused position, stamped now),
    scored on the true motion: the thrust lost and the sections switched off under the vehicle in
    both, and what the controller refused."""
    from ..wayside import stator
    params = stator.controller_params()
    top = max(abs(s.speed) for s in loop.truth)
    length = stator.min_section_length(params, VEHICLE_LENGTH, 1.1 * top + 1.0, 20.0, params["max_state_age"])
    end = max(loop.distance) + 2.0 * length
    items = stator.lay_sections(min(loop.distance) - 2.0 * length, end, length)
    layout = stator.Layout.of([stator.Section(it["id"], it["position"], it["end"], f"INV{k % 2 + 1}")
                               for k, it in enumerate(items)])
    vehicle = stator.Vehicle(VEHICLE_LENGTH, orientation)
    real = [stator.TrainView(e.stamp, e.mode in (1, 2), e.position_min, e.position_max, e.speed, e.speed_stddev)
            for e in loop.estimates]
    times, front = np.array([s.stamp for s in loop.truth]), np.array(loop.distance)
    stamps = attack.t + np.arange(int(attack.rate * attack.duration)) / attack.rate
    spoofed = np.interp(stamps, times, front) + attack.offset
    spoofs = [stator.TrainView(float(t), True, float(x) - 1.0, float(x) + 1.0, 0.0, 0.01) for t, x in zip(stamps, spoofed)]
    out = {}
    for name, views in (("clean", real), ("attacked", sorted(real + spoofs, key=lambda v: v.stamp))):
        ctrl = stator.StatorController(layout, {"train": vehicle}, None, (layout.starts[0], layout.ends[-1]))
        j = 0
        for now in np.arange(views[0].stamp, views[-1].stamp + 1e-9, params["period"]).tolist():
            while j < len(views) and views[j].stamp <= now + 1e-9:
                ctrl.admit("train", views[j], now)
                j += 1
            ctrl.update(now)
        report = stator.evaluate(layout, ctrl.commands, times, front, vehicle).as_dict()
        out[name] = {"thrust_loss_s": report["thrust_loss_s"], "switched_off_under_vehicle":
                     report["switched_off_under_vehicle"], "refused": ctrl.refused()}
    return out
