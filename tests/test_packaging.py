"""package.xml is valid for catkin_pkg, and colcon sees the package as ros.ament_python."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from panel_rig.ros.discovery import PROFILE

ROOT = Path(__file__).resolve().parents[1]


def test_package_xml_passes_catkin_pkg_validation() -> None:
    package = pytest.importorskip("catkin_pkg.package")
    pkg = package.parse_package(str(ROOT / "package.xml"), warnings=(warnings := []))
    pkg.validate()  # raises InvalidPackage on any error (e.g. a bad maintainer e-mail)
    assert pkg.name == "panel_rig" and not warnings
    assert pkg.get_build_type() == "ament_python"


def test_colcon_lists_the_package_as_ament_python(tmp_path: Path) -> None:
    colcon = Path(sys.executable).with_name("colcon")
    if not colcon.exists():
        pytest.skip("colcon not installed (pip install colcon-core colcon-ros colcon-python-setup-py)")
    pkg = tmp_path / "src" / "panel_rig"
    pkg.mkdir(parents=True)
    for name in ("package.xml", "setup.py", "setup.cfg"):
        shutil.copy(ROOT / name, pkg / name)
    for name in ("resource", "panel_rig", "config", "launch"):
        shutil.copytree(ROOT / name, pkg / name, ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, COLCON_HOME=str(tmp_path / "colcon_home"), COLCON_LOG_PATH=str(tmp_path / "log"))
    out = subprocess.run([str(colcon), "list"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line.split() for line in out.stdout.splitlines() if line.strip()]
    assert ["panel_rig", "src/panel_rig", "(ros.ament_python)"] in rows, out.stdout


def test_version_is_one_number_in_setup_package_xml_and_the_cli(capsys: pytest.CaptureFixture[str]) -> None:
    """`panel-rig --version` failed ("the following arguments are required: command"); it prints the installed
    version, which is package.xml's (colcon and pip read the two files separately)."""
    import re

    from panel_rig.cli import main

    xml = re.search(r"<version>([^<]+)</version>", (ROOT / "package.xml").read_text()).group(1)
    setup = re.search(r'version="([^"]+)"', (ROOT / "setup.py").read_text()).group(1)
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"panel-rig {xml}" and setup == xml


def test_the_dds_profile_is_installed_with_the_package(tmp_path: Path) -> None:
    """The node's Fast DDS profile (panel_rig/ros/discovery.py) is package data: a built package that left it out
    would start with Fast DDS's 3 s announcements and no word."""
    out = subprocess.run([sys.executable, "setup.py", "-q", "build_py", "--build-lib", str(tmp_path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    built = tmp_path / "panel_rig" / "ros" / PROFILE.name
    assert built.read_text() == PROFILE.read_text()
