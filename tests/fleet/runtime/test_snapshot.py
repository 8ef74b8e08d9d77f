"""The simulator's snapshot (``fleet sim --state DIR``): a simulator resumed from it starts at
the saved time with every robot at its saved pose and battery; a file that is not a snapshot of
this fleet is refused naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fleet_procs import PATROL

from fleet.config.loader import load_config
from fleet.errors import ConfigError
from fleet.runtime.serve import resume_simulator, simulator_from_config
from fleet.runtime.snapshot import SNAPSHOT_FILE, take, write
from fleet.types import NavigateToPose, Pose2D


def test_a_resumed_simulator_starts_where_the_snapshot_left_its_robots(tmp_path: Path) -> None:
    config = load_config(PATROL)
    sim = simulator_from_config(config)
    ns = config.robots[0].namespace
    start = sim.robot_state(ns).pose
    assert start is not None
    sim.send_goal(ns, NavigateToPose(Pose2D(start.x, start.y + 3.0, start.theta)))
    for _ in range(100):
        sim.step()
    names = {r.namespace: r.name for r in config.robots}
    snap = take(sim, config.name, names)
    write(tmp_path / SNAPSHOT_FILE, snap)

    again = resume_simulator(config, tmp_path)
    assert again.clock.now() == pytest.approx(sim.clock.now())
    for r in config.robots:
        a, b = sim.robot_state(r.namespace), again.robot_state(r.namespace)
        assert a.pose is not None and b.pose is not None
        assert b.pose.distance_to(a.pose) < 1e-6 and b.battery == pytest.approx(a.battery)
    moved = again.robot_state(ns).pose
    assert moved is not None and moved.distance_to(start) > 0.5


def test_no_snapshot_starts_from_the_config_and_a_bad_one_is_refused(tmp_path: Path) -> None:
    config = load_config(PATROL)
    fresh = resume_simulator(config, tmp_path / "new")
    assert fresh.clock.now() == 0.0
    path = tmp_path / SNAPSHOT_FILE
    for doc, field in (
        ({"version": 1, "fleet": "other", "t": 1.0, "robots": {}}, "fleet"),
        ({"version": 1, "fleet": config.name, "t": "soon", "robots": {}}, "t"),
        ({"version": 1, "fleet": config.name, "t": 1.0, "robots": {"robot1": {"x": 1.0}}}, "robots.robot1.y"),
    ):
        path.write_text(json.dumps(doc))
        with pytest.raises(ConfigError) as e:
            resume_simulator(config, tmp_path)
        assert e.value.file == str(path) and e.value.field == field
    path.write_text("{not json")
    with pytest.raises(ConfigError, match="not a simulator snapshot"):
        resume_simulator(config, tmp_path)


def test_a_robot_docked_at_the_kill_is_charging_at_its_agents_first_look(tmp_path: Path) -> None:
    """The docking state comes back before the first step: an agent started with the resumed
    simulator sees the charge under way at once (and its battery guard finishes it), instead
    of a robot standing on a charger that does not charge until the simulator steps."""
    config = load_config(PATROL)
    charger = config.chargers[0].pose
    docked = {"x": charger.x, "y": charger.y, "theta": charger.theta, "battery": 0.4, "charging": True}
    doc = {"version": 1, "fleet": config.name, "t": 50.0, "robots": {"robot1": docked}}
    (tmp_path / SNAPSHOT_FILE).write_text(json.dumps(doc))
    sim = resume_simulator(config, tmp_path)
    ns = config.robots[0].namespace
    st = sim.robot_state(ns)
    assert st.charging and st.battery == pytest.approx(0.4) and sim.clock.now() == 50.0
    assert not sim.robot_state(config.robots[1].namespace).charging
    sim.step()
    assert sim.robot_state(ns).charging and sim.robot_state(ns).battery > 0.4  # it charges on
    names = {r.namespace: r.name for r in config.robots}
    assert take(sim, config.name, names).robots["robot1"].charging  # and the next snapshot says so
    doc["robots"] = {"robot1": {**docked, "charging": "yes"}}
    (tmp_path / SNAPSHOT_FILE).write_text(json.dumps(doc))
    with pytest.raises(ConfigError) as e:
        resume_simulator(config, tmp_path)
    assert e.value.field == "robots.robot1.charging"


def test_runs_started_in_the_same_second_each_get_a_new_state_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without ``--state`` every run gets its own empty book: a second run of the same process
    in the same second must not resume the first one's robots (this once made a run start at
    the previous run's end time)."""
    from fleet.runtime.service_host import default_state_dir

    monkeypatch.setenv("FLEET_STATE_ROOT", str(tmp_path))
    config = load_config(PATROL)
    dirs = [default_state_dir(config) for _ in range(3)]
    assert len(set(dirs)) == 3
    for d in dirs:
        assert d.is_dir() and not any(d.iterdir())
        assert d.parent == tmp_path and d.name.startswith(config.name)
