"""Record the reference bag `bags/stiffness_staircase/` and its analysis (run from the repo root).

The node runs in fast mode (stiffness variant, tunnel lag 0.3 s, the default tunnel turbulence and tip sensor)
and records at a reduced rate to keep the bag under 2 MB: readings at 64 Hz (`publish_rate_hz`, 32 physics steps
of 1/2048 s; the LCO is ~23 Hz), the panel shape at 1 Hz, and paced at 2x real time
(`fast_max_realtime_factor`) so that the operator's commands land on time. The operator plays
`bags/stiffness_staircase.yaml`; it is started before the node, so that little rest is recorded before its first
command. The turbulence is seeded (`tunnel.turbulence.seed`, default 0); the operator's command times are not
(they land on the rig's clock within a publish period), so a re-recording differs in detail, not in kind.
Then `panel-rig analyze` writes `analysis.json` and the PNGs next to the bag; `--analysis-only` rewrites them
for the shipped bag without recording it again (after a change to the analysis).

    .venv/bin/python bags/make_reference.py [--analysis-only]
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
NAME = "stiffness_staircase"
NODE_PARAMS = ["model.variant:=stiffness", "tunnel.time_constant_s:=0.3", "publish_rate_hz:=64.0", "shape_rate_hz:=1.0",
               "diagnostics_rate_hz:=0.5", "record:=true", "fast_max_realtime_factor:=2.0"]


def record(tmp: Path) -> Path:
    """Node + operator; returns the recorded bag directory."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 199)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(tmp / "log"))
    params = [a for p in [*NODE_PARAMS, f"bag_dir:={tmp / 'bags'}"] for a in ("-p", p)]
    os.environ.update(env)  # the operator runs in this process: same domain
    import rclpy

    from panel_rig.ros.operator import Operator, format_summary, load_profile

    steps = load_profile(ROOT / "bags" / f"{NAME}.yaml")
    # the operator first: the node's fast mode runs (and records) from its start, so every second it waits for the
    # operator to be discovered is recorded at rest (a loaded machine once put 49 s of rest at the start)
    rclpy.init()
    operator = Operator("/rig", 60.0)
    node = subprocess.Popen([sys.executable, "-m", "panel_rig.ros.rig_node", "--fast", "--ros-args", "-r", "__ns:=/rig",
                             *params], env=env, cwd=ROOT)
    try:
        summary = operator.play(steps)
    finally:
        node.send_signal(signal.SIGINT)  # at once: the node runs ahead in fast mode
        node.wait(30)
        operator.destroy_node()
        rclpy.shutdown()
    print(format_summary(summary))
    (bag,) = (tmp / "bags").iterdir()
    return bag


def install(bag: Path, dest: Path) -> None:
    """Move the bag to dest, renaming its MCAP to `<dest>_0.mcap` (metadata.yaml follows)."""
    if dest.exists():
        shutil.rmtree(dest)
    shutil.move(str(bag), dest)
    old = next(dest.glob("*.mcap"))
    new = dest / f"{dest.name}_0.mcap"
    old.rename(new)
    meta_path = dest / "metadata.yaml"
    doc = yaml.safe_load(meta_path.read_text())
    info = doc["rosbag2_bagfile_information"]
    info["relative_file_paths"] = [new.name]
    for f in info["files"]:
        f["path"] = new.name
    meta_path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=False))


def main(argv: list[str]) -> int:
    from panel_rig.analyze_cli import analyze_bag, format_table

    dest = ROOT / "bags" / NAME
    if "--analysis-only" not in argv:
        with tempfile.TemporaryDirectory() as tmp:
            install(record(Path(tmp)), dest)
    result = analyze_bag(dest, plots_dir=dest / "plots")
    result["bag"] = f"bags/{NAME}"
    result["plots"] = [str(Path(p).relative_to(ROOT)) for p in result["plots"]]
    (dest / "analysis.json").write_text(json.dumps(result, indent=2) + "\n")
    print(format_table(result))
    size = sum(p.stat().st_size for p in dest.rglob("*") if p.is_file())
    print(f"{dest}: {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
