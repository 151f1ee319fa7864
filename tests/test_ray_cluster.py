"""`ilcsan reproduce --backend ray --address` against a real Ray cluster started as Ray's users start one.

Every cluster here is made of ``ray start`` processes in a loopback-only network namespace (``ray_cluster``): a
head with token authentication as Ray 2.60 turns it on (a token in ``~/.ray/auth_token``), a second node on the
same machine, and the ``ilcsan`` command line as the driver. The tests stop what they started, by its ids.
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import time
from pathlib import Path

import pytest
from ray_cluster import ILCSAN, RAY, LoopbackNetwork, RayNode, alive, namespace_unavailable, open_paths
from test_experiments import TINY_GRID

pytest.importorskip("ray", reason="Ray is not installed (pip install 'ilcsan[ray]'); CI installs it")
pytestmark = pytest.mark.slow
if reason := namespace_unavailable():
    pytest.skip(f"a Ray cluster on the loopback only needs a network namespace: {reason}", allow_module_level=True)

PORT = 6390
ADDRESS = f"127.0.0.1:{PORT}"
WORKERS_AT_OUR_PRIORITY = {"RAY_worker_niceness": "0"}
"""Ray lowers its workers' priority by default: on 2 cores beside another busy test worker they starved."""
SHORT_CONNECT = {"RAY_NUM_REDIS_GET_RETRIES": "3"}
"""For the drivers that must fail: Ray gives up on a refused connection after 3 tries (≈ 3 s) instead of 20."""


def grid_text(steps: int) -> str:
    """The tiny grid of ``test_experiments`` with one seed and ``steps`` (4 jobs: 2 tasks × 2 rows)."""
    return TINY_GRID.replace('name = "tiny"', 'name = "cluster"').replace("seeds = 2", "seeds = 1") \
        .replace("steps = 300", f"steps = {steps}")


@pytest.fixture
def network():
    network = LoopbackNetwork()
    try:
        yield network
    finally:
        network.close()


def environment(home: Path, **variables: str) -> dict[str, str]:
    """This process's environment without Ray's own variables, with ``home`` as HOME (where Ray keeps its token)."""
    home.mkdir(parents=True, exist_ok=True)
    env = {name: value for name, value in os.environ.items() if not name.startswith("RAY_")}
    return {**env, "HOME": str(home), "PYTHONUNBUFFERED": "1", **WORKERS_AT_OUR_PRIORITY, **variables}


def generate_token(env: dict[str, str]) -> str:
    subprocess.run([RAY, "get-auth-token", "--generate"], env=env, check=True, capture_output=True, timeout=60)
    return (Path(env["HOME"]) / ".ray" / "auth_token").read_text().strip()


def start_head(network: LoopbackNetwork, env: dict[str, str], tmp_path: Path, cpus: int = 1) -> RayNode:
    head = RayNode(network, ["--head", f"--port={PORT}", f"--num-cpus={cpus}", f"--temp-dir={network.ray_temp}",
                             "--include-dashboard=false"], env, tmp_path / "head.log")
    head.wait_started()
    return head


def reproduce(network: LoopbackNetwork, tmp_path: Path, env: dict[str, str], address: str, steps: int = 300,
              **popen) -> subprocess.Popen:
    tmp_path.mkdir(parents=True, exist_ok=True)
    grid = tmp_path / "cluster.toml"
    grid.write_text(grid_text(steps))
    return subprocess.Popen(network.command([ILCSAN, "reproduce", str(grid), "--backend", "ray", "--address",
                                             address, "--out", str(tmp_path / "out")]),
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def finished(process: subprocess.Popen, timeout: float = 600.0) -> tuple[int, str, str]:
    out, err = process.communicate(timeout=timeout)
    return process.returncode, out, err


def run_folders(out: Path) -> list[Path]:
    return sorted(path.parent for path in out.glob("cluster/*/*/seed*/config.json"))


def run_result(folder: Path) -> dict | None:
    """The run's result.json once its first checkpoint is complete (result.json is written last)."""
    path = folder / "result.json"
    return json.loads(path.read_text()) if path.is_file() else None


def metrics_steps(folder: Path) -> list[int]:
    with open(folder / "metrics.csv") as stream:
        return [int(row["step"]) for row in csv.DictReader(stream)]


def assert_grid_complete(out: Path, steps: int) -> None:
    folders = run_folders(out)
    assert len(folders) == 4, folders
    for folder in folders:
        result = json.loads((folder / "result.json").read_text())
        assert result["finished"] and result["steps_done"] == steps, folder
        assert metrics_steps(folder) == list(range(150, steps + 1, 150)), f"{folder}: evaluation lost or doubled"
    report = (out / "cluster" / "report.md").read_text()
    assert "ILC-SAN 16" in report and "PopSAN 16" in report and "InvertedPendulum-v4" in report


def snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {name: ((folder / name).stat().st_mtime_ns, (folder / name).read_bytes())
            for name in ("result.json", "metrics.csv", "checkpoint.pt", "policy.pt")}


def held_run(node: RayNode, out: Path) -> Path | None:
    """The run folder a process of ``node`` trains (it holds the folder's ``.lock`` open), if any."""
    for pid in node.pids():
        for path in open_paths(pid):
            if path.startswith(str(out)) and path.endswith("/.lock"):
                return Path(path).parent
    return None


def test_a_grid_on_a_two_node_token_cluster_survives_losing_a_node(network, tmp_path):
    env = environment(tmp_path / "home")
    generate_token(env)  # as `ray start --head` finds it in ~/.ray/auth_token, token authentication is on
    head = start_head(network, env, tmp_path)
    assert "Token authentication is enabled" in head.log.read_text()
    second = RayNode(network, [f"--address={ADDRESS}", "--num-cpus=1"], {**env, "RAY_AUTH_MODE": "token"},
                     tmp_path / "second.log")  # Ray's way to add a node to a cluster with token authentication
    second.wait_started()
    out = tmp_path / "out"
    steps = 1500
    driver = reproduce(network, tmp_path, env, ADDRESS, steps=steps)  # the token from ~/.ray, no RAY_ variable
    try:
        victim = None
        deadline = time.monotonic() + 300
        while victim is None and time.monotonic() < deadline:  # the second node's job, past its first checkpoint
            folder = held_run(second, out)
            if folder is not None and (result := run_result(folder)) and not result["finished"]:
                victim = folder
            assert driver.poll() is None, driver.communicate()
            time.sleep(0.05)
        assert victim is not None, f"no job seen on the second node: {[open_paths(pid) for pid in second.pids()]}"
        done_before = {folder: snapshot(folder) for folder in run_folders(out)
                       if (result := run_result(folder)) and result["finished"]}
        node_processes = second.pids()
        second.kill()
        killed_at = json.loads((victim / "result.json").read_text())["steps_done"]
        deadline = time.monotonic() + 10
        while any(map(alive, node_processes)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(node_processes) >= 4 and not any(map(alive, node_processes)), "the whole node is gone"
        code, printed, errors = finished(driver)
    finally:
        if driver.poll() is None:
            driver.kill()
        second.kill()
        head.kill()
    assert code == 0, errors
    assert "the Ray cluster at 127.0.0.1:6390 (token authentication), 2 CPU(s)" in printed, printed
    assert_grid_complete(out, steps)
    for folder, files in done_before.items():
        assert snapshot(folder) == files, f"{folder} had finished and was written again"
    logs = "".join(path.read_text() for path in (out / "cluster" / "logs").glob("*.log"))
    resumed = re.search(rf"resumed {re.escape(str(victim))} at step (\d+)", logs)
    assert resumed and killed_at <= int(resumed[1]) < steps, logs  # from its last checkpoint, not from step 0
    assert "Traceback" not in errors and len(errors.splitlines()) < 5, errors


def test_a_cluster_without_authentication_is_joined_by_a_driver_with_a_token(network, tmp_path):
    # a cluster without authentication (no token where the head starts: Ray 2.60 leaves it off) is joined by a
    # driver that has a token of its own
    head = start_head(network, environment(tmp_path / "bare"), tmp_path, cpus=2)
    try:
        assert "Token authentication is disabled" in head.log.read_text()
        env = environment(tmp_path / "home")
        generate_token(env)
        code, printed, errors = finished(reproduce(network, tmp_path, env, ADDRESS))
        assert code == 0, errors
        assert "(token authentication)" in printed  # the token is sent, and a cluster without authentication takes it
        assert_grid_complete(tmp_path / "out", 300)
    finally:
        head.kill()


def test_auto_with_rays_own_variables_and_one_line_failures(network, tmp_path):
    cluster = environment(tmp_path / "head-home")
    token = generate_token(cluster)
    head = start_head(network, cluster, tmp_path, cpus=2)
    try:
        # --address auto with Ray's RAY_ADDRESS, the token in RAY_AUTH_TOKEN (HOME has none)
        env = environment(tmp_path / "empty", RAY_ADDRESS=ADDRESS, RAY_AUTH_TOKEN=token)
        code, printed, errors = finished(reproduce(network, tmp_path, env, "auto"))
        assert code == 0, errors
        assert "(token authentication)" in printed
        assert_grid_complete(tmp_path / "out", 300)

        failures = {
            "no token": environment(tmp_path / "none", **SHORT_CONNECT),
            "wrong token": environment(tmp_path / "none", RAY_AUTH_TOKEN="0" * 32, **SHORT_CONNECT),
        }
        for case, env in failures.items():
            started = time.monotonic()
            code, printed, errors = finished(reproduce(network, tmp_path / case.replace(" ", "-"), env, ADDRESS))
            lines = errors.strip().splitlines()
            assert code == 2 and len(lines) == 1 and "Traceback" not in errors, (case, errors)
            expected = "has none" if case == "no token" else "refused this machine's Ray token"
            assert expected in lines[0] and "ray get-auth-token" in lines[0], (case, lines)
            assert time.monotonic() - started < 120
    finally:
        head.kill()
    code, printed, errors = finished(reproduce(network, tmp_path / "gone", environment(tmp_path / "none"),
                                               ADDRESS))
    lines = errors.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "no Ray cluster answers at 127.0.0.1:6390" in lines[0], errors
    assert "ray start --head --port=6390" in lines[0]
