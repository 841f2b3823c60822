"""Every shell command in README.md's code blocks works as written (so the README cannot drift again).

Commands are the code-block lines whose first word is a program we ship or document. Each is either run here
(bounded in time, in a scratch copy of the repository's config/ and bags/), or listed in ``NOT_RUN_HERE`` with
the reason. A command the README gains that this file does not classify fails the test.
"""

from __future__ import annotations

import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PROGRAMS = ("panel-rig", ".venv/bin/panel-rig", "ros2", "python", "make", ".venv/bin/rerun", "colcon")

#: first words -> why the suite does not run them
NOT_RUN_HERE = {
    ("ros2",): "the ros2 CLI (ros2cli) is not on PyPI; the same calls are made with rclpy in tests/test_node.py",
    ("make",): "the README's own entry points: `make test` is this suite, `make run` is the demo + paper report",
    ("python", "benchmarks/run.py"): "benchmarks take minutes; run by hand (figures in the README and validation)",
    (".venv/bin/rerun",): "opens a viewer (a display or a browser); checked by hand, screenshot in docs/figures",
    ("colcon",): "needs a ROS workspace; tests/test_packaging.py runs `colcon list` on the package",
    ("panel-rig", "study", "--scheduler"): "needs a running Dask scheduler and workers; tests/test_studies.py "
                                           "starts them on 127.0.0.1 and runs the same command against them",
    ("panel-rig", "control-demo"): "takes ~40 s; tests/test_control_node.py runs the same loop (node + controller)",
    (".venv/bin/panel-rig", "flutter-test"): "takes ~1 min; tests/test_flutter_test.py runs it with a short dwell and --set",
}
#: long-running programs: started, then stopped with SIGINT once they show they work
SERVICES = {"run": "panel_rig up", "operate": None, "control": "controller up"}
TIMEOUT_S = 240.0


def readme_commands() -> list[str]:
    """The command lines of README.md's fenced code blocks (comments stripped), in order."""
    text = (ROOT / "README.md").read_text()
    out = []
    for block in re.findall(r"^ *```[a-z]*\n(.*?)^ *```", text, flags=re.S | re.M):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and line.split()[0] in PROGRAMS:
                out.append(line)
    return out


def skip_reason(cmd: str) -> str | None:
    words = tuple(cmd.split())
    for prefix, reason in NOT_RUN_HERE.items():
        if words[: len(prefix)] == prefix:
            return reason
    return None


def argv(cmd: str) -> list[str]:
    """The command with the venv's programs (the README's `panel-rig` is `.venv/bin/panel-rig`)."""
    words = shlex.split(cmd)
    if words[0] in ("panel-rig", ".venv/bin/panel-rig"):
        words[0] = str(BIN / "panel-rig")
    return words


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scratch working directory with copies of config/ and bags/ (commands may write there)."""
    d = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "config", d / "config")
    shutil.copytree(ROOT / "bags", d / "bags", ignore=shutil.ignore_patterns("*.broken"))
    return d


@pytest.fixture(scope="module")
def env(ros_env: dict[str, str], scratch: Path) -> dict[str, str]:
    return dict(ros_env, ROS_LOG_DIR=str(scratch / "ros_log"), MPLBACKEND="Agg")


def test_readme_has_the_commands_we_expect() -> None:
    cmds = readme_commands()
    assert len(cmds) >= 12
    assert any(c.startswith(".venv/bin/panel-rig run --ros-args") for c in cmds)


def _run_service(words: list[str], ready: str | None, scratch: Path, env: dict[str, str]) -> tuple[int, str]:
    """Start a long-running command; once ``ready`` is in its output (or after it ran 3 s without failing),
    stop it with SIGINT. Returns (exit code, output)."""
    log = scratch / f"service_{time.monotonic_ns()}.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen(words, cwd=scratch, env=env, stdout=fh, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60.0
        started = time.monotonic()
        while proc.poll() is None and time.monotonic() < deadline:
            text = log.read_text(errors="replace")
            if (ready and ready in text) or (ready is None and time.monotonic() - started > 3.0):
                break
            time.sleep(0.1)  # polling a log file, not synchronising two parties
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        code = proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return code, log.read_text(errors="replace")


@pytest.mark.parametrize("cmd", readme_commands())
def test_readme_command_works_as_written(cmd: str, scratch: Path, env: dict[str, str]) -> None:
    reason = skip_reason(cmd)
    if reason:
        pytest.skip(reason)
    words = argv(cmd)
    assert Path(words[0]).name == "panel-rig", f"unclassified README command: {cmd}"
    sub = words[1]
    if sub in SERVICES:
        if sub == "operate":  # needs a rig to talk to: the README's node command, in fast mode
            node = [str(BIN / "panel-rig"), "run", "--fast", "--ros-args", "-r", "__ns:=/rig"]
            with open(scratch / "operate_node.log", "w") as fh:
                rig = subprocess.Popen(node, cwd=scratch, env=env, stdout=fh, stderr=subprocess.STDOUT)
            try:  # the profile ends by itself (90 s simulated): no signal whose arrival could race its exit
                done = subprocess.run(words, cwd=scratch, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
            finally:
                rig.send_signal(signal.SIGINT)
                rig.wait(30)
            out = done.stdout + done.stderr
            # against the default (full) node the staircase's flutter reaches the wall and the rig aborts, as the
            # README says: exit 1 with the line saying the profile did not run as written
            assert done.returncode == 0 or (done.returncode == 1 and "the profile did not run as written: the rig "
                                            "aborted during step" in done.stderr), out[-2000:]
            assert "unrecognized arguments" not in out and "Traceback" not in out, out[-2000:]
            return
        code, out = _run_service(words, SERVICES[sub], scratch, env)
        assert SERVICES[sub] in out, out[-2000:]
        assert code == 0, out[-2000:]
        assert "Traceback" not in out
        return
    proc = subprocess.run(words, cwd=scratch, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, f"{cmd}\n{proc.stderr[-2000:]}"
    assert "Traceback" not in proc.stderr


def test_the_readme_s_study_spec_is_the_shipped_example() -> None:
    """The README showed a 0.20..0.30 m, 6-level spec right under `--spec config/studies/flutter_map_small.yaml`,
    whose file has 0.25..0.29 m in 2 levels: a reader took one for the other. The block now is that file."""
    import yaml

    text = (ROOT / "README.md").read_text()
    block = re.search(r"```yaml\n(# config/studies/flutter_map_small\.yaml.*?)```", text, re.S)
    assert block, "the README's commented copy of flutter_map_small.yaml"
    shown = yaml.safe_load(block[1])
    shipped = yaml.safe_load((ROOT / "config/studies/flutter_map_small.yaml").read_text())
    assert shown.pop("aero") == "rom"  # the default the README spells out
    assert shown == shipped
