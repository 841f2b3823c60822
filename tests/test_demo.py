"""`panel-rig demo` stopped half-way: its node and operator do not outlive it, the wind goes off, the bag closes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("how", "status"), [("sigterm", 143), ("ctrl_c", 130)])
def test_a_stopped_demo_stops_its_children_and_closes_the_bag(tmp_path: Path, how: str, status: int) -> None:
    """SIGTERM ended the demo at once while its node ran on, recording without limit (106 MB in 15 s); a Ctrl-C
    in the terminal (SIGINT to the whole process group) stopped the node before the operator's wind-off. The
    children now run in their own sessions and the demo stops them in order: operator (0 m/s), then node."""
    psutil = pytest.importorskip("psutil")
    pytest.importorskip("rclpy")
    from panel_rig.recording.reader import read_bag

    out, bags = tmp_path / "out", tmp_path / "bags"
    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "demo", "--out", str(out), "--bag-dir", str(bags)],
                            cwd=ROOT, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:  # until the operator's first command is recorded
            if any(b"/rig/airspeed_cmd" in f.read_bytes() for f in bags.glob("rig_*/*.mcap")):
                break
            time.sleep(0.2)  # polling the bag the demo writes (flushed every fraction of a second), bounded
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 2, "no node and operator under the demo"
        if how == "sigterm":
            proc.send_signal(signal.SIGTERM)
        else:
            os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == status, err[-2000:]
    _, alive = psutil.wait_procs(children, timeout=60)
    assert not alive, f"left running: {[p.cmdline()[:4] for p in alive]}"
    (bag,) = bags.glob("rig_*")
    assert (bag / "metadata.yaml").exists()  # closed, not a recording to recover
    assert _commands(read_bag, bags)[-1] == 0.0, "the wind was not turned off"  # the operator's wind-off


def _commands(read_bag, bags: Path) -> list[float]:
    (bag,) = bags.glob("rig_*")
    return [m.data for topic, _, _, m in read_bag(bag) if topic.endswith("/airspeed_cmd")]
