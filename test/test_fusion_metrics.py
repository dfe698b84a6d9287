"""The coupling figures of core/fusion/ (tools/fusion_metrics.py): what counts as a write of the
bookkeeping, and the figures issue 49 asks to stay at 0."""
from __future__ import annotations

import ast

from train_localization.tools import fusion_metrics

FIELDS = {"suspended", "events", "motion_views", "nis"}


def _written(src: str) -> set:
    return fusion_metrics._written_fields(ast.parse(src), FIELDS)


def test_writes_through_the_record_an_alias_an_item_or_a_mutating_call_count():
    assert _written("def f(self):\n    self.f.aux.suspended = {}") == {"suspended"}
    assert _written("def f(self):\n    held = self.f.aux\n    other = held\n    other.events += 1") == {"events"}
    assert _written("def f(aux):\n    aux.motion_views[0] = 1\n    aux.nis.pop('x')") == {"motion_views", "nis"}
    assert _written("def f(aux):\n    a, aux.suspended = 1, {}") == {"suspended"}
    assert _written("def f(aux):\n    setattr(aux, 'events', {})") == {"events"}


def test_reads_and_other_records_fields_do_not_count():
    assert _written("def f(aux, r):\n    x = aux.suspended\n    r.nis = 1.0\n    aux.events.get('a')") == set()


def test_each_state_field_has_one_writer_and_no_policy_calls_another():
    figures = fusion_metrics.measure()
    assert figures["state fields written from more than one file"] == "0 ()"
    assert figures["calls between policies"] == 0 and figures["self.f._ reads outside filter.py"] == 0
