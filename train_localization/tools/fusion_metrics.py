"""Coupling figures of core/fusion/ (issue 49's "Done when", measured by reading the code).

  python -m train_localization.tools.fusion_metrics

Prints: reads of the filter's private names through ``self.f._`` outside filter.py; calls
from one policy component to another (``self.f.<policy>.``); the bookkeeping's state fields
written from more than one file; and the length [lines] of the per-reading function
(``pipeline.py`` ``apply_reading`` if it exists, else filter.py ``_apply_policy``).

A write is an assignment (plain, augmented, tuple target, ``del``) to ``<record>.<field>`` or
``<record>.<field>[...]``, a ``setattr(<record>, ...)``, or a mutating method call on
``<record>.<field>`` (``pop``, ``update``, ...), where ``<record>`` is the bookkeeping: a name
``aux``, any ``<expr>.aux``, or a local name bound to one of them (``held = self.f.aux``). The
record's own constructor and copy (bookkeeping.py ``Bookkeeping``) are its definition, not writers.
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


MUTATORS = frozenset({"pop", "popitem", "update", "clear", "setdefault", "append", "extend", "insert", "remove",
                      "add", "discard", "__setitem__", "__delitem__"})


def _is_record(node: ast.AST, aliases: set) -> bool:
    """Whether ``node`` is the bookkeeping: ``aux``, ``<expr>.aux`` or an alias of them (``aliases``)."""
    if isinstance(node, ast.Name):
        return node.id == "aux" or node.id in aliases
    return isinstance(node, ast.Attribute) and node.attr == "aux"


def _record_field(node: ast.AST, aliases: set, fields: set) -> str | None:
    """The state field ``node`` names (``<record>.<field>``, or an item of it), else None."""
    while isinstance(node, ast.Subscript):
        node = node.value
    if isinstance(node, ast.Attribute) and node.attr in fields and _is_record(node.value, aliases):
        return node.attr
    return None


def _targets(node: ast.AST):
    """The assigned targets of a statement, tuple targets unpacked."""
    if isinstance(node, ast.Assign):
        todo = list(node.targets)
    elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
        todo = [node.target]
    elif isinstance(node, ast.Delete):
        todo = list(node.targets)
    else:
        return
    while todo:
        t = todo.pop()
        if isinstance(t, (ast.Tuple, ast.List)):
            todo.extend(t.elts)
        else:
            yield t


def _written_fields(tree: ast.AST, fields: set) -> set:
    """The state fields a module writes (see the module's docstring for what counts). Aliases are
    collected over the whole module (conservative: a name bound to the record anywhere counts
    everywhere)."""
    definition = next(((c.lineno, c.end_lineno) for c in ast.walk(tree)
                       if isinstance(c, ast.ClassDef) and c.name == "Bookkeeping"), (0, -1))
    nodes = [n for n in ast.walk(tree) if not definition[0] <= getattr(n, "lineno", 0) <= definition[1]]
    aliases: set = set()
    changed = True
    while changed:   # names bound to the record, also through other aliases
        changed = False
        for n in nodes:
            if isinstance(n, (ast.Assign, ast.AnnAssign)) and n.value is not None and _is_record(n.value, aliases):
                for t in _targets(n):
                    if isinstance(t, ast.Name) and t.id not in aliases:
                        aliases.add(t.id)
                        changed = True
    written: set = set()
    for n in nodes:
        written.update(f for f in (_record_field(t, aliases, fields) for t in _targets(n)) if f)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in MUTATORS:
            field = _record_field(n.func.value, aliases, fields)
            if field:
                written.add(field)
        if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setattr" and n.args \
                and _is_record(n.args[0], aliases):
            name = n.args[1].value if len(n.args) > 1 and isinstance(n.args[1], ast.Constant) else None
            written.update({name} if name in fields else fields)
    return written


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
        for field in _written_fields(ast.parse(text), fields):
            writers.setdefault(field, set()).add(name)
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
