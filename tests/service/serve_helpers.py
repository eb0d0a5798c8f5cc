"""Helpers of the tests that run ``illumon serve`` as a real process on a free loopback port."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ILLUMON = Path(sys.executable).with_name("illumon")


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    """A running ``illumon serve`` process; its standard output and error go to a file read by :meth:`log`."""

    proc: subprocess.Popen
    port: int
    data_dir: Path
    log_path: Path
    env: dict[str, str] = field(default_factory=dict)

    @property
    def base(self) -> str:
        """Base URL."""
        return f"http://127.0.0.1:{self.port}"

    def client(self, timeout: float = 60) -> httpx.Client:
        """An HTTP client bound to the server (no proxies from the environment)."""
        return httpx.Client(base_url=self.base, trust_env=False, timeout=timeout)

    def log(self) -> str:
        """Everything the process wrote so far (stdout and stderr)."""
        return self.log_path.read_text(errors="replace")

    def kill(self) -> None:
        """SIGKILL and reap."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=20)

    def stop(self) -> None:
        """SIGTERM (graceful), SIGKILL after 20 s."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.kill()


def start_server(data_dir: Path, *, port: int | None = None, env: dict[str, str] | None = None,
                 log_level: str = "info", database_url: str | None = None, timeout: float = 60) -> Server:
    """Start ``illumon serve`` and wait until ``/healthz`` answers (AssertionError with the log otherwise)."""
    port = port or free_port()
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("ILLUMON_")}
    full_env.update(env or {})
    full_env.setdefault("OMP_NUM_THREADS", "1")
    log_path = Path(tempfile.mkstemp(prefix="illumon-serve-", suffix=".log", dir=data_dir.parent)[1])
    cmd = [str(ILLUMON), "serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data_dir),
           "--log-level", log_level]
    if database_url:
        cmd += ["--database-url", database_url]
    with open(log_path, "ab") as fh:
        proc = subprocess.Popen(cmd, env=full_env, stdout=fh, stderr=subprocess.STDOUT)
    server = Server(proc, port, data_dir, log_path, full_env)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"serve exited with {proc.returncode}: {server.log()}")
        try:
            if httpx.get(f"{server.base}/healthz", timeout=1, trust_env=False).status_code == 200:
                return server
        except httpx.TransportError:
            time.sleep(0.1)
    server.kill()
    raise AssertionError(f"serve did not answer /healthz within {timeout} s: {server.log()}")
