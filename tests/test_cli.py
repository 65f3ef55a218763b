"""The command line: summaries, exit codes, no tracebacks."""

import subprocess
import sys

from bgc.cli import main

from conftest import ROOT


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bgc", *args], cwd=ROOT, capture_output=True, text=True)


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
    undefined. bgc compile says so in one located line, without a traceback."""
    text = (ROOT / "tests" / "data" / "models" / "orifice_tanks.yaml").read_text()
    kink = tmp_path / "kink.yaml"
    kink.write_text(text.replace("C2: {kind: C, initial: 1.5}", "C2: {kind: C, initial: 1.2}"))
    r = run("compile", str(kink), "-o", str(tmp_path / "out"), "--no-pictures")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"{kink}: de2/dt has no finite derivative with respect to e2 at the initial state")
    assert "away from sqrt(abs(e)) at e = 0" in lines[0]
    # away from the kink the same plant compiles
    ok = run("compile", str(ROOT / "tests" / "data" / "models" / "orifice_tanks.yaml"), "-o", str(tmp_path / "ok"),
             "--no-pictures")
    assert ok.returncode == 0, ok.stderr
