"""The DDS fuzz command against live nodes: malformed input rejected and counted by reason,
every node alive, valid input after it accepted, and every attack that is not one bad message
withstood (train_localization/tools/fuzz.py, fuzz_attacks.py)."""
from __future__ import annotations

import json
import os

from train_localization.tools import fuzz, fuzz_attacks

NODES = ["doppler_radar", "mmwave_ranging", "fusion"]
# enough for every malformed kind once per node (about half of the messages are malformed)
MESSAGES = 2 * max(len(fuzz.RAW_KINDS), len(fuzz.FUSION_KINDS)) + 16


def _count(sent: dict, *kinds: str) -> int:
    return sum(sent.get(k, 0) for k in kinds)


def test_fuzz_command_rejects_every_malformed_kind_and_keeps_the_nodes_alive(tmp_path, capsys):
    """The message mix, then the attacks. Each attack had worked: a set_position of stddev 1e200
    killed the fusion, one /clock message 1e6 s ahead stopped its states for good, a truth state
    stamped + 1000 s made a sensor node in simulator mode burst 20,000 blocks and refuse every
    real state after it, another train's state stamped + 1e6 s blinded the line's association
    (``stamp_back`` for every real one), and a flood of 4,400 messages/s stopped the states; the
    ETCS chain's attacks (issue 48) are described in fuzz_attacks.py's module doc."""
    report = tmp_path / "fuzz.json"
    domain = int(os.environ["ROS_DOMAIN_ID"])   # the run's own domain (conftest)
    code = fuzz.main(["--nodes", ",".join(NODES), "--messages", str(MESSAGES), "--seed", "3",
                      "--domain-id", str(domain), "--log-dir", str(tmp_path / "logs"), "--json", str(report)])
    out = capsys.readouterr().out
    assert code == 0, out
    nodes = {n["node"]: n for n in json.loads(report.read_text())["nodes"]}
    assert list(nodes) == NODES
    for name, node in nodes.items():
        assert node["alive"] and node["exit_code"] == 0 and not node["failures"], (name, node, out)
        assert sum(node["sent"].values()) == MESSAGES
        # what the node counted on /diagnostics is exactly what the core predicts
        assert node["counted"] == {k: v for k, v in node["expected"].items() if v}, (name, out)
        # a bad message does not blind the input: the valid tail after the mix is accepted
        assert node["tail_sent"] >= 3 and node["tail_accepted"] == node["tail_sent"], (name, out)
        assert node["rss_before_mb"] > 0 and node["rss_after_mb"] > 0
        assert f"{name} " in out

    for name in ("doppler_radar", "mmwave_ranging"):   # both have a fixed channel layout
        sent, counted, kinds = nodes[name]["sent"], nodes[name]["counted"], nodes[name]["kinds"]
        assert set(fuzz.RAW_KINDS) <= set(sent), (name, sent)
        # kinds refused before the node's state is looked at: exactly their reason
        assert counted["nan"] == _count(sent, "nan_sample", "inf_sample")
        assert counted["shape"] == _count(sent, "empty_data", "ragged_data", "units_mismatch")
        assert counted["channels"] == _count(sent, "no_channels", "extra_channel", "renamed_channels")
        assert counted["sample_rate"] == _count(sent, *(k for k in fuzz.RAW_KINDS if k.startswith("rate_")))
        assert counted["sensor"] == sent["wrong_sensor"]
        assert counted["stamp"] == sent["stamp_overflow"]
        assert counted["too_large"] == _count(sent, "too_large", "at_limit") == 2
        assert counted["too_long"] == _count(sent, "long_unit_id", "long_channel") >= 2
        for kind, reason in fuzz.RAW_KINDS.items():
            if reason is not None:
                assert kinds[kind] == {reason: sent[kind]}, (name, kind, kinds[kind])
        # the sequence guard: duplicates and backwards blocks refused, never decoded
        assert kinds["duplicate"].keys() <= {"duplicate", "stamp_back"}
        assert kinds["seq_back"].keys() <= {"duplicate", "stamp_back"}
        assert kinds["stamp_back"].keys() <= {"duplicate", "stamp_back"}
        assert counted["accepted"] == kinds["good"].get("accepted", 0) + sum(nodes[name]["bad_accepted"].values())
        # nothing else than the replayed block under another unit_id is handled unexpectedly
        # (findings: fixed-reason kinds counted otherwise, valid blocks blinded too long)
        assert all(f.startswith("foreign_unit") for f in nodes[name]["findings"]), nodes[name]["findings"]

    sent, counted = nodes["fusion"]["sent"], nodes["fusion"]["counted"]
    assert set(fuzz.FUSION_KINDS) <= set(sent), sent
    for kind in ("future", "wrong_track", "off_track", "too_late", "duplicate"):
        assert counted[kind] == sent[kind], (kind, counted, sent)   # these kinds are named as their reason
    assert counted["wrong_sensor"] == _count(sent, "unknown_sensor", "foreign_sensor")
    assert counted["nan"] == _count(sent, "nan_value", "inf_value", "nan_stddev", "duration_nan")
    assert counted["stddev"] == _count(sent, "zero_stddev", "negative_stddev", "duration_zero")
    assert counted["implausible"] == _count(sent, "stddev_1e-300", "stddev_1e300", "speed_1e4", "position_1e12",
                                            "duration_1e-300", "distance_1e12")
    assert counted["too_long"] == _count(sent, "long_unit_id", "long_sensor", "long_track_id", "long_reference_id")
    assert counted["accepted"] == sent["good"]
    # the attacks that are not one bad message (tools/fuzz_attacks.py), each on nodes of its own
    attacks = {a["attack"]: a for a in json.loads(report.read_text())["attacks"]}
    assert list(attacks) == list(fuzz_attacks.ATTACKS)
    assert all(a["passed"] and set(a["exit_codes"].values()) == {0} for a in attacks.values()), attacks
    assert "shed" in attacks["flood"]["detail"] and "refused" in attacks["set_position"]["detail"]
    # the ETCS chain (etcs_location, atp_supervision): a standstill stamped +50 s / +1e6 s blinded
    # both to every real state, one report at v_est 0 released a held brake, one fix naming a
    # group 10 km away became the LRBG, a flood of unknown ids cut the reports to 3.8/s
    assert "refused as future 2 (expected 2), as motion 1" in attacks["etcs_state_ahead"]["detail"]
    assert "0 releases after it" in attacks["etcs_standstill_report"]["detail"]
    assert "emergency brake in" in attacks["etcs_standstill_report"]["detail"]
    assert "(8, 'BG010')" in attacks["etcs_far_group"]["detail"]
    assert "BG010" not in attacks["etcs_far_group"]["detail"].split("LRBGs reported")[1]
    assert "shed" in attacks["etcs_unknown_flood"]["detail"]
