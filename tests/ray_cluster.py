"""A real Ray cluster for the tests: nodes started with Ray's own ``ray start``, on the loopback only.

On Linux, Ray's cluster mode (needed for a second node) replaces 127.0.0.1 by the machine's outward address. So
every process here runs in a network namespace of its own whose only interface is the loopback: there Ray finds no
other address, and nothing it starts can listen on, or reach, any other. The namespace needs root (``unshare``);
without it the tests that use it skip and say so.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent
RAY = str(BIN / "ray")
ILCSAN = str(BIN / "ilcsan")


def namespace_unavailable() -> str | None:
    """Why a loopback-only network namespace cannot be made here, or None when it can."""
    try:
        done = subprocess.run(["unshare", "--net", "--", "ip", "link", "set", "lo", "up"], capture_output=True,
                              text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as error:
        return f"unshare/ip not usable: {error}"
    return None if done.returncode == 0 else f"no network namespace here: {done.stderr.strip()[:120]}"


class LoopbackNetwork:
    """A network namespace with only ``lo`` up; :meth:`command` runs a command inside it."""

    def __init__(self):
        self.holder = subprocess.Popen(["unshare", "--net", "--", "sh", "-c",
                                        "ip link set lo up && echo up && exec sleep infinity"],
                                       stdout=subprocess.PIPE, text=True)
        assert self.holder.stdout is not None and self.holder.stdout.readline().strip() == "up"
        self.inode = os.stat(f"/proc/{self.holder.pid}/ns/net").st_ino
        self.ray_temp = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))
        """Ray's ``--temp-dir``: short, as its socket paths must stay under 108 bytes (a pytest folder is too long)."""

    def command(self, argv: list[str]) -> list[str]:
        return ["nsenter", f"--target={self.holder.pid}", "--net", "--", *argv]

    def members(self) -> list[int]:
        """Every process in this namespace but its holder: each one started by the test."""
        found = []
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) != self.holder.pid:
                with contextlib.suppress(OSError):
                    if os.stat(entry / "ns" / "net").st_ino == self.inode:
                        found.append(int(entry.name))
        return found

    def close(self) -> None:
        """Kill whatever still runs in the namespace, then its holder; remove Ray's temporary folder."""
        for pid in self.members():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        self.holder.kill()
        self.holder.wait()
        shutil.rmtree(self.ray_temp, ignore_errors=True)


class RayNode:
    """One ``ray start … --block``: the node's processes (GCS, raylet, agents, the workers they fork) are its
    descendants, so :meth:`kill` is a real SIGKILL of the whole node."""

    def __init__(self, network: LoopbackNetwork, arguments: list[str], env: dict[str, str], log: Path):
        self.log = log
        with open(log, "w") as stream:
            self.process = subprocess.Popen(network.command([RAY, "start", *arguments, "--block",
                                                             "--disable-usage-stats"]),
                                            env=env, stdout=stream, stderr=subprocess.STDOUT, start_new_session=True)

    def wait_started(self, timeout: float = 120.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.log.read_text(errors="replace")
            if "Ray runtime started" in text:
                return text
            assert self.process.poll() is None, f"ray start exited ({self.process.returncode}):\n{text[-2000:]}"
            time.sleep(0.2)
        raise AssertionError(f"ray start did not start in {timeout:g} s:\n{self.log.read_text()[-2000:]}")

    def pids(self) -> list[int]:
        """The node's live processes: ``ray start`` and its descendants (Ray forks some workers into process groups
        of their own, so the group alone would miss them)."""
        children: dict[int, list[int]] = {}
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit():
                with contextlib.suppress(OSError, ValueError, IndexError):
                    state, parent = (entry / "stat").read_text().rsplit(")", 1)[1].split()[:2]
                    if state != "Z":
                        children.setdefault(int(parent), []).append(int(entry.name))
        found, queue = [], [self.process.pid] if self.process.poll() is None else []
        while queue:
            pid = queue.pop()
            found.append(pid)
            queue.extend(children.get(pid, []))
        return found

    def kill(self) -> None:
        """SIGKILL every process of the node (twice over the tree, for a process forked meanwhile)."""
        for _ in range(2):
            for pid in self.pids():
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        self.process.wait()


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie does not)."""
    try:
        return (Path(f"/proc/{pid}") / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def open_paths(pid: int) -> list[str]:
    """The files process ``pid`` holds open."""
    paths = []
    with contextlib.suppress(OSError):
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(OSError):
                paths.append(os.readlink(fd))
    return paths
