"""The panel-rig CLI and the parameter file: figures as JSON, bad input as exit 2 with one line."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from panel_rig.analysis.published import NATURAL_FREQUENCIES_HZ
from panel_rig.config import ConfigError, config_from_flat, load_config

CLI = [sys.executable, "-m", "panel_rig.cli"]


def run(*args):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)


def test_modes_json():
    out = run("modes", "--json")
    assert out.returncode == 0, out.stderr
    f = json.loads(out.stdout)["natural_frequencies_hz"]
    assert f == pytest.approx(list(NATURAL_FREQUENCIES_HZ), rel=0.025)


@pytest.mark.parametrize("extra", [[], ["--aero", "rom", "--rom-modes", "12"]])
def test_flutter_json(extra):
    out = run("flutter", "--json", *extra)
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["flutter_frequency_hz"] == pytest.approx(22.37, rel=0.03)
    assert d["dominant_mode"] == 2
    assert 9 < d["flutter_speed_mps"] < 13


def test_flutter_plot(tmp_path):
    png = tmp_path / "new" / "dir" / "fig3.png"  # its directory is made when the figure is saved
    out = run("flutter", "--plot", str(png))
    assert out.returncode == 0, out.stderr
    assert png.stat().st_size > 10_000
    assert out.stdout.splitlines()[-1].split() == ["plot", str(png)]  # the table names the file it wrote


@pytest.mark.parametrize("args,needle", [
    (["modes", "--set", "nonsense.key=1"], "nonsense.key"),
    (["modes", "--set", "panel.thickness_m=-0.001"], "panel.thickness_m"),
    (["modes", "--set", "aero.elements=0"], "aero.elements"),
    (["modes", "--params", "/no/such/file.yaml"], "not found"),
    (["operate", "--profile", "config"], "is a directory"),  # was "profile not found"
    (["flutter", "--rom-modes", "0", "--aero", "rom"], "rom-modes"),
    # more modes than the lattice has gave the full model, reported as "rom_modes": 500
    (["flutter", "--rom-modes", "500", "--aero", "rom"], "1 to 60 aerodynamic eigenmodes"),
    (["lco", "--airspeed", "5", "--duration", "0.01", "--set", "aero.rom_modes=500"], "1 to 60 aerodynamic eigenmodes"),
    (["flutter", "--rom-modes", "5"], "--aero rom"),  # the full lattice's analysis ignored it
    (["modes", "--set", "structure.modes=two"], "structure.modes"),
    (["modes", "--set", "panel.thickness_m=inf"], "panel.thickness_m: must be a finite number, got 'inf'"),
    # physical bounds: 1e300 m overflowed with a traceback, 1e-300 kg/m^3 printed NaN frequencies with status 0,
    # a divergence bound of 1e300 let a cubic panel swing to 179 L as an "LCO"
    (["modes", "--set", "panel.length_m=1e300"], "panel.length_m: must lie in [0.001, 10], got 1e+300"),
    (["modes", "--set", "material.density_kgpm3=1e-300"], "material.density_kgpm3: must lie in [1, 100000]"),
    (["modes", "--set", "panel.thickness_m=1e-300"], "panel.thickness_m: must lie in [1e-06, 0.1]"),
    (["lco", "--airspeed", "20", "--duration", "1", "--set", "sim.max_tip_w_over_L=1e300"],
     "sim.max_tip_w_over_L: must lie in (0, 2]"),
    (["modes", "--set", "panel.thickness_m=.nan"], "panel.thickness_m: must be finite, got nan"),  # YAML's NaN
    # a 1 ns step: `lco --duration 1` marched 1e9 steps (~17 min) without a word
    (["lco", "--airspeed", "11", "--duration", "1", "--set", "sim.dt_s=1e-9"], "sim.dt_s: must lie in [1e-06, 0.01]"),
    # the lattice is incompressible: no airspeed beyond Mach ~0.3 (a 200 m/s run gave a 781 Hz "LCO")
    (["lco", "--airspeed", "150"], "Mach 0.3"),
    (["lco-sweep", "--airspeeds", "90:110:10"], "Mach 0.3"),
    (["flutter", "--vg", "10:120:10"], "--vg STOP: airspeed must be in [0, 100] m/s"),  # it quoted 101, not 120
    (["flutter", "--vg", "5:150:1"], "got 150"),
    (["flutter", "--control", "--rate-hz", "0"], "--rate-hz"),  # was a ZeroDivisionError traceback
    (["flutter", "--control", "--plot", "/proc/no_such_dir/x.png"], "/proc/no_such_dir"),  # any OSError: one line
    # /proc itself is a directory that takes no file: its ENOENT read "No such file or directory"
    (["flutter", "--plot", "/proc/x.png"], "--plot: cannot write in the directory /proc: it takes no files"),
    (["flutter-test", "--domain-id", "300"], "--domain-id"),  # was an RTPS error on stdout
    (["flutter-test", "--in-process", "--domain-id", "5"], "not with --in-process"),  # was silently ignored
    # rcl's argument errors were tracebacks (from remove_ros_args or the node's creation)
    (["run", "--ros-args", "--params-file", "/no/such/file.yaml"], "Couldn't parse params file"),
    (["run", "--fast", "--ros-args", "-p", "publish_rate_hz"], "quote it"),
    # a value out of range: the node's logger and the command each printed it (the first with the name repeated)
    (["run", "--ros-args", "-p", "publish_rate_hz:=-5"], "invalid parameters: publish_rate_hz: Invalid parameter"),
    (["run", "--ros-args", "-r", "__ns:=/rig/"], "must not end with a '/'"),
    # the node's "[INFO] physics parameters given" line came before this error, as if the node were starting
    (["run", "--ros-args", "-p", "model.variant:=bogus"], "invalid node parameters: model.variant: must be one of"),
    # a recording that cannot be opened: the INFO line came first here too (it is said once the sinks are up)
    (["run", "--ros-args", "-p", "record:=true", "-p", "bag_dir:=/proc/no_such_dir"], "/proc/no_such_dir"),
    # the start-up warnings (a tip limit at the model's bound) came before it as well
    (["run", "--ros-args", "-p", "record:=true", "-p", "bag_dir:=/proc/no_such_dir",
      "-p", "safety.max_tip_w_over_L:=2.0"], "/proc/no_such_dir"),
    # a misspelt parameter ran the defaults behind a warning (the node) or without a word (the controller)
    (["run", "--ros-args", "-p", "model.variantt:=exact"], "'model.variantt' (did you mean 'model.variant'?)"),
    (["control", "--ros-args", "-p", "gian_nspm2:=1.0"], "'gian_nspm2' (did you mean 'gain_nspm2'?)"),
    # rclpy's exception class name led the line
    (["control", "--ros-args", "-p", "design_delay_ms:=abc"], "control: design_delay_ms: Trying to set parameter"),
    (["control", "--ros-args", "-p"], "bad --ros-args"),
    (["operate", "--profile", "config/staircase.yaml", "--namespace", "bad name"], "--namespace 'bad name'"),
    (["operate", "--profile", "config/staircase.yaml", "--timeout", "nan"], "--timeout"),  # never timed out
    (["operate", "--profile", "config/staircase.yaml", "--startup-timeout", "-1"], "--startup-timeout"),
    (["flutter-test", "--settle", "inf"], "--settle"),  # was refused by the node, the reason only in its log
    (["flutter-test", "--dwell", "1e9"], "--dwell"),
    # checked before the test runs: a plot that could not be written lost a whole test's results
    (["flutter-test", "--plot", "/proc/no_such_dir/vg.png"], "--plot"),
    # rerun replaces whatever the path names: a typo overwrote a profile YAML; a directory lost a whole analysis
    (["flutter-test", "--rerun", "config/staircase.yaml"], ".rrd file"),
    (["analyze", "bags/stiffness_staircase", "--rerun", "config/staircase.yaml"], ".rrd file"),
    (["analyze", "bags/stiffness_staircase", "--json", "--rerun", "config"], ".rrd file"),
    (["analyze", "bags/stiffness_staircase", "--plots", "README.md/sub"], "--plots"),  # after the whole analysis
    (["analyze", "bags/stiffness_staircase", "--rerun", "README.md/x.rrd"], "README.md is a file"),
    (["analyze", "bags/stiffness_staircase", "--rerun", "/proc/no_such_dir/x.rrd"], "--rerun: cannot create"),
    (["control-demo", "--out", "/proc/no_such_dir/demo"], "--out"),  # was a traceback after the design
    (["flutter", "--control", "--vg", "5:10:1"], "--vg"),  # options the analysis would silently ignore
    (["flutter", "--control", "--aero", "full"], "--aero full"),
    (["flutter", "--delay-ms", "5"], "--delay-ms applies only with --control"),
    # durations, dwells and ranges checked before the work (tracebacks, numpy messages or TiB allocations before)
    (["lco-sweep", "--airspeeds", "10:11:1", "--duration", "inf"], "--duration"),
    (["lco", "--airspeed", "11", "--duration", "1e-9"], "--duration"),
    (["forced", "--band", "23", "24", "--step", "1", "--dwell", "0.5"], "--dwell"),
    (["forced", "--band", "23", "24", "--step", "1", "--f0", "nan"], "--f0"),
    # zero gave all-zero amplitudes and a "peak" at the band's first frequency
    (["forced", "--band", "23", "24", "--step", "1", "--f0", "0"], "--f0 must be a finite force amplitude > 0 N/m"),
    (["lco", "--airspeed", "100.0001"], "got 100.0001"),  # it read "got 100"
    (["flutter", "--plot", "out/zz.png/"], "is a directory"),  # it wrote the file out/zz.png
    (["forced", "--band", "4", "4.4", "--step", "0.2", "--dwell", "30", "--f0", "2"], "lower --f0"),  # diverges
    (["lco-sweep", "--airspeeds", "0:100:1e-12"], "points"),
    (["flutter", "--vg", "0:100:1e-9"], "points"),
    (["lco", "--airspeed", "11", "--duration", "1", "--plot", "out/x"], ".png"),  # the JSON named a file not written
    (["paper", "--out", ""], "--out"),
    # an output that cannot be written is found before the run, not after it (an hour's lco lost its numbers)
    (["lco", "--airspeed", "10", "--duration", "1", "--plot", "/proc/x.png"], "--plot: cannot write in"),
    (["flutter", "--plot", "/proc/x.png"], "--plot: cannot write in"),
    (["lco-sweep", "--airspeeds", "10:11:1", "--duration", "1", "--plot", "README.md/x.png"], "is a file"),
    (["paper", "--out", "README.md"], "--out: README.md is a file, not a directory"),
    (["paper", "--out", "/proc/never_written", "--sweep-duration", "inf"], "--sweep-duration"),
])
def test_bad_input_exits_2_with_one_line(args, needle):
    out = run(*args)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], out.stderr
    assert "Traceback" not in out.stderr


def test_refused_command_leaves_no_plot_directory(tmp_path):
    """--plot's directory is checked before the run, but a command refused for another option made it and left it
    empty behind its error line; now it is made only when the figure is saved."""
    plot_dir = tmp_path / "new" / "dir"
    out = run("lco", "--airspeed", "150", "--plot", str(plot_dir / "x.png"))
    assert out.returncode == 2 and "Mach 0.3" in out.stderr
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("args", [["modes"], ["modes", "--json"]])
def test_closed_reader_ends_quietly_with_sigpipe_status(args):
    """`panel-rig modes | head -0`: stdout's reader is gone before the first write; the command ends with 141
    (128 + SIGPIPE, as a shell reports it) and nothing on stderr (it printed a BrokenPipeError traceback)."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # every write to write_end now fails with EPIPE, whatever the timing
    try:
        out = subprocess.run([*CLI, *args], stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert out.returncode == 141
    assert out.stderr == ""


def test_a_forced_dwell_too_short_to_settle_is_warned_of():
    """`forced --band 3.5 5 --dwell 1` put the first mode's peak at 4.4 Hz (it is at 4.17 Hz) without a word: the
    1 s dwell is a fraction of the mode's decay time 1/(zeta omega) = 7.6 s. A settled dwell gets no warning."""
    short = run("forced", "--band", "3.5", "5", "--step", "0.5", "--dwell", "1", "--variant", "linear", "--json")
    assert short.returncode == 0, short.stderr
    assert short.stderr.strip() == ("warning: --dwell 1 s is shorter than 3 decay times of the mode at 4.17 Hz "
                                    "(zeta 0.005: 22.9 s): the amplitudes hold its start-up transient"), short.stderr
    settled = run("forced", "--band", "23", "24", "--step", "1", "--dwell", "4", "--variant", "linear", "--json")
    assert settled.returncode == 0 and settled.stderr == "", settled.stderr


def test_a_reader_of_the_progress_lines_that_left_does_not_stop_the_work(tmp_path):
    """`panel-rig paper 2>&1 >/dev/null | head -1`: the reader of stderr left after the first progress line and the
    report died with status 141 after its first figure. The progress lines now go nowhere and the work ends."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # every write to stderr fails with EPIPE
    try:
        out = subprocess.run([*CLI, "flutter-test", "--in-process", "--dwell", "20", "--max-points", "2", "--bag-dir",
                              str(tmp_path), "--plot", str(tmp_path / "vg.png")], stdout=subprocess.PIPE,
                             stderr=write_end, text=True, timeout=300)
    finally:
        os.close(write_end)
    assert out.returncode == 0 and "stop: 2 test points done" in out.stdout, out.stdout
    assert (tmp_path / "vg.png").is_file()


@pytest.mark.parametrize("args", [("modes", "--params"), ("operate", "--profile"), ("study", "--spec")])
def test_malformed_yaml_is_one_line_with_its_place(tmp_path, args):
    """A parameters file, an operator profile and a study spec that YAML cannot parse: status 2 and one line
    naming the file, the line and the parser's complaint (the operator's was the parser's multi-line report)."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("panel_rig:\n  ros__parameters: [1, 2\n")
    out = run(*args, str(bad))
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert f"{bad}: malformed YAML (line 3; expected ',' or ']'" in out.stderr


@pytest.mark.parametrize("args", [("modes", "--params"), ("run", "--params"), ("operate", "--profile"),
                                  ("study", "--spec")])
def test_a_file_that_is_not_utf8_text_is_one_line_naming_it(tmp_path, args):
    """A binary file given as parameters, profile or spec: the node's start was a UnicodeDecodeError traceback,
    the others one line that did not name the file."""
    binary = tmp_path / "p.yaml"
    binary.write_bytes(b"\xff\xfe\x00panel_rig")
    out = run(*args, str(binary))
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert f"{binary}: not a UTF-8 text file (byte 0)" in lines[0], lines


@pytest.mark.parametrize("args", [("modes", "--params"), ("study", "--spec")])
def test_a_key_given_twice_is_an_error_not_the_last_one_wins(tmp_path, args):
    """YAML's safe loader keeps the last of two equal keys without a word: a spec varying panel.thickness_m twice
    ran only the second list, a parameters file setting a value twice used the second."""
    twice = tmp_path / "twice.yaml"
    twice.write_text("kind: flutter_map\nvary:\n  panel.thickness_m: [0.0003]\n  panel.thickness_m: [0.0004]\n"
                     if args[0] == "study" else
                     "panel_rig:\n  ros__parameters:\n    panel:\n      length_m: 0.27\n      length_m: 0.30\n")
    out = run(*args, str(twice))
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert f"{twice}: malformed YAML (line " in lines[0] and "given twice" in lines[0], lines


def test_config_validation_names_key(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("panel_rig:\n  ros__parameters:\n    air:\n      density_kgpm3: -1.0\n")
    with pytest.raises(ConfigError, match="air.density_kgpm3"):
        load_config(p)
    p.write_text("panel_rig:\n  ros__parameters:\n    aero:\n      wake_relaxation: 1.5\n")
    with pytest.raises(ConfigError, match="aero.wake_relaxation"):
        load_config(p)


def test_flutter_control_says_when_the_loop_is_unstable_at_low_speed():
    out = run("flutter", "--control", "--delay-ms", "20")
    assert out.returncode == 0, out.stderr
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("closed-loop flutter speed"))
    assert "unstable already at low speed" in line and "stable up to" not in line, line


def test_the_node_refuses_an_airspeed_limit_beyond_the_incompressible_lattice():
    from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
    from panel_rig.ros.params import check_node_params

    assert check_node_params({"safety.max_airspeed_mps": MAX_AIRSPEED_MPS}) == []
    pair = check_node_params({"control.fast_delay_s": 0.2, "control.timeout_s": 0.1})  # each valid alone
    assert len(pair) == 1 and pair[0].startswith("control.fast_delay_s") and "control.timeout_s" in pair[0], pair
    problems = check_node_params({"safety.max_airspeed_mps": 150.0})
    assert len(problems) == 1 and problems[0].startswith("safety.max_airspeed_mps"), problems


def test_the_node_and_the_cli_take_the_same_flutter_test_margins():
    """The node took flutter_test.margin 1.0 (a margin no prediction can meet), which flutter-test --margin refuses:
    both take (0, 1) now."""
    from panel_rig.ros.params import check_node_params

    assert check_node_params({"flutter_test.margin": 0.999}) == []
    for margin in (1.0, 0.0):
        problems = check_node_params({"flutter_test.margin": margin})
        assert len(problems) == 1 and "must lie in (0, 1)" in problems[0], problems
    assert run("flutter-test", "--in-process", "--margin", "1").returncode == 2


def test_the_node_and_the_cli_take_the_same_flutter_test_repeats():
    """flutter_test.repeats (the monitor's decision) takes what flutter-test --repeats takes: integers in [0, 12];
    the live test hands its own to the node, so the node's published advice is the client's."""
    from panel_rig.config import load_config
    from panel_rig.ros.flutter_live import node_parameters
    from panel_rig.ros.params import check_node_params

    assert check_node_params({"flutter_test.repeats": 0}) == [] == check_node_params({"flutter_test.repeats": 12})
    for bad in (-1, 13, 1.5, True):
        problems = check_node_params({"flutter_test.repeats": bad})
        assert len(problems) == 1 and problems[0].startswith("flutter_test.repeats"), (bad, problems)
    assert run("flutter-test", "--in-process", "--repeats", "13").returncode == 2
    prm = node_parameters(load_config(), "full", 0.1, 5.0, 200.0, 10.48, None, None, 0)
    assert prm["flutter_test.repeats"] == 0 and check_node_params(prm) == []


def test_the_node_s_physics_step_has_sim_dt_s_s_bounds():
    """physics_dt took 1e-9 s (any value in [0, 0.01]): 1e9 steps a simulated second."""
    from panel_rig.ros.params import check_node_params

    assert check_node_params({"physics_dt": 0.0}) == [] == check_node_params({"physics_dt": 1 / 4096})
    for bad in (1e-9, 0.02, "x"):
        (problem,) = check_node_params({"physics_dt": bad})
        assert "must be 0 (use sim.dt_s) or in [1e-06, 0.01] s" in problem, problem


def test_a_negative_number_in_exponent_form_is_a_value():
    """`static --tip-force -5e0` was "argument --tip-force: expected one argument": argparse took -5e0 for an
    option (its pattern knows -5 and -.5); -5 and --tip-force=-5e0 worked."""
    from panel_rig.cli import build_parser

    args = build_parser().parse_args(["static", "--tip-force", "-5e0"])
    assert args.tip_force == -5.0
    assert build_parser().parse_args(["static", "--tip-load-parameter", "-2.5E+1"]).tip_load_parameter == -25.0


def test_default_file_is_the_paper():
    c = load_config()
    assert (c.panel_length_m, c.panel_thickness_m, c.airfoil_length_m) == (0.27, 0.00036, 0.072)
    assert (c.n_elements, c.n_wake, c.wake_relaxation, c.rom_modes, c.n_modes) == (60, 60, 0.992, 12, 3)


def test_paper_yaml_equals_code_defaults():
    """config/tang_dowell_2002.yaml holds exactly PanelConfig's defaults (one home: the code)."""
    from panel_rig.config import SCHEMA, PanelConfig, default_params_path, read_params_file

    values = read_params_file(default_params_path())
    defaults = PanelConfig()
    assert set(values) == set(SCHEMA)
    for key, spec in SCHEMA.items():
        default = getattr(defaults, spec.field)
        assert values[key] == (default if isinstance(default, str) else pytest.approx(default, rel=1e-12)), key
        assert type(values[key]) is type(default), key


def test_rig_yaml_equals_node_defaults_and_names_nest():
    """config/rig.yaml holds exactly the node's defaults, and no parameter name is also a prefix of another
    (so `ros2 param dump` can nest them and `ros2 param load` takes them back)."""
    pytest.importorskip("rclpy")
    from panel_rig.config import SCHEMA, flatten
    from panel_rig.ros.params import NODE_PARAMS

    doc = yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "rig.yaml").read_text())
    values = flatten(doc["/**"]["ros__parameters"])
    assert values == {name: p.default for name, p in NODE_PARAMS.items()}
    assert all(type(values[n]) is type(p.default) for n, p in NODE_PARAMS.items())  # 500.0, not 500
    names = set(NODE_PARAMS) | set(SCHEMA)
    prefixes = {".".join(n.split(".")[:k]) for n in names for k in range(1, n.count(".") + 1)}
    assert not names & prefixes, names & prefixes


def test_physics_commands_work_without_the_recording_and_viz_extras():
    """`panel-rig modes` (and the parser) import neither mcap, rerun nor rclpy: blocked here, it still works."""
    code = ("import sys\n"
            "for name in ('mcap', 'mcap_ros2', 'rerun', 'rclpy'):\n"
            "    sys.modules[name] = None  # import of a blocked module raises ImportError\n"
            "from panel_rig.cli import main\n"
            "sys.exit(main(['modes', '--json']))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["natural_frequencies_hz"][0] > 0


def test_json_has_no_non_finite_numbers():
    """A diverged run has no RMS: null in the JSON (RFC 8259 has no NaN; strict parsers such as jq refused the
    bare NaN that was printed)."""
    out = run("lco", "--airspeed", "15", "--variant", "full", "--duration", "5", "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert d["diverged"] is True and d["rms_tip_w_over_L"] is None and d["dominant_frequency_hz"] is None


@pytest.mark.parametrize("program", ["operate", "run"])
def test_a_late_interrupt_of_a_handed_on_program_is_status_130(monkeypatch, capsys, program):
    """Ctrl-C that lands outside a program's own stop handling (the README test's SIGINT reached the operator just
    as it finished, after its signal handlers were restored): status 130 and one line, not death by SIGINT with a
    traceback."""
    from panel_rig import cli

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setitem(cli.PROGRAMS, program, (interrupted, *cli.PROGRAMS[program][1:]))
    assert cli.main([program, "--profile", "x.yaml"]) == cli.INTERRUPTED_STATUS == 130
    assert capsys.readouterr().err == "panel-rig: interrupted\n"


def test_child_programs_run_this_install_not_a_checkout_in_the_working_directory(tmp_path):
    """The demo, control demo and flutter test start the node as `python -m panel_rig...`; run from a directory
    holding another panel_rig/ (a second checkout), `-m` imported that one while the parent ran this install."""
    from panel_rig.processes import module_command

    (tmp_path / "panel_rig").mkdir()
    (tmp_path / "panel_rig" / "__init__.py").write_text("raise SystemExit('the working directory panel_rig ran')\n")
    out = subprocess.run([*module_command("panel_rig.jsonio")], cwd=tmp_path, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    naive = subprocess.run([sys.executable, "-m", "panel_rig.jsonio"], cwd=tmp_path, capture_output=True, text=True,
                           timeout=60)
    assert "the working directory panel_rig ran" in naive.stderr  # what -P prevents


def test_set_takes_numbers_yaml_1_1_leaves_as_text():
    """`--set sensor.tip_noise_m=5e-6` (the README's own spelling of the default) was refused: YAML 1.1 reads 5e-6
    as text. In a parameters file too, as rcl's parser (`--params-file`) reads it: a number; `1_0` or `nan` spelled
    as text are not."""
    out = run("modes", "--json", "--set", "sensor.tip_noise_m=5e-6", "--set", "air.density_kgpm3=1e0")
    assert out.returncode == 0, out.stderr
    assert load_config(None, ["sensor.tip_noise_m=5e-6"]).sensor_tip_noise_m == 5e-6
    assert config_from_flat({"panel.thickness_m": "3e-4"}).panel_thickness_m == 3e-4
    for text in ("1_0", "0x10", "3e-4 m"):
        with pytest.raises(ConfigError, match="expected a number"):
            config_from_flat({"air.density_kgpm3": text})
    with pytest.raises(ConfigError, match="must be a finite number, got 'nan'"):  # text, but no number we take
        config_from_flat({"air.density_kgpm3": "nan"})


def test_off_is_the_spectrum_off_however_it_is_given(tmp_path):
    """YAML 1.1 reads `off` as false: `--set tunnel.turbulence.spectrum=off`, `spectrum: off` in a parameters file or
    a study spec and the node's `-p tunnel.turbulence.spectrum:=off` were all "expected str, got False", though the
    README lists `off` as a value. A boolean for a choice without such a value still names the cause."""
    from rclpy.parameter import Parameter

    from panel_rig.ros.params import as_declared, parameter_table

    assert load_config(None, ["tunnel.turbulence.spectrum=off"]).turbulence_spectrum == "off"
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    tunnel:\n      turbulence:\n        spectrum: off\n")
    assert load_config(str(params), ()).turbulence_spectrum == "off"
    assert config_from_flat({"tunnel.turbulence.spectrum": False}).turbulence_spectrum == "off"
    with pytest.raises(ConfigError, match="got True .YAML reads no/off/false/yes/on/true as a boolean: quote"):
        config_from_flat({"tunnel.turbulence.spectrum": True})  # no "on" value
    with pytest.raises(ConfigError, match="aero.load_point: expected str, got False"):
        config_from_flat({"aero.load_point": False})
    prm = as_declared(parameter_table(), Parameter("tunnel.turbulence.spectrum", Parameter.Type.BOOL, False))
    assert (prm.type_, prm.value) == (Parameter.Type.STRING, "off")
    out = run("lco", "--airspeed", "8", "--duration", "1", "--set", "tunnel.turbulence.spectrum=off", "--json")
    assert out.returncode == 0, out.stderr


def test_set_with_an_empty_value_says_so():
    """`--set panel.length_m=` said "expected a number, got None" (YAML reads nothing as null)."""
    out = run("modes", "--set", "panel.length_m=")
    assert out.returncode == 2 and out.stderr.strip() == "panel-rig: error: --set panel.length_m= has no value (KEY=VALUE)"
    with pytest.raises(ConfigError, match="has no value"):
        load_config(None, ["panel.length_m=  "])


def test_a_tunnel_lco_reports_the_abort_time_not_the_chunk_end():
    out = run("lco", "--airspeed", "20", "--duration", "3", "--seed", "2", "--json")
    assert out.returncode == 0, out.stderr
    said = float(out.stderr.split("rig aborted at t = ")[1].split(" s")[0])
    res = json.loads(out.stdout)
    assert res["diverged_at_s"] == pytest.approx(said, abs=1e-3) and said < 1.0
    assert res["abort_reason"].startswith("tip |w/L| = ") and res["abort_reason"] in out.stderr  # which limit


def test_a_panel_that_does_not_move_has_no_frequency():
    """A quiet tunnel (no turbulence) leaves the panel at rest: the JSON said 0.0 Hz, a frequency nobody measured."""
    out = run("lco", "--airspeed", "11", "--duration", "2", "--turbulence-intensity", "0", "--seed", "1", "--json")
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["rms_tip_w_over_L"] == 0.0 and res["dominant_frequency_hz"] is None, res
    assert res["abort_reason"] is None and res["diverged"] is False


def test_static_says_when_the_modal_series_is_truncated():
    """A dead transverse tip load never turns the tip past pi/2; 3 modes did at P L^2/D = 50 without a word."""
    far = json.loads(run("static", "--tip-load-parameter", "50", "--variant", "exact", "--json").stdout)
    assert far["tip_angle_rad"] > np.pi / 2 and "structure.modes" in far["note"]
    resolved = json.loads(run("static", "--tip-load-parameter", "50", "--variant", "exact", "--json", "--set",
                              "structure.modes=6").stdout)
    assert resolved["tip_angle_rad"] < np.pi / 2 and resolved["note"] is None
    cubic = json.loads(run("static", "--tip-load-parameter", "40", "--variant", "full", "--json").stdout)
    assert cubic["tip_u_over_L"] > 1 and "--variant exact" in cubic["note"]  # u/L 3.42 went without a word
    assert cubic["note"].startswith("the full variant's cubic expansion does not hold")
    # the linear variant has no cubic expansion to blame; "1 modes do not resolve"
    linear = json.loads(run("static", "--tip-load-parameter", "5", "--variant", "linear", "--json").stdout)
    assert linear["note"].startswith("the linear variant's small-deflection theory does not hold"), linear["note"]
    one = json.loads(run("static", "--tip-load-parameter", "50", "--set", "structure.modes=1", "--json").stdout)
    assert "1 mode does not resolve this load" in one["note"], one["note"]


def test_a_range_s_points_are_the_decimals_typed() -> None:
    """`lco-sweep --airspeeds 10:27:0.85 --json` listed 12.549999999999999 and 26.999999999999993 (np.arange's sums)."""
    from panel_rig.cli import _range

    points = _range("10:27:0.85")
    assert points.size == 21 and points[3] == 12.55 and points[-1] == 27.0
    assert [float(u) for u in points] == [float(f"{10 + 0.85 * k:.2f}") for k in range(21)]
    assert list(_range("0:1:0.1")) == [round(0.1 * k, 1) for k in range(11)]


def test_the_lco_table_shows_a_missing_value_one_way() -> None:
    """`panel-rig lco` (the table) printed a missing frequency as "nan" and a missing time as "None"."""
    from panel_rig.cli import _key_value_table

    lines = _key_value_table({"dominant_frequency_hz": float("nan"), "steady_after_s": None, "rms": 0.0,
                              "diverged": False}).splitlines()
    assert [line.split()[-1] for line in lines] == ["-", "-", "0.0", "False"]


def test_a_range_that_starts_below_zero_gets_the_range_s_message(capsys):
    """`flutter --vg -5:20:1` said "argument --vg: expected one argument" (argparse took the range for an option);
    only `--vg=-5:20:1` reached the range's check."""
    from panel_rig.cli import main

    assert main(["flutter", "--vg", "-5:20:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--vg START: airspeed must be in [0, 100] m/s" in err, err
    assert "expected one argument" not in err


def test_lco_says_when_its_numbers_are_not_a_limit_cycle_s():
    """`lco --airspeed 10.84 --duration 30` (full variant) printed RMS 0.337 and a peak of 1.28 L as any result,
    while 0.1 % changes of the airspeed or the duration moved the RMS from 0.32 to 0.54: only steady_after_s null
    hinted at it. A settled cycle within the panel's length gets no warning; a diverged run has its own flag."""
    from panel_rig.cli import lco_warnings

    settled = {"peak_tip_w_over_L": 0.118, "steady_after_s": 10.0, "diverged": False}
    assert lco_warnings(settled) == []
    wild = lco_warnings({"peak_tip_w_over_L": 1.28, "rms_tip_w_over_L": 0.337, "steady_after_s": None,
                         "diverged": False})
    assert len(wild) == 2 and "|w/L| = 1.28, past the panel's own length" in wild[0]
    assert "no steady state" in wild[1] and "of a transient or an irregular response" in wild[1]
    # a diverged run has no metrics (null, "-"): it said nothing on stderr and exited 0 as a clean run did
    (gone,) = lco_warnings({"peak_tip_w_over_L": None, "steady_after_s": None, "diverged": True,
                            "diverged_at_s": 5.3662109375})
    assert gone.startswith("warning: the run diverged at t = 5.366 s") and "no LCO metrics" in gone, gone
    from panel_rig.config import SCHEMA  # the limit it names is a key `--set` takes (it named model.max_tip_w_over_L)

    named = gone.split("|w/L| over ", 1)[1].split(",", 1)[0]
    assert named in SCHEMA, named
    # the tunnel's rig stopped it: the rig's own log line says when and why
    assert lco_warnings({"diverged": True, "diverged_at_s": 9.78, "abort_reason": "tip |w/L| = 1.0024 exceeds"}) == []


def test_a_run_too_short_for_its_numbers_says_so():
    """`lco --duration 0.01` reported a dominant frequency of 106 Hz (no mode is near it; 10 ms is a quarter of a
    flutter period) and blamed the RMS of "the last 1 s windows" the run did not have. The frequency is now given
    only over signals.MIN_PERIODS periods, as analyze and the operator give it."""
    from panel_rig.cli import lco_warnings

    out = run("lco", "--airspeed", "10", "--duration", "0.01", "--json")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["dominant_frequency_hz"] is None
    assert "a run of 0.01 s is too short to show one: it takes 3 s" in out.stderr
    out = run("lco", "--airspeed", "10", "--duration", "1", "--json")  # 23 periods of the 23 Hz response
    assert json.loads(out.stdout)["dominant_frequency_hz"] == pytest.approx(23.0, abs=1.5)
    (line,) = lco_warnings({"rms_tip_w_over_L": 0.1, "steady_after_s": None, "diverged": False}, 30.0)
    assert "the RMS of the last 1 s windows still changes" in line


def test_forced_says_when_the_tip_passes_the_panel_s_length_and_where_it_diverged():
    """`forced` reported amplitudes of 1.15 L without a word (lco and lco-sweep warn), and a divergence "at t =
    20.96 s", a time counted over the whole sweep, without the frequency that diverged."""
    out = run("forced", "--band", "3.5", "4.5", "--step", "0.5", "--f0", "2.35", "--json")
    assert out.returncode == 0, out.stderr
    amps = json.loads(out.stdout)["amplitude_tip_w_over_L"]
    assert amps[0] < 1.0 < min(amps[1:])
    assert "warning: at 4, 4.5 Hz the tip passed |w/L| = 1 (up to 1.15), past the panel's own length" in out.stderr
    out = run("forced", "--band", "4", "4.5", "--step", "0.5", "--f0", "3")
    assert out.returncode == 2
    assert re.search(r", at 4.5 Hz, 0\.9[0-9]* s into its dwell: lower --f0", out.stderr), out.stderr


def test_a_diverged_lco_run_s_plot_holds_its_history_up_to_the_divergence(tmp_path):
    """The history of a diverged run ended at the last whole 1 s chunk (5.0 s), its "diverged" mark at 5.37 s: the
    steps of the chunk it diverged in were lost with the error. They are kept now."""
    from panel_rig.analysis.lco import run_lco
    from panel_rig.config import load_config

    cfg = load_config()
    res, tip, st = run_lco(cfg, 13.0, 10.0, keep=True)
    assert res.diverged and tip.size == st.steps == round(res.diverged_at_s / cfg.dt_s), (tip.size, st.steps)
    assert abs(tip[-1]) <= cfg.max_tip_w_over_L and abs(tip[-1]) > 0.9 * cfg.max_tip_w_over_L


def test_lco_in_the_tunnel_below_flutter_is_called_a_random_response_and_a_panel_at_rest_gets_no_warning():
    """An audit: `lco ... --turbulence-intensity 0` (RMS 0: the panel stays at rest) warned "no steady state ...
    not of a limit cycle", and every turbulent run below flutter got the transient's wording."""
    from panel_rig.cli import lco_warnings

    at_rest = {"peak_tip_w_over_L": 0.0, "rms_tip_w_over_L": 0.0, "steady_after_s": None, "diverged": False,
               "turbulence_intensity": 0.0}
    assert lco_warnings(at_rest) == []
    random = lco_warnings({**at_rest, "peak_tip_w_over_L": 2e-4, "rms_tip_w_over_L": 5e-5,
                           "turbulence_intensity": 0.001})
    assert len(random) == 1 and "a random response to the turbulence (below flutter)" in random[0]


def test_lco_sweep_warns_of_tips_past_the_panel_s_length_and_prints_no_nan():
    """`lco-sweep` gave RMS 0.69-0.80 for `full` points whose tips passed |w/L| = 1 without the warning a single
    `lco` gives, and its table printed nan for diverged runs."""
    from panel_rig.analysis.lco import LCOResult
    from panel_rig.cli import _lco_sweep_table, lco_sweep_warning

    nan = float("nan")
    res = [LCOResult(10.5, 0.1, 0.3, 22.5, 5.0, False), LCOResult(11.0, 0.48, 1.24, 17.5, None, False),
           LCOResult(11.85, 0.56, 1.32, 18.0, None, False), LCOResult(12.7, nan, nan, nan, None, True, 8.39)]
    line = lco_sweep_warning(res)
    assert line.startswith("warning: at 11, 11.85 m/s the tip passed |w/L| = 1 (up to 1.32)"), line
    assert lco_sweep_warning(res[:1] + res[3:]) is None
    table = _lco_sweep_table(res)
    assert "nan" not in table and table.splitlines()[-1].split() == ["12.70", "-", "-", "-", "at", "8.39", "s"]
    assert table.splitlines()[2].split() == ["11.00", "0.4800", "1.2400", "17.50", "False"]


def test_a_step_too_coarse_for_the_highest_mode_is_warned_of():
    """`--set sim.dt_s=0.01` (1.4 steps a period of the 73 Hz mode) moved the stiffness LCO from 23.15 to 20.43 Hz
    without a word; the default step (28 steps) and 1 ms (13.7) get no warning. The default step was never
    checked: a 5 cm panel (its 2134 Hz third mode in 1.0 step, the LCO's RMS off by 50 %) and 12 modes (1548 Hz, 1.3
    steps) ran without a word. Only a command that marches warns (`modes` has no step)."""
    from panel_rig.analysis.run_checks import coarse_step_warning

    cfg = load_config(None, ())
    assert coarse_step_warning(cfg) is None and coarse_step_warning(cfg.replace(dt_s=0.001)) is None
    assert coarse_step_warning(cfg.replace(dt_s=0.01)) == (
        "warning: sim.dt_s = 0.01 s resolves the highest mode (73.2 Hz) with 1.4 steps a period (fewer than 10): "
        "the results are not converged in the step")
    short = coarse_step_warning(load_config(None, ("panel.length_m=0.05",)))
    many = coarse_step_warning(load_config(None, ("structure.modes=12",)))
    assert short is not None and "(2133.6 Hz) with 1.0 steps" in short and many is not None and "with 1.3 steps" in many
    out = run("lco", "--airspeed", "5", "--duration", "0.01", "--set", "sim.dt_s=0.01")
    assert out.returncode == 0 and out.stderr.startswith("warning: sim.dt_s = 0.01 s"), out.stderr
    assert "warning" not in run("modes", "--set", "sim.dt_s=0.01").stderr


def test_a_refused_march_says_one_line_and_no_warning_before_it():
    """`lco --set sim.dt_s=0.005 --variant exact --scheme paper` printed the step's warning, then the error: two
    lines where the README promises one (and `forced ... --dwell 1` likewise with its dwell warning)."""
    out = run("lco", "--airspeed", "5", "--duration", "1", "--set", "sim.dt_s=0.005", "--variant", "exact",
              "--scheme", "paper")
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [
        "panel-rig: error: the exact structure runs the implicit (midpoint) scheme only"], out.stderr
    out = run("forced", "--band", "4", "4", "--variant", "exact", "--scheme", "paper", "--dwell", "1")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_the_run_checks_build_the_structure_once(monkeypatch):
    """A `forced` run with a step coarser than the default is checked twice (the step, the dwell); both read the
    natural frequencies of one cached structure (each built it before)."""
    import panel_rig.model.structure as structure
    from panel_rig.analysis import run_checks

    built = []
    real = structure.build_structure
    monkeypatch.setattr(structure, "build_structure", lambda cfg: built.append(cfg) or real(cfg))
    run_checks.natural_frequencies_hz.cache_clear()
    cfg = load_config(None, ()).replace(dt_s=0.01)
    assert run_checks.coarse_step_warning(cfg) is not None
    assert run_checks.forced_settling_warning(cfg, 3.5, 5.0, 1.0) is not None
    assert len(built) == 1


def test_static_text_has_no_nan_angle():
    """`static --variant full` at P L^2/D = 5 printed "tip angle, rad nan" (the JSON had null)."""
    out = run("static", "--tip-load-parameter", "5", "--variant", "full")
    assert out.returncode == 0 and "nan" not in out.stdout, out.stdout
    assert "tip angle, rad            -   (none: the cubic slope exceeds 1" in out.stdout


def test_every_option_of_every_subcommand_says_what_it_takes():
    """`panel-rig lco --help` listed `--plot FILE.png` and `lco-sweep` `--airspeeds START:STOP:STEP` with no word on
    what they do (or that STOP is included)."""
    import argparse

    from panel_rig.cli import build_parser

    def silent(parser: argparse.ArgumentParser, name: str) -> list[str]:
        out = []
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, p in action.choices.items():
                    out += silent(p, f"{name} {sub}")
            elif action.option_strings and not action.help:
                out.append(f"{name} {action.option_strings[0]}")
        return out

    assert silent(build_parser(), "panel-rig") == []
