"""Helpers of the tests that run ``illumon serve`` as a real process on a free loopback port."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import httpx
from illumon_service.process import free_port, stop_process, wait_healthy

ILLUMON = Path(sys.executable).with_name("illumon")


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
        stop_process(self.proc)


def start_server(data_dir: Path, *, port: int | None = None, env: dict[str, str] | None = None,
                 log_level: str = "info", database_url: str | None = None, timeout: float = 60,
                 workers: int = 1) -> Server:
    """Start ``illumon serve`` (``workers`` processes) and wait until ``/healthz`` answers (AssertionError with the
    log otherwise)."""
    port = port or free_port()
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("ILLUMON_")}
    full_env.update(env or {})
    full_env.setdefault("OMP_NUM_THREADS", "1")
    log_path = Path(tempfile.mkstemp(prefix="illumon-serve-", suffix=".log", dir=data_dir.parent)[1])
    cmd = [str(ILLUMON), "serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data_dir),
           "--log-level", log_level]
    if database_url:
        cmd += ["--database-url", database_url]
    if workers > 1:
        cmd += ["--workers", str(workers)]
    with open(log_path, "ab") as fh:
        proc = subprocess.Popen(cmd, env=full_env, stdout=fh, stderr=subprocess.STDOUT)
    server = Server(proc, port, data_dir, log_path, full_env)
    try:
        wait_healthy(proc, server.base, timeout=timeout, describe=server.log)
    except RuntimeError as exc:
        raise AssertionError(str(exc)) from None
    return server
