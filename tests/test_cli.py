"""The command line: summaries, exit codes, no tracebacks."""

import subprocess
import sys

import pytest

from bgc.cli import main

from conftest import ROOT, bgc_cli as run


def test_check_circuit_reports_thesis_states(capsys):
    assert main(["check", "models/circuit.yaml"]) == 0
    out = capsys.readouterr().out
    assert "e4 (C1, integral)" in out and "e8 (C2, integral)" in out and "f10 (L, integral)" in out


def test_check_ro_reports_five_integral_states(capsys):
    assert main(["check", "models/ro.yaml"]) == 0
    out = capsys.readouterr().out
    for state, element in [("f3", "I_fp"), ("f22", "I_rp"), ("e6", "C_res"), ("e13", "C_memb"), ("e27", "C_k")]:
        assert f"{state} ({element}, integral)" in out


def test_missing_file_is_one_line_exit_1():
    r = run("check", "models/nope.yaml")
    assert r.returncode == 1
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr


def test_usage_error_exit_2():
    assert run().returncode == 2
    assert run("check").returncode == 2


def test_version():
    r = run("--version")
    assert r.returncode == 0 and r.stdout.startswith("bgc ")


def test_nonlinear_law_at_its_kink_is_one_line_exit_1(tmp_path):
    """sqrt(abs(e)) has no finite derivative at e = 0: starting both tanks at the
    same pressure leaves the linearisation (integration step, noise levels)
    undefined. bgc compile says so in one line located at the law with the
    kink (line 22, column 25 of the test plant: the valve's law), without a
    traceback; bgc check says the same (it runs every stage)."""
    text = (ROOT / "tests" / "data" / "models" / "orifice_tanks.yaml").read_text()
    kink = tmp_path / "kink.yaml"
    kink.write_text(text.replace("C2: {kind: C, initial: 1.5}", "C2: {kind: C, initial: 1.2}"))
    r = run("compile", str(kink), "-o", str(tmp_path / "out"), "--no-pictures")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"{kink}:22:25: de2/dt has no finite derivative with respect to e2 at the initial "
                               "state")
    check = run("check", str(kink))
    assert check.returncode == 1 and check.stderr == r.stderr and check.stdout == ""
    assert "away from sqrt(abs(e)) at e = 0" in lines[0]
    # away from the kink the same plant compiles
    ok = run("compile", str(ROOT / "tests" / "data" / "models" / "orifice_tanks.yaml"), "-o", str(tmp_path / "ok"),
             "--no-pictures")
    assert ok.returncode == 0, ok.stderr


RC = """name: rc1
description: single-state RC (test model)
parameters: {R: %s, C: %s}
inputs: {V: 1.0}
elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, C: {kind: C}}
bonds: {1: [V, j], 2: [j, R], 3: [j, C]}
%s
faults: {R: [abrupt, incipient]}
"""


def one_line_error(r):
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_stiff_plant_for_its_sample_period_is_refused_not_run_for_hours(tmp_path):
    """tau = R C = 1e-6 with dt = 1 would take 666 667 RK4 substeps per sample."""
    model = tmp_path / "stiff.yaml"
    model.write_text(RC % ("1.0e-3", "1.0e-3", "measurements: {e3: {}}"))
    line = one_line_error(run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures"))
    assert line.startswith(f"{model}:1:1: model 'rc1' is stiff for its sample period")  # no simulation section: at the name
    assert "666667 substeps" in line and "set simulation.dt to at most 0.0003" in line
    assert one_line_error(run("simulate", str(model), "--steps", "3", "-o", str(tmp_path / "r.csv"))) == line


def test_run_time_options_out_of_range_are_one_line_errors(tmp_path):
    model = tmp_path / "rc.yaml"
    model.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}"))
    csv = tmp_path / "run.csv"
    assert run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures").returncode == 0
    assert run("simulate", str(model), "--steps", "20", "-o", str(csv)).returncode == 0
    r = run("simulate", str(model), "--steps", "5", "--seed", "-1", "-o", str(csv))
    assert r.returncode == 2 and "--seed: -1 is negative" in r.stderr and "Traceback" not in r.stderr
    line = one_line_error(run("simulate", str(model), "--steps", "5", "--fault", "R:abrupt:1e400@2", "-o", str(csv)))
    assert "must be finite numbers" in line
    line = one_line_error(run("simulate", str(model), "--steps", "5", "-o", str(tmp_path)))
    assert line == f"{tmp_path} is a folder (give a file path for the output)"
    line = one_line_error(run("filter", str(model), str(csv), "--generated", str(tmp_path / "g"),
                              "--fault", "R:abrupt", "--start", "60"))
    assert line.startswith("--start 60 is outside the run (1 to 20)")  # samples at t = 1..20 (dt = 1)


def test_workers_out_of_range_are_one_line_errors(tmp_path):
    """``--workers`` and the environment's ``BGC_WORKERS`` that sets its
    default: a count of processes >= 1, else a one-line error naming it."""
    for value in ("0", "two", "-1"):
        r = run("diagnose", "models/circuit.yaml", "--scenario", "none", "--steps", "5", "-o", str(tmp_path / "d"),
                env={"BGC_WORKERS": value})
        assert r.returncode == 1 and not (tmp_path / "d").exists(), r.stderr
        assert one_line_error(r).startswith(f"BGC_WORKERS={value!r} in the environment: not a number of processes")
    r = run("monitor", "models/circuit.yaml", "--data", "-", "--workers", "0", "-o", str(tmp_path / "m"))
    assert r.returncode == 2 and "--workers: 0: give an integer >= 1" in r.stderr and "Traceback" not in r.stderr


def test_workers_come_from_the_flag_then_the_environment_then_the_default(monkeypatch):
    """``--workers`` first, else ``BGC_WORKERS``, else DiagnosisOptions' 2;
    a bad environment value is not read when the flag is given."""
    import argparse

    from bgc.cli.common import workers

    monkeypatch.delenv("BGC_WORKERS", raising=False)
    assert workers(argparse.Namespace(workers=None)) == 2
    monkeypatch.setenv("BGC_WORKERS", "3")
    assert workers(argparse.Namespace(workers=None)) == 3
    assert workers(argparse.Namespace(workers=1)) == 1
    monkeypatch.setenv("BGC_WORKERS", "none")
    assert workers(argparse.Namespace(workers=2)) == 2


def test_the_apis_default_count_of_processes_is_the_environments_when_the_work_starts(monkeypatch):
    """``DiagnosisOptions()`` leaves ``workers`` None: the environment's
    ``BGC_WORKERS`` read when a map of jobs starts, else 2; a bad value is a
    one-line ArgumentValueError naming it there (not when options are made)."""
    import os

    from bgc.diagnosis.options import DiagnosisOptions, processes
    from bgc.diagnosis.parallel import parallel_map
    from bgc.errors import ArgumentValueError

    assert DiagnosisOptions().workers is None and processes(3) == 3
    monkeypatch.delenv("BGC_WORKERS", raising=False)
    assert processes(None) == 2
    monkeypatch.setenv("BGC_WORKERS", "1")
    assert processes(None) == 1
    assert len(set(parallel_map(lambda _: os.getpid(), [0, 1], None))) == 1  # one process: a lambda need not pickle
    monkeypatch.setenv("BGC_WORKERS", "0")
    DiagnosisOptions()  # made without reading it
    with pytest.raises(ArgumentValueError, match="BGC_WORKERS='0' in the environment: not a number of processes"):
        parallel_map(abs, [1, 2], None)


def test_filter_on_a_plant_without_sensors_says_there_is_nothing_to_filter(tmp_path):
    model = tmp_path / "blind.yaml"
    model.write_text(RC % ("1.0", "2.0", ""))
    csv = tmp_path / "run.csv"
    assert run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures").returncode == 0
    assert run("simulate", str(model), "--steps", "5", "-o", str(csv)).returncode == 0
    line = one_line_error(run("filter", str(model), str(csv), "--generated", str(tmp_path / "g")))
    assert "has no measurements, so there is nothing to filter" in line


def test_compile_reports_a_bad_model_and_goes_on_with_the_others(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(RC % ("one", "2.0", "measurements: {e3: {}}"))
    good = tmp_path / "rc.yaml"
    good.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}"))
    r = run("compile", str(bad), str(good), "-o", str(tmp_path / "g"), "--no-pictures")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[0].startswith(f"{bad}:3:17: parameters.R must be a number")
    assert (tmp_path / "g" / "rc1" / "numpy_model" / "__init__.py").exists()   # the good one was compiled


def test_filter_refuses_a_run_of_another_model(tmp_path):
    csv = tmp_path / "circuit.csv"
    assert run("simulate", "models/circuit.yaml", "--steps", "3", "-o", str(csv)).returncode == 0
    line = one_line_error(run("filter", "models/ro.yaml", str(csv)))
    assert line.startswith(f"{csv} is a run of model 'circuit', not of 'ro'")


def test_show_causality_works_where_a_later_stage_fails(tmp_path):
    """Derivative causality stops the equations, but bgc show causality still
    shows the causal strokes: it is how a user finds out why."""
    model = tmp_path / "deriv.yaml"
    model.write_text("""name: deriv
description: a C on a 0-junction whose effort the source fixes (test model)
parameters: {R: 1.0, C: 2.0}
inputs: {V: 1.0}
elements: {V: {kind: Se}, n: {kind: "0"}, R: {kind: R}, C: {kind: C}}
bonds: {1: [V, n], 2: [n, R], 3: [n, C]}
measurements: {f3: {}}
""")
    r = run("show", "causality", str(model))
    assert r.returncode == 0, r.stderr
    assert "C (C, bond 3): derivative" in r.stdout
    assert one_line_error(run("show", "equations", str(model))).endswith(
        "(merge it with the storage element that fixes it, or add a resistor in between)")


# ------------------------------------------------ pipes, limits, data from outside
@pytest.mark.process
@pytest.mark.parametrize("reader", ["true", "head -1"])
def test_a_closed_pipe_ends_quietly_with_status_0(reader):
    """``bgc show equations models/two_tank.yaml | true`` (the reader never
    reads) or ``| head -1`` (it stops early), and the RO's TCG as JSON (a
    longer output): no message, status 0, as other CLIs do. A real process:
    the pipe must be a real one, closed by its reader, and the interpreter's
    last flush must raise nothing."""
    r = subprocess.run(["bash", "-c", f"set -o pipefail; {sys.executable} -m bgc show equations models/two_tank.yaml"
                                      f" | {reader} > /dev/null"], cwd=ROOT, capture_output=True, text=True)
    assert (r.returncode, r.stderr) == (0, "")
    big = subprocess.run(["bash", "-c", f"set -o pipefail; {sys.executable} -m bgc show tcg models/ro.yaml"
                                        f" --format json | {reader} > /dev/null"], cwd=ROOT, capture_output=True,
                         text=True)
    assert (big.returncode, big.stderr) == (0, "")


def test_check_says_one_loop_is_one_loop():
    """The test plant's one loop, by hand: the source fixes bond 1 and the
    capacitor bond 7; every variable of bonds 2 to 6 (R1, the j1-j0 bond, R2,
    the j0-j2 bond, R3) depends on the others; SCAP chose R1's and R2's forms."""
    r = run("check", "tests/data/models/resistor_loop.yaml")
    assert r.returncode == 0, r.stderr
    loops = [line for line in r.stdout.splitlines() if line.startswith("  algebraic loops:")]
    assert loops == ["  algebraic loops: 1: through e2, f2, e3, f3, e4, f4, e5, f5, e6, f6, closed by R1 and R2"]


def test_check_prints_model_text_escaped_on_its_own_lines(tmp_path):
    """A description with a newline and an ANSI escape cannot forge a line of
    bgc's output or colour the terminal."""
    model = tmp_path / "rc.yaml"
    model.write_text((RC % ("1.0", "2.0", "measurements: {e3: {}}")).replace(
        "description: single-state RC (test model)", 'description: "x\\nrc.yaml: ok: forged\\e[31m"'))
    r = run("check", str(model))
    assert r.returncode == 0, r.stderr
    first = r.stdout.splitlines()[0]
    assert first == f"{model}: ok: rc1 (x\\nrc.yaml: ok: forged\\x1b[31m)"
    assert "\x1b" not in r.stdout and not any(line.startswith("rc.yaml") for line in r.stdout.splitlines())


def test_requests_beyond_the_limits_are_refused_before_any_work(tmp_path):
    """A billion simulated steps or ten billion particles: one located line at
    once, not an hour of work or a memory error."""
    model = tmp_path / "rc.yaml"
    model.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}"))
    csv = tmp_path / "run.csv"
    assert run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures").returncode == 0
    line = one_line_error(run("simulate", str(model), "--steps", "1000000000", "-o", str(csv)))
    assert line.startswith("--steps: 1000000000 steps is more than bgc simulates in one run (at most 10000000")
    assert not csv.exists()
    assert run("simulate", str(model), "--steps", "20", "-o", str(csv)).returncode == 0
    line = one_line_error(run("filter", str(model), str(csv), "--generated", str(tmp_path / "g"),
                              "--particles", "10000000000"))
    assert line.startswith("--particles 10000000000 would take about") and "use at most" in line


@pytest.mark.parametrize("content, message", [
    (b"time,y:e3\n1.0,2.0\n2.0,\xff\n", "{csv}:3: not UTF-8 text (byte 22 is 0xff)"),  # 10 + 8 + 4 bytes before
    (b"time,y:e3\n1.0," + b"9" * 50_000_000 + b"\n", "{csv}:2: line is 50000004 characters long"),
    (b"time,y:e3\n", "{csv}: the run has no data rows, only column names"),
    (b"time,y:other\n1.0,2.0\n", "{csv}: the run has no column y:e3"),
])
def test_filter_on_a_broken_run_file_is_one_located_line(tmp_path, content, message):
    model = tmp_path / "rc.yaml"
    model.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}"))
    assert run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures").returncode == 0
    csv = tmp_path / "run.csv"
    csv.write_bytes(content)
    line = one_line_error(run("filter", str(model), str(csv), "--generated", str(tmp_path / "g")))
    assert line.startswith(message.format(csv=csv)), line


def test_filter_on_a_run_of_one_sample_works(tmp_path):
    model = tmp_path / "rc.yaml"
    model.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}\nsimulation: {time_unit: ms}"))
    csv = tmp_path / "run.csv"
    assert run("compile", str(model), "-o", str(tmp_path / "g"), "--no-pictures").returncode == 0
    assert run("simulate", str(model), "--steps", "1", "-o", str(csv)).returncode == 0
    r = run("filter", str(model), str(csv), "--generated", str(tmp_path / "g"), "--filter", "gpf")
    assert r.returncode == 0 and "GPF on nominal, N = 200: 1 steps" in r.stdout, r.stderr
    r = run("filter", str(model), str(csv), "--generated", str(tmp_path / "g"), "--filter", "gpf",
            "--fault", "R:incipient", "--start", "1")
    assert r.returncode == 0 and "estimate of slope of R (per ms)" in r.stdout, r.stdout + r.stderr  # the model's time unit


def test_filter_without_the_compiled_package_names_generated(tmp_path):
    """After bgc compile -o DIR the package is in DIR: the hint says --generated."""
    model = tmp_path / "rc.yaml"
    model.write_text(RC % ("1.0", "2.0", "measurements: {e3: {}}"))
    csv = tmp_path / "run.csv"
    assert run("simulate", str(model), "--steps", "5", "-o", str(csv)).returncode == 0
    line = one_line_error(run("filter", str(model), str(csv), "--generated", str(tmp_path / "nowhere")))
    assert "point --generated at the folder bgc compile -o wrote" in line


@pytest.mark.slow
@pytest.mark.long
def test_a_successful_run_is_quiet_on_stderr_and_says_what_it_chose_with_v(tmp_path, capsys):
    """stderr holds errors and warnings only: a diagnosis that succeeds
    writes nothing there; with -v (after the command or before it) it says
    where the model came from and the backend it runs on, and why. (-v
    before the command is checked on a fault-free scenario: what it changes
    is the parsing, and a fault-free diagnosis skips the hypotheses' work.)"""
    base = ["diagnose", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@1.5", "--particles", "100", "--steps", "60"]
    assert main([*base, "-o", str(tmp_path / "a")]) == 0
    assert capsys.readouterr().err == ""
    assert main([*base, "-v", "-o", str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err and all(line.startswith("bgc: ") for line in err), err
    assert any(line.startswith("bgc: model circuit: ") for line in err), err
    assert sum(line.startswith("bgc: backend numpy (") for line in err) == 1, err
    assert main(["-v", *base[:3], "none", *base[4:], "-o", str(tmp_path / "c")]) == 0
    assert any(line.startswith("bgc: backend numpy (") for line in capsys.readouterr().err.splitlines())
    for command in (["simulate", "models/circuit.yaml", "--steps", "20", "-o", str(tmp_path / "r.csv")],
                    ["filter", "models/circuit.yaml", str(tmp_path / "r.csv"), "--particles", "50"],
                    ["cache"]):
        assert main(command) == 0, command
        assert capsys.readouterr().err == "", command


def test_cache_clear_and_list_work_on_an_empty_or_missing_cache_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("BGC_CACHE_DIR", str(tmp_path / "nothing-yet"))
    assert main(["cache"]) == 0
    assert "(empty)" in capsys.readouterr().out
    assert main(["cache", "clear"]) == 0
    assert "removed from" in capsys.readouterr().out
    assert not (tmp_path / "nothing-yet").exists()
    r = run("cache", "empty")
    assert r.returncode == 2 and "invalid choice" in r.stderr
