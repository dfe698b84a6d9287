"""README.md stays true and short: quick start, node list, the pages it points to; the
parameter tables of docs/nodes.md stay those of the code."""
from __future__ import annotations

import re

from conftest import ROOT
from train_localization.core.sensors import NODE_NAMES
from train_localization.tools.docs import (BEGIN, END, FUSION_BEGIN, FUSION_END, fusion_params_markdown,
                                          sensor_params_markdown)

README = (ROOT / "README.md").read_text()
NODES_PAGE = (ROOT / "docs" / "nodes.md").read_text()


def test_quick_start_holds_exactly_the_demo_then_the_test_command():
    section = README.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```(?:bash|sh)?\n(.*?)```", section, re.S).group(1)
    commands = [line for line in block.splitlines() if line.strip() and not line.startswith("#")]
    assert commands == ["bash scripts/demo.sh", "bash scripts/test.sh"]
    assert "bash scripts/test.sh" in (ROOT / ".ci" / "run").read_text()


def test_every_node_is_documented_with_its_current_parameters():
    table = NODES_PAGE.split(BEGIN, 1)[1].split(END, 1)[0]
    assert table.strip() == sensor_params_markdown().strip(), "run: python -m train_localization.tools.docs --write"
    fusion = NODES_PAGE.split(FUSION_BEGIN, 1)[1].split(FUSION_END, 1)[0]
    assert fusion.strip() == fusion_params_markdown().strip(), "run: python -m train_localization.tools.docs --write"
    import ast
    setup = ast.parse((ROOT / "setup.py").read_text())
    nodes = next(ast.literal_eval(st.value) for st in setup.body
                 if isinstance(st, ast.Assign) and getattr(st.targets[0], "id", "") == "NODES")
    assert {"simulator", "fusion", "recorder", "replayer"} <= set(nodes)
    for node in (*nodes, *NODE_NAMES):
        assert f"`{node}`" in README and f"`{node}`" in NODES_PAGE + (ROOT / "docs" / "changeover.md").read_text()


def test_the_readme_is_a_users_page_that_points_to_pages_that_exist():
    """Under 400 lines; every docs/ page it names exists, and every page of docs/ is named."""
    assert README.count("\n") < 400
    named = set(re.findall(r"`(docs/[\w.]+\.md)`", README))
    assert named and all((ROOT / page).exists() for page in named), named
    assert {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")} <= named


def test_example_params_files_hold_every_sensor_parameter_at_its_default():
    from train_localization.tools.docs import params_files
    for name, body in params_files().items():
        path = ROOT / "config" / "params" / name
        assert path.read_text() == body, "run: python -m train_localization.tools.docs --write"
