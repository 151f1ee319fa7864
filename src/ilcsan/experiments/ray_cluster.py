"""Ray for ``ilcsan reproduce --backend ray``: start a private one on this machine, or join a user's cluster.

Joining (``--address HOST:PORT`` or ``auto``) follows what Ray itself does for ``ray.init(address="auto")``:
when ``RAY_AUTH_MODE`` is not set and this machine has a Ray token (``RAY_AUTH_TOKEN``, the file named by
``RAY_AUTH_TOKEN_PATH``, or ``~/.ray/auth_token``, where ``ray start --head`` and ``ray get-auth-token
--generate`` keep it), the driver sends it. Ray 2.60 turns token authentication on for a head started
where a token exists, yet sends no token to an address given by hand, so without this the one documented
way to a cluster failed on Ray's defaults. A driver that sends a token still joins a cluster without
authentication; ``RAY_AUTH_MODE=disabled`` sends none.

While Ray connects, its C++ client writes a line to the terminal for every failed attempt (≈ 20 in 20 s);
they are captured instead, and a failure is told in one line: nothing listening at the address, the token
(missing or not the cluster's), or another Ray or Python version on the cluster than on this machine.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import socket
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass

from ..errors import UserError

RAY_INSTALL_HINT = 'pip install "ilcsan[ray]"'
AUTH_MODE_VARIABLE = "RAY_AUTH_MODE"
PROBE_SECONDS = 5.0
"""How long the address is given to accept a TCP connection before Ray is asked to join it."""


def import_ray():
    """Ray, or a UserError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(f"--backend ray needs Ray, which is not installed; install it with {RAY_INSTALL_HINT}") \
            from None
    return ray


# ------------------------------------------------------------------------------- a private Ray
def start_local_ray(num_cpus: int, dashboard: bool = False) -> None:
    """Start a private single-machine Ray that listens on 127.0.0.1 only (never joins another cluster).

    In Ray 2.60 on Linux ``_node_ip_address="127.0.0.1"`` alone is turned into the machine's outward
    address and the servers listen there; Ray keeps a node on the loopback address only when its cluster
    mode is off (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, the default on macOS and Windows), which is
    set here for the processes Ray starts and restored afterwards. ``address="local"`` makes sure a new
    instance is started, whatever ``RAY_ADDRESS`` says.
    """
    ray = import_ray()
    variable = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    saved_env = os.environ.get(variable)
    constants = _ray_constants()
    saved_flag = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    os.environ[variable] = "0"
    if saved_flag is not None:
        constants.ENABLE_RAY_CLUSTER = False  # read at import time; Ray may already be imported
    try:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=dashboard, dashboard_host="127.0.0.1",
                 _node_ip_address="127.0.0.1", log_to_driver=False, logging_level=logging.WARNING)
    finally:
        if saved_env is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = saved_env
        if saved_flag is not None:
            constants.ENABLE_RAY_CLUSTER = saved_flag


def _ray_constants():
    try:
        from ray._private import ray_constants
    except ImportError:  # a future Ray without this module: the node address is checked by the caller
        return None
    return ray_constants


def ray_node_address() -> str:
    """The address the connected Ray node listens on (127.0.0.1 for :func:`start_local_ray`)."""
    import ray

    return str(ray.util.get_node_ip_address())


# ------------------------------------------------------------------------------- a user's cluster
def join_ray_cluster(address: str) -> str:
    """Connect this process to the Ray cluster at ``address`` (``HOST:PORT`` or ``auto``); returns what joined it
    ("the Ray cluster at HOST:PORT (token authentication)"), or raises a UserError of one line
    (:func:`join_failure`). What Ray wrote while joining is read for the error's cause; after a successful join it
    is passed on to stderr, so that Ray's warnings still reach the user."""
    ray = import_ray()
    if address != "auto":
        check_listening(address)
    token = send_token_if_available()
    failure: Exception | None = None
    with captured_stderr() as ray_log:  # the fd must be restored before the error is told
        try:
            ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
        except Exception as error:  # Ray raises ConnectionError, RuntimeError, ValueError, its AuthenticationError
            failure = error
    if failure is not None:
        raise UserError(join_failure(address, failure, ray_log.text, token)) from None
    if ray_log.text:
        sys.stderr.write(ray_log.text)
    joined = ray.get_runtime_context().gcs_address
    return f"the Ray cluster at {joined} ({'token' if token else 'no'} authentication)"


def check_listening(address: str) -> None:
    """A UserError unless something accepts a TCP connection at ``HOST:PORT`` within :data:`PROBE_SECONDS`."""
    host, _, port = address.split("://", 1)[-1].rpartition(":")  # ray://HOST:PORT (Ray Client) too
    if not host or not port.isdigit():
        raise UserError(f"--address {address!r} is not HOST:PORT (e.g. 10.0.0.5:6379) or auto")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_SECONDS):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise UserError(f"no Ray cluster answers at {address} ({reason}): start one there with `ray start --head "
                        f"--port={port}`, or check --address") from None


def send_token_if_available() -> bool:
    """Send this machine's Ray token when ``RAY_AUTH_MODE`` is unset and a token exists (what Ray does for
    ``address="auto"``); returns whether a token will be sent."""
    mode = os.environ.get(AUTH_MODE_VARIABLE)
    if mode is not None:
        return mode.lower() == "token"
    try:
        from ray._private.authentication.authentication_token_setup import (
            maybe_enable_token_auth_if_token_available,
        )
    except ImportError:  # a Ray without token authentication: nothing to send
        return False
    with captured_stderr():  # Ray's own note that token authentication is on
        return bool(maybe_enable_token_auth_if_token_available(warn_if_disabled=False))


@dataclass
class CapturedText:
    text: str = ""


@contextlib.contextmanager
def captured_stderr() -> Iterator[CapturedText]:
    """Within the block, whatever this process (its C++ libraries included) writes to file descriptor 2 is kept
    in the yielded object's ``text`` instead of reaching the terminal."""
    captured = CapturedText()
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.text = sink.read().decode(errors="replace")


VERSION_MISMATCH = re.compile(r"started with:\s*Ray: (\S+)\s*Python: (\S+)\s*This process.*?started with:\s*"
                              r"Ray: (\S+)\s*Python: (\S+)", re.S)
AUTH_REFUSED = ("Unauthenticated", "InvalidAuthToken")


def join_failure(address: str, error: BaseException, ray_log: str, token_sent: bool) -> str:
    """One line for a failed join: what went wrong and what to do (``ray_log``: what Ray wrote meanwhile)."""
    where = f"the Ray cluster at {address}"
    message = str(error)
    copy_token = "copy the head node's ~/.ray/auth_token here, or set RAY_AUTH_TOKEN to what `ray get-auth-token` " \
                 "prints on the head node"
    if type(error).__name__ == "AuthenticationError":  # raised here, before connecting: token mode, no token
        return f"{AUTH_MODE_VARIABLE}=token, but this machine has no Ray token: {copy_token}"
    if any(word in ray_log for word in AUTH_REFUSED):
        if token_sent:
            return (f"{where} refused this machine's Ray token: put the cluster's token (`ray get-auth-token` on "
                    "its head node prints it) in ~/.ray/auth_token or RAY_AUTH_TOKEN")
        return f"{where} asks for a Ray token and this machine has none: {copy_token}"
    if versions := VERSION_MISMATCH.search(message):
        cluster_ray, cluster_python, own_ray, own_python = versions.groups()
        return (f"{where} runs Ray {cluster_ray} on Python {cluster_python}, this machine Ray {own_ray} on Python "
                f"{own_python}: the driver needs the same versions (pip install 'ray[default]=={cluster_ray}' in a "
                f"Python {cluster_python} environment)")
    if address == "auto" and "Could not find any running Ray instance" in message:
        return ("--address auto found no running Ray cluster on this machine (nor in RAY_ADDRESS): start one with "
                "`ray start --head`, or give --address HOST:PORT")
    first = message.strip().splitlines()[0] if message.strip() else type(error).__name__
    return f"cannot join {where}: {first}"
