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
