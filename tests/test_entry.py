"""Console entry points: a Ctrl-C while the program is still being imported ends with one line and status 130; each
program names itself as the user called it."""

from __future__ import annotations

import importlib
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

from panel_rig import cli, entry
from panel_rig.processes import INTERRUPTED_STATUS

SLOW_MODULE = "import os, signal\nos.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while this module loads\n"


def test_ctrl_c_during_the_import_is_one_line_and_status_130(tmp_path):
    (tmp_path / "slow_program.py").write_text(SLOW_MODULE + "def main():\n    return 0\n")
    code = (f"import sys; sys.path.insert(0, {str(tmp_path)!r}); from panel_rig.entry import launch; "
            "sys.exit(launch('slow_program', 'slow'))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == INTERRUPTED_STATUS
    assert proc.stderr == "slow: interrupted\n"


def test_launch_returns_the_program_s_status(tmp_path, monkeypatch):
    (tmp_path / "done_program.py").write_text("def main():\n    return 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert entry.launch("done_program", "done") == 3


def test_installed_commands_go_through_the_entry_module():
    scripts = {ep.name: ep.value for ep in entry_points(group="console_scripts")
               if ep.name in ("panel-rig", "rig_node", "rig_operator", "rig_controller")}
    assert scripts == {
        "panel-rig": "panel_rig.entry:panel_rig",
        "rig_node": "panel_rig.entry:rig_node",
        "rig_operator": "panel_rig.entry:rig_operator",
        "rig_controller": "panel_rig.entry:rig_controller",
    }
    for value in scripts.values():
        assert callable(getattr(entry, value.split(":")[1]))


@pytest.mark.parametrize(("command", "usage"), [
    (["run", "--help"], "usage: panel-rig run"),
    (["operate", "--help"], "usage: panel-rig operate"),
    (["control", "--help"], "usage: panel-rig control"),
    (["operate", "--profile", "config/staircase.yaml", "--timeout", "-1"], "panel-rig operate: --timeout"),
])
def test_programs_behind_panel_rig_give_the_command_the_user_typed(command, usage, capsys):
    """`panel-rig run --help` said "usage: rig_node" (the ros2-run name) where the user had typed `panel-rig run`."""
    try:
        code = cli.main(command)
    except SystemExit as done:  # argparse's --help
        code = done.code
    out = capsys.readouterr()
    assert code in (0, 2)
    assert (out.out + out.err).startswith(usage), out


@pytest.mark.parametrize(("main", "usage"), [
    ("panel_rig.ros.rig_node", "usage: rig_node"),
    ("panel_rig.ros.operator", "usage: rig_operator"),
    ("panel_rig.ros.controller", "usage: rig_controller"),
])
def test_the_installed_programs_keep_their_own_names(main, usage, capsys):
    with pytest.raises(SystemExit):
        importlib.import_module(main).main(["--help"])
    assert capsys.readouterr().out.startswith(usage)


@pytest.mark.parametrize("program", ["run", "operate", "control", "control-demo", "demo"])
def test_a_program_s_unknown_option_is_one_line(program, capsys):
    """`panel-rig control-demo --bogus` (and run, operate, control, demo) printed argparse's usage block before the
    error, two lines where every other subcommand gives one."""
    with pytest.raises(SystemExit) as done:
        cli.main([program, "--bogus"])
    err = capsys.readouterr().err.strip()
    assert done.value.code == 2 and err.startswith(f"panel-rig {program}: error: ") and "\n" not in err, err


@pytest.mark.parametrize("study", ["flutter_study", "elastica_study", "sensitivity", "exact_study", "scheme_study"])
def test_a_study_script_s_help_describes_it_instead_of_running_it(study):
    """`python -m panel_rig.analysis.flutter_study --help` started its 2-6 minutes of computation (no parser)."""
    module = f"panel_rig.analysis.{study}"
    shown = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=120)
    assert shown.returncode == 0 and shown.stdout.startswith(f"usage: python -m {module}"), shown.stderr
    assert "|---" not in shown.stdout  # no table: nothing was computed
    wrong = subprocess.run([sys.executable, "-m", module, "--bogus"], capture_output=True, text=True, timeout=120)
    assert wrong.returncode == 2 and wrong.stdout == ""
    assert wrong.stderr == f"python -m {module}: error: unrecognized arguments: --bogus\n"
