"""`panel-rig control-demo`: its summary's numbers, and a demo stopped half-way writing what it measured."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from panel_rig import jsonio

ROOT = Path(__file__).resolve().parents[1]


def test_summary_takes_the_diagnostics_as_numbers() -> None:
    """The node's diagnostics are KeyValues (text): the summary had `"control_commands": "1200"`. Counts are
    integers, command ages floats, and a 'nan' (no command yet) is null, not a string or NaN."""
    from panel_rig.control_demo import diagnostics_summary

    d = diagnostics_summary({"control_latency_mean_total_ms": "0.213", "control_latency_p99_total_ms": "nan",
                             "control_commands": "1200", "rejected_commands": "0", "state": "running"})
    assert json.loads(jsonio.dumps(d)) == {"latency_mean_total_ms": 0.213, "latency_p99_total_ms": None,
                                           "rig_state": "running", "control_commands": 1200, "rejected_commands": 0}
    assert isinstance(d["control_commands"], int) and diagnostics_summary({})["control_commands"] is None


def test_onset_summary_interpolates_the_first_zero_crossing_of_the_steps_so_far() -> None:
    from panel_rig.control_demo import ONSET_FACTORS, onset_summary

    s = onset_summary([-0.5, 0.5], 10.0)
    assert s["emulated_closed_loop_onset_mps"] == pytest.approx(5 * (ONSET_FACTORS[0] + ONSET_FACTORS[1]))
    assert s["onset_airspeeds_mps"] == pytest.approx([10 * f for f in ONSET_FACTORS[:2]])
    none = onset_summary([-0.5], 10.0)  # stopped after the first step: nothing bracketed yet
    assert none["emulated_closed_loop_onset_mps"] is None and none["onset_growth_rates_per_s"] == [-0.5]


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_a_stopped_control_demo_writes_what_it_measured(tmp_path: Path, sig: int, status: int, stderr_lines) -> None:
    """Stopped after the quiet check: summary.json with that check, `"interrupted": true`, the bag and the node
    log; status 130/143; node and controller stopped. Before, nothing was written."""
    psutil = pytest.importorskip("psutil")
    pytest.importorskip("rclpy")
    out, bags = tmp_path / "out", tmp_path / "bags"
    # relative directories, from another working directory: the summary's paths come out absolute (the bag's
    # was relative while the .rrd's and the logs' were absolute)
    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "control-demo", "--json", "--out", "out",
                             "--bag-dir", "bags"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    err = stderr_lines(proc)
    try:
        err.wait_for("1.2 U_f =", 240)  # the quiet check measured; the onset steps begin
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 2, "no node and controller under the demo"
        proc.send_signal(sig)
        proc.wait(timeout=120)
        stdout = proc.stdout.read()
    finally:
        err.close()
    text = err.text
    assert stdout.strip(), f"status {proc.returncode}, nothing on stdout; stderr:\n{text[-3000:]}"
    printed = json.loads(stdout)
    assert proc.returncode == status, text[-2000:]
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, f"left running: {[p.cmdline()[:4] for p in alive]}"
    summary = json.loads((out / "summary.json").read_text())
    assert summary == printed and summary["interrupted"] is True
    assert summary["quiet_tip_rms_m"] > 0 and isinstance(summary["quiet"], bool)
    assert summary["node_exit"] == 0 and summary["controller_exit"] == 0
    assert Path(summary["bag"], "metadata.yaml").exists() and Path(summary["node_log"]).exists()
    assert all(Path(summary[k]).is_absolute() for k in ("bag", "node_log", "controller_log")), summary
    assert Path(summary["bag"]).parent == bags
    assert isinstance(summary["control_commands"], int) and summary["control_commands"] > 0
    assert isinstance(summary["latency_mean_total_ms"], float)
    assert f"stopped by {signal.Signals(sig).name}" in text
    # the message names the run's own summary (summary.json is a copy of the latest run's)
    (own,) = out.glob("control_demo_*_summary.json")
    assert str(own) in text and json.loads(own.read_text()) == summary
    from panel_rig.recording.series import load_series

    assert load_series(summary["bag"]).commands["airspeed_cmd"][-1][1] == 0.0  # the wind off, recorded


def test_a_failed_control_demo_writes_what_it_measured(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A demo that fails part-way (a set-point the tunnel does not reach in time: DemoError) wrote no summary.json.
    Now it does, with the reason under "error", and the message names it; node and controller are stopped."""
    pytest.importorskip("rclpy")
    import panel_rig.control_demo as demo

    monkeypatch.setenv("ROS_DOMAIN_ID", "0")  # run() joins its own domain: restored after the test
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    reason = "timed out after 60 s waiting for the tunnel at 1.2 U_f"

    def tunnel_never_there(client: object, u_f: float) -> dict:
        raise demo.DemoError(reason)

    monkeypatch.setattr(demo, "_quiet_check", tunnel_never_there)
    out = tmp_path / "out"
    with pytest.raises(demo.DemoError, match=f"{reason}; what was measured so far is in {out}/control_demo_.*_summary"):
        demo.run(2.0, out, tmp_path / "bags", log=lambda line: None)
    summary = json.loads((out / "summary.json").read_text())
    (own,) = out.glob("control_demo_*_summary.json")
    assert json.loads(own.read_text()) == summary
    assert summary["error"] == reason and summary["interrupted"] is False
    assert summary["node_exit"] == 0 and summary["controller_exit"] == 0
    assert summary["quiet"] is None and summary["onset_growth_rates_per_s"] == []
    assert Path(summary["bag"], "metadata.yaml").exists()


def test_a_delay_the_law_cannot_take_is_refused_before_anything_starts(tmp_path: Path) -> None:
    """A 50 ms command age: the linear model (the delay as cascaded Padé sections) predicts the loop unstable from
    low speed. The demo once predicted 13.73 m/s there (one Padé approximant of the whole delay), started the node
    and its rig aborted at 1.2 U_f; it now refuses, naming the delay, before any node runs."""
    out, bags = tmp_path / "out", tmp_path / "bags"
    proc = subprocess.run([sys.executable, "-m", "panel_rig.cli", "control-demo", "--delay-ms", "50", "--out",
                           str(out), "--bag-dir", str(bags)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "51.24 ms loop delay" in lines[0] and "unstable from low speed" in lines[0], proc.stderr
    assert not bags.exists() and not out.exists()  # no node ran, nothing recorded, no empty directory left
