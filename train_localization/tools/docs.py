"""Markdown tables of every sensor node's parameters (kept in README.md).

  python -m train_localization.tools.docs            # print them
  python -m train_localization.tools.docs --write    # update README.md
test/test_readme.py checks that README.md holds exactly this text between the
markers ``<!-- sensor-params:begin/end -->`` and ``<!-- fusion-params:begin/end -->``.
"""
from __future__ import annotations

from ..core.sensors import NODE_NAMES, spec
from ..core.sensors.base import COMMON_PARAMS

BEGIN, END = "<!-- sensor-params:begin -->", "<!-- sensor-params:end -->"
FUSION_BEGIN, FUSION_END = "<!-- fusion-params:begin -->", "<!-- fusion-params:end -->"


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


def fusion_params_markdown() -> str:
    """Parameters of the fusion node beyond scenario/track/sensors/publish_rate/frames:
    every global tuning field of core.fusion.FusionConfig, then the per-sensor error-model
    fields (nested parameters ``<sensor>.<field>``)."""
    from dataclasses import fields

    from ..core.fusion import FusionConfig
    from ..core.sensors.base import ErrorModel
    base = FusionConfig()
    lines = ["| parameter | default | meaning |", "|---|---|---|"]
    for f in FusionConfig.tuning_fields():
        if f.name == "track_id":
            continue
        value = getattr(base, f.name)
        lines.append(f"| `{f.name}` | {_value(value)} | {f.metadata.get('doc', '').replace('|', '/')} |")
    names = ", ".join(f"`{f.name}`" for f in fields(ErrorModel) if f.name not in ("sensor", "measures"))
    lines += ["", "Per configured sensor, the fields of its own error model (core/sensors/base.py "
              f"`ErrorModel`) are nested parameters `<sensor>.<field>`: {names} (`faults` as a comma-separated "
              "string). Their defaults are the sensor's own model; a different value (a params file, `-p "
              "doppler.scale_sigma:=0.01`) overrides it and is logged at start-up."]
    return "\n".join(lines) + "\n"


def splice(text: str, begin: str, end: str, body: str) -> str:
    """``text`` with the part between the markers replaced by ``body``."""
    head, rest = text.split(begin, 1)
    return head + begin + "\n" + body + end + rest.split(end, 1)[1]


if __name__ == "__main__":
    import sys
    from ..core.paths import SOURCE_ROOT
    readme = SOURCE_ROOT / "README.md"
    if sys.argv[1:] == ["--write"]:
        text = splice(readme.read_text(), BEGIN, END, sensor_params_markdown())
        readme.write_text(splice(text, FUSION_BEGIN, FUSION_END, fusion_params_markdown()))
    else:
        print(sensor_params_markdown() + "\n" + fusion_params_markdown(), end="")
