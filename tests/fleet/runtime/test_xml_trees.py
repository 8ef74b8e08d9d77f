"""``fleet run --tree FILE.xml``: the shipped patrol and picking trees as BehaviorTree.CPP XML
(``nodes/trees/patrol.xml``, ``picking.xml``) behave as the Python builders on the simulator
(the same run, robot by robot), and a bad file is an error naming file, line and node."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from ports import free_endpoint

from fleet.config.loader import load_config
from fleet.errors import ConfigError, TreeError
from fleet.runtime.runner import FleetRunner
from fleet.types import TreeKind

ROOT = Path(__file__).resolve().parents[3]
TREES = ROOT / "nodes" / "trees"


def _run(config: str, kind: TreeKind, tree_file: str | None, duration: float = 300.0) -> dict[str, Any]:
    cfg = load_config(ROOT / "configs" / config)
    runner = FleetRunner(
        cfg,
        duration=duration,
        speed=0,
        endpoint=free_endpoint(),
        live=False,
        tree_kind=kind,
        tree_file=tree_file,
        traffic=False,  # an XML tree runs without traffic management: compare like with like
        out=io.StringIO(),
    )
    return runner.run().to_dict()


@pytest.mark.parametrize(
    ("config", "kind", "xml"),
    [
        ("warehouse_patrol.yaml", TreeKind.PATROL, "patrol.xml"),
        ("warehouse_picking.yaml", TreeKind.PICKING, "picking.xml"),
    ],
)
def test_xml_tree_runs_the_fleet_as_the_builder_tree(config: str, kind: TreeKind, xml: str) -> None:
    built = _run(config, kind, None)
    from_xml = _run(config, TreeKind.PATROL, str(TREES / xml))  # the kind comes from the file
    # The built-in fleet runs the task tree, whose step leaf is named FollowSteps where the
    # single-purpose picking tree (and its XML) names GoToShelf: every other field must agree.
    assert [_without_leaf(r) for r in from_xml["per_robot"]] == [_without_leaf(r) for r in built["per_robot"]]
    for key in ("laps_completed", "patrols_completed", "picks_completed", "reassignments", "collisions"):
        assert from_xml[key] == built[key], key
    work = built["laps_completed"] if kind is TreeKind.PATROL else built["picks_completed"]
    assert work > 0  # the comparison is over a fleet that did something
    charges = sum(r["charges"] for r in built["per_robot"])
    assert charges > 0  # ... including going to charge, recovering and charging


def _without_leaf(row: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in row.items() if k != "leaf"}


def test_bad_tree_file_is_an_error_before_the_run(tmp_path: Path) -> None:
    bad = tmp_path / "patrol.xml"
    bad.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="T">\n<ReactiveFallback>\n<FollowRoutee/>\n<Idle/>\n</ReactiveFallback></BehaviorTree></root>'
    )
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml")
    with pytest.raises(TreeError, match=r"patrol.xml:3: <FollowRoutee>: unknown node"):
        FleetRunner(cfg, duration=1, speed=0, endpoint=free_endpoint(), live=False, tree_file=str(bad))
    with pytest.raises(ConfigError, match="traffic"):
        FleetRunner(cfg, duration=1, speed=0, live=False, tree_file=str(TREES / "patrol.xml"), traffic=True)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "fleet.cli",
            "run",
            str(ROOT / "configs" / "warehouse_patrol.yaml"),
            "--tree",
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert f"{bad}:3: <FollowRoutee>: unknown node 'FollowRoutee'; did you mean FollowRoute" in proc.stderr
