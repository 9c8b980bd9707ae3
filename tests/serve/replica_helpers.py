"""Replicas of `smf serve` behind HAProxy on this machine's loopback, with the shipped configuration: started,
waited for, killed or stopped one by one (the replica tests and benchmarks/serve_replicas.py)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from serve_helpers import free_port
from stablemofusion.serve.balancer import haproxy_config, haproxy_env

HOST = "127.0.0.1"  # never any other address
SERVE = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"
HAPROXY = shutil.which("haproxy") or "/usr/sbin/haproxy"
START_TIMEOUT_S = 300.0


def haproxy_available() -> bool:
    return os.path.exists(HAPROXY)


def wait_ready(url: str, timeout: float = START_TIMEOUT_S, replicas: int = 1) -> None:
    """Until ``url``'s /v1/health answers 200 (through a balancer: until ``replicas`` distinct replicas have)."""
    seen, deadline = set(), time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            r = httpx.get(f"{url}/v1/health", timeout=2)
            if r.status_code == 200:
                seen.add(r.headers.get("x-smf-replica", url))
                if len(seen) >= replicas:
                    return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    raise TimeoutError(f"{url} not ready after {timeout} s ({len(seen)} of {replicas} replicas)")


class Replicas:
    """``count`` `smf serve` processes (each in a process group of its own, with its worker processes) and
    HAProxy in front of them. ``url`` is the balancer's, ``urls[k]`` replica k's."""

    def __init__(self, count: int, folder: Path, serve_args: tuple[str, ...] = ("--engine", "onnx", "--threads", "1")):
        self.count, self.folder, self.serve_args = count, Path(folder), tuple(serve_args)
        self.ports = [free_port() for _ in range(count)]
        self.urls = [f"http://{HOST}:{p}" for p in self.ports]
        self.port = free_port()
        self.url = f"http://{HOST}:{self.port}"
        self.replicas: list[subprocess.Popen | None] = [None] * count
        self.balancer: subprocess.Popen | None = None
        self.logs: list = []  # the processes' stderr files, closed with them

    def start_replica(self, k: int) -> None:
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        self.replicas[k] = subprocess.Popen(
            [sys.executable, "-c", SERVE, "serve", "--host", HOST, "--port", str(self.ports[k]), *self.serve_args],
            env=env, stdout=subprocess.DEVNULL, stderr=self._log(f"replica{k}.log"), start_new_session=True)

    def _log(self, name: str):
        self.logs.append(open(self.folder / name, "ab"))
        return self.logs[-1]

    def start(self) -> "Replicas":
        for k in range(self.count):
            self.start_replica(k)
        for url in self.urls:
            wait_ready(url)
        config = self.folder / "haproxy.cfg"
        config.write_text(haproxy_config(self.count))
        env = {**os.environ, **haproxy_env(f"{HOST}:{self.port}", [f"{HOST}:{p}" for p in self.ports])}
        self.balancer = subprocess.Popen([HAPROXY, "-db", "-f", str(config)], env=env, stdout=subprocess.DEVNULL,
                                         stderr=self._log("haproxy.log"))
        wait_ready(self.url, 60, replicas=self.count)
        return self

    def signal(self, k: int, sig: int) -> None:
        """Send ``sig`` to replica k: SIGKILL to its whole process group (server and workers die at once, as a
        machine that fails), any other signal to the server alone (SIGTERM: it drains and stops its workers)."""
        proc = self.replicas[k]
        if sig == signal.SIGKILL:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)

    def close(self) -> None:
        for proc in [self.balancer, *self.replicas]:
            if proc is not None and proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL) if proc is not self.balancer else proc.kill()
                proc.wait(30)
        for log in self.logs:
            log.close()

    def __enter__(self) -> "Replicas":
        try:
            return self.start()
        except BaseException:
            self.close()
            raise

    def __exit__(self, *exc) -> None:
        self.close()
