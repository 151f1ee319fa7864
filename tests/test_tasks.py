"""Tasks: the paper's task table built from the paper's facts, and every failure to build a task as one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from ilcsan.cli import main
from ilcsan.errors import UserError
from ilcsan.paper import published as paper
from ilcsan.rl import tasks
from ilcsan.rl.tasks import TASK_SPECS, make_env


def test_paper_tasks_follow_the_papers_table():
    assert tuple(TASK_SPECS) == paper.PAPER_TASK_NAMES
    for name, spec in TASK_SPECS.items():
        assert (spec.paper_id, spec.state_dim, spec.action_dim) == (paper.TASKS[name].paper_id, paper.TASKS[name].n,
                                                                    paper.TASKS[name].m)


@pytest.mark.parametrize("name", list(TASK_SPECS))
def test_paper_tasks_have_the_papers_sizes(name):
    env = make_env(name, seed=0)
    try:
        assert env.observation_space.shape == (TASK_SPECS[name].state_dim,)
        assert env.action_space.shape == (TASK_SPECS[name].action_dim,)
    finally:
        env.close()


def _build_or_user_error(gym_id: str) -> str:
    """'built' (Box action, flat Box observation, one step works) or 'refused' (one-line UserError)."""
    try:
        env = make_env(gym_id, seed=0)
    except UserError as error:
        message = str(error)
        assert "\n" not in message and gym_id in message, message
        return "refused"
    try:
        assert isinstance(env.action_space, gym.spaces.Box)
        assert isinstance(env.observation_space, gym.spaces.Box) and len(env.observation_space.shape) == 1
        observation, *_ = env.step(env.action_space.sample())
        assert np.asarray(observation).shape == env.observation_space.shape
    finally:
        env.close()
    return "built"


def test_every_registered_task_builds_or_is_one_user_error():
    outcomes = {gym_id: _build_or_user_error(gym_id) for gym_id in sorted(gym.registry)}
    assert len(outcomes) == len(gym.registry)
    built = {gym_id for gym_id, outcome in outcomes.items() if outcome == "built"}
    assert {"Hopper-v4", "Ant-v4", "Pendulum-v1", "BipedalWalker-v3"} <= built
    assert {"Hopper-v3", "CartPole-v1", "CarRacing-v3"} <= set(outcomes) - built


class _Broken(gym.Env):
    """An environment that fails where a task can fail: in its constructor or its first reset."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def __init__(self, where: str = "make"):
        if where == "make":
            raise RuntimeError("the simulator says no\nsecond line \x1b[33mcoloured\x1b[0m")
        self.where = where

    def reset(self, *, seed=None, options=None):
        raise OSError("model file missing")


@pytest.fixture
def broken_tasks():
    gym.register("IlcsanBrokenMake-v0", entry_point=_Broken, kwargs={"where": "make"})
    gym.register("IlcsanBrokenReset-v0", entry_point=_Broken, kwargs={"where": "reset"})
    yield
    del gym.registry["IlcsanBrokenMake-v0"], gym.registry["IlcsanBrokenReset-v0"]


@pytest.mark.parametrize("gym_id, cause", [("IlcsanBrokenMake-v0", "the simulator says no second line coloured"),
                                           ("IlcsanBrokenReset-v0", "model file missing")])
def test_any_exception_while_building_is_one_user_error(broken_tasks, gym_id, cause):
    with pytest.raises(UserError) as caught:
        make_env(gym_id)
    message = str(caught.value)
    assert gym_id in message and cause in message and "\n" not in message and "\x1b" not in message


def test_bad_keyword_arguments_are_a_user_error(monkeypatch):
    monkeypatch.setattr(tasks, "resolve_task", lambda name: ("Hopper-v4", {"no_such_argument": 1}))
    with pytest.raises(UserError, match="keyword arguments"):
        make_env("Hopper")


def test_old_versions_of_paper_tasks_point_to_the_paper_task():
    with pytest.raises(UserError, match="--task Hopper"):
        make_env("Hopper-v3")


def test_train_on_a_task_that_cannot_be_built_is_one_line(broken_tasks, tmp_path, capsys):
    code = main(["train", "--task", "IlcsanBrokenMake-v0", "--steps", "10", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "IlcsanBrokenMake-v0" in err and "the simulator says no" in err
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_building_a_v4_task_is_quiet(capfd):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_env("Hopper", seed=0).close()
        make_env("InvertedPendulum-v4", seed=0).close()
    assert not caught
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""


def test_tasks_listing_says_which_versions_and_why(capsys):
    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    assert tasks.VERSION_NOTE in out and "-v4" in out


def test_environments_built_before_one_that_fails_are_closed(monkeypatch):
    built: list[Closable] = []

    def make_third_fails(name, seed=None, render_mode=None, contact_forces=None):
        if len(built) == 2:
            raise UserError(f"task {name!r} cannot be built here: out of file handles")
        built.append(Closable())
        return built[-1]

    monkeypatch.setattr(tasks, "make_env", make_third_fails)
    with pytest.raises(UserError, match="out of file handles"):
        tasks.make_envs("Hopper", 5)
    assert len(built) == 2 and all(env.closed for env in built)


class Closable:
    def __init__(self):
        self.closed = False

    def close(self):
        self.closed = True


def test_a_task_of_ones_own_is_module_colon_id_and_every_process_imports_it(tmp_path, capsys, monkeypatch):
    env = make_env("own_tasks:HeavyPendulum-v0")
    assert env.unwrapped.g == 12.0  # the user's registration, not Gymnasium's Pendulum
    env.close()
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--task", "own_tasks:HeavyPendulum-v0", "--steps", "300", "--eval-every", "150",
                 "--eval-episodes", "1", "--start-steps", "150", "--hidden-width", "16", "--no-progress"]) == 0
    run = tmp_path / "runs" / "HeavyPendulum-v0-ilc-san-s0"  # the id names the folder, not the module
    assert json.loads((run / "config.json").read_text())["task"] == "own_tasks:HeavyPendulum-v0"
    capsys.readouterr()

    def evaluate_in_a_new_process(pythonpath: str):
        environment = {**os.environ, "PYTHONPATH": pythonpath}
        return subprocess.run([sys.executable, "-m", "ilcsan.cli", "evaluate", str(run), "--episodes", "1"],
                              capture_output=True, text=True, env=environment, timeout=600)

    found = evaluate_in_a_new_process(str(Path(__file__).parent))
    assert found.returncode == 0 and "own_tasks:HeavyPendulum-v0 · ilc-san · 1 episode:" in found.stdout
    lost = evaluate_in_a_new_process("")
    assert lost.returncode == 2 and lost.stderr.strip().splitlines() == [
        "ilcsan: error: task 'own_tasks:HeavyPendulum-v0': cannot import module 'own_tasks' (No module named "
        "'own_tasks'); install it, or add its folder to PYTHONPATH"]


@pytest.mark.parametrize(("task", "fragment"), [
    ("no_such_module:Arm-v0", "cannot import module 'no_such_module' (No module named 'no_such_module')"),
    ("own_tasks:Arm-v0", "importing 'own_tasks' registered no task of that id"),
    (":Arm-v0", "names no module before ':'"),
    ("Arm-v0", "or a task of your own as module:id"),
])
def test_a_task_of_ones_own_that_cannot_be_found_is_one_line(task, fragment, capsys):
    code = main(["train", "--task", task, "--steps", "100"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and fragment in err
