"""Shared fixtures: the paper's configuration and models built once per session; a private ROS 2 graph."""

import os
import queue
import subprocess
import threading
from collections.abc import Callable, Iterator

import pytest

from panel_rig.config import load_config
from panel_rig.domains import TEST_DOMAINS, claim_domain_id
from panel_rig.model.aeroelastic import AeroelasticModel


@pytest.fixture(scope="session")
def cfg():
    return load_config()


@pytest.fixture(scope="session")
def model(cfg):
    return AeroelasticModel(cfg)


@pytest.fixture(scope="module")
def ros_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A private ROS 2 graph for one test module: a free domain (TEST_DOMAINS, away from the default 0 of a user's
    own nodes and the programs' PRIVATE_DOMAINS; claimed, so a suite run beside this one never shares it),
    discovery on localhost only, logs in a temporary directory. Applied to this process (the rclpy clients a test
    makes join it) and restored afterwards; yields the whole environment, for the nodes a test starts."""
    claim = claim_domain_id(*TEST_DOMAINS)
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("ROS_DOMAIN_ID", str(claim.domain_id))
            mp.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            mp.setenv("ROS_LOG_DIR", str(tmp_path_factory.mktemp("ros_log")))
            mp.setenv("PYTHONFAULTHANDLER", "1")  # a child's native crash prints where it was (the test shows its output)
            yield dict(os.environ)
    finally:
        claim.release()


class StderrLines:
    """A child's stderr read line by line in a thread: a test waits for a line, never for a time."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self._lines: queue.Queue[str] = queue.Queue()
        self._seen: list[str] = []
        self._proc = proc
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen) -> None:
        for line in proc.stderr:
            self._seen.append(line)
            self._lines.put(line)

    def wait_for(self, prefix: str, timeout_s: float) -> str:
        """The first line from now on that starts with ``prefix`` (queue.Empty after ``timeout_s`` without a line)."""
        line = ""
        while not line.startswith(prefix):
            line = self._lines.get(timeout=timeout_s)
        return line

    @property
    def text(self) -> str:
        """Everything read so far (all of it once the child has ended and :meth:`close` returned)."""
        return "".join(self._seen)

    def close(self) -> None:
        """Kill the child if it still runs (a failed test), and wait for the reader."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._thread.join(10)


@pytest.fixture
def stderr_lines() -> Iterator[Callable[[subprocess.Popen], StderrLines]]:
    """``stderr_lines(proc)``: a :class:`StderrLines` of a child started with ``stderr=subprocess.PIPE, text=True``
    (its reader is joined at the end of the test)."""
    readers: list[StderrLines] = []

    def start(proc: subprocess.Popen) -> StderrLines:
        readers.append(StderrLines(proc))
        return readers[-1]

    yield start
    for reader in readers:
        reader.close()
