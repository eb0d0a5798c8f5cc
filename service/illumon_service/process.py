"""``illumon serve`` as a child process, for tests, benchmarks and demos: a free port, waiting for ``/healthz``, stopping."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from collections.abc import Callable

import httpx

__all__ = ["free_port", "wait_healthy", "stop_process"]


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_healthy(
    proc: subprocess.Popen, base_url: str, *, timeout: float = 60.0, describe: Callable[[], str] = lambda: ""
) -> None:
    """Return once ``base_url/healthz`` answers 200.

    Raises
    ------
    RuntimeError
        When the process exits first or ``timeout`` seconds pass (killed then); the message ends with ``describe()``
        (e.g. the server's log).
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"serve exited with {proc.returncode}: {describe()}")
        try:
            if httpx.get(f"{base_url}/healthz", timeout=1, trust_env=False).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    stop_process(proc, grace=0)
    raise RuntimeError(f"serve did not answer /healthz within {timeout:g} s: {describe()}")


def stop_process(proc: subprocess.Popen, *, grace: float = 20.0) -> None:
    """SIGTERM (graceful shutdown), SIGKILL after ``grace`` seconds; reaps the process."""
    if proc.poll() is not None:
        return
    if grace > 0:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=grace)
            return
        except subprocess.TimeoutExpired:
            pass
    proc.kill()
    proc.wait(timeout=20)
