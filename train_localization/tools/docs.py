"""Markdown tables of every sensor node's parameters (kept in README.md).

  python -m train_localization.tools.docs > /tmp/params.md
test/test_readme.py checks that README.md holds exactly this text between the
markers ``<!-- sensor-params:begin -->`` and ``<!-- sensor-params:end -->``.
"""
from __future__ import annotations

from ..core.sensors import NODE_NAMES, spec
from ..core.sensors.base import COMMON_PARAMS

BEGIN, END = "<!-- sensor-params:begin -->", "<!-- sensor-params:end -->"


def _value(v) -> str:
    return f"`{v!r}`" if not isinstance(v, str) else f"`\"{v}\"`"


def sensor_params_markdown() -> str:
    lines = ["Common to every sensor node: `mode` (`\"sim\"` | `\"ingest\"`), `scenario` (YAML: track, "
             "vehicle, seed, overrides), `track` (YAML, when no scenario), and:", "",
             "| parameter | default | meaning |", "|---|---|---|"]
    lines += [f"| `{n}` | {_value(p.default)} | {p.description} |" for n, p in COMMON_PARAMS.items()]
    for node in NODE_NAMES:
        s = spec(node)
        outs = ", ".join(f"`sensors/{s.sensor}/{o}`" if o != "sections" else "`wayside/sections`" for o in s.outputs)
        lines += ["", f"#### `{node}` — {s.description}", "",
                  f"Seeds: {', '.join(s.seeds)}. Raw: `sensors/{s.sensor}/raw`. Output: {outs}.", "",
                  "| parameter | default | meaning |", "|---|---|---|"]
        lines += [f"| `{n}` | {_value(p.default)} | {p.description.replace('|', '/')} |" for n, p in s.params.items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(sensor_params_markdown(), end="")
