"""Coupling figures of core/fusion/ (issue 49's "Done when", measured by reading the code).

  python -m train_localization.tools.fusion_metrics

Prints: reads of the filter's private names through ``self.f._`` outside filter.py; calls
from one policy component to another (``self.f.<policy>.``); the bookkeeping's state fields
assigned (``aux.<field> =``) from more than one file; and the length [lines] of the
per-reading function (``pipeline.py`` ``apply_reading`` if it exists, else filter.py
``_apply_policy``).
"""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

FUSION = Path(__file__).resolve().parent.parent / "core" / "fusion"
POLICIES = ("lone", "solutions", "interval", "motion", "arbitration", "episodes", "plausibility", "fixes")
PER_READING = (("pipeline.py", "apply_reading"), ("filter.py", "_apply_policy"))


def _state_fields() -> list[str]:
    """The names of the state fields (Bookkeeping's slots, or the fields of state.py's records)."""
    names: list[str] = []
    for path in (FUSION / "bookkeeping.py", FUSION / "state.py"):
        if not path.exists():
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "__slots__" for t in node.targets):
                names += [e.value for e in node.value.elts]
    return names


def _function_length(path: Path, name: str) -> int | None:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return node.end_lineno - node.lineno + 1
    return None


def measure() -> dict[str, object]:
    sources = {p.name: p.read_text() for p in sorted(FUSION.glob("*.py"))}
    private = sum(len(re.findall(r"\bself\.f\._\w", text)) for name, text in sources.items() if name != "filter.py")
    between = sum(len(re.findall(rf"\bself\.f\.(?:{'|'.join(POLICIES)})\.\w+\(", text))
                  for name, text in sources.items() if name != "filter.py")
    writers: dict[str, set] = {}
    fields = set(_state_fields())
    for name, text in sources.items():
        for m in re.finditer(r"\baux\.(\w+)\s*(?:[+\-|&]?=)(?!=)", text):
            if m.group(1) in fields:
                writers.setdefault(m.group(1), set()).add(name)
    shared = sorted(f for f, files in writers.items() if len(files) > 1)
    length = next((( f"{file}:{func}", n) for file, func in PER_READING
                   if (FUSION / file).exists() and (n := _function_length(FUSION / file, func)) is not None),
                  ("-", 0))
    return {"self.f._ reads outside filter.py": private, "calls between policies": between,
            "state fields written from more than one file": f"{len(shared)} ({', '.join(shared)})",
            f"per-reading function ({length[0]}) lines": length[1]}


def main() -> int:
    for key, value in measure().items():
        print(f"{key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
