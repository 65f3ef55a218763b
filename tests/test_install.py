"""A non-editable install of bgc works on its own, away from the checkout.

The editable install that ``make test`` uses reads every file straight from
the checkout, so it cannot notice a file the package needs at run time (the
JSON Schema of model files, the code templates) that the wheel does not ship.
Here a wheel is built from the checkout and installed into a fresh virtual
environment that sees the test environment's dependencies but neither the
checkout nor the editable bgc; its ``bgc`` command then checks, compiles,
simulates and filters the circuit from a folder outside the checkout.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from bgc.compiler import validate

from conftest import MODELS, ROOT

PUBLISHED_SCHEMA = ROOT / "schemas" / "bondgraph.schema.json"
PACKAGED_SCHEMA = ROOT / "bgc" / "schema" / "bondgraph.schema.json"
#: What a fresh clone does not have: git's and build products, environments.
NOT_IN_A_CLONE = shutil.ignore_patterns(".git", ".venv", ".venvs", "build", "*.egg-info", "__pycache__", "*.pyc",
                                        ".pytest_cache", ".hypothesis", "out")


def test_published_schema_is_the_packaged_one():
    assert PUBLISHED_SCHEMA.read_bytes() == PACKAGED_SCHEMA.read_bytes(), (
        "schemas/bondgraph.schema.json (published) differs from bgc/schema/bondgraph.schema.json (the one bgc "
        "reads); after editing the packaged schema run: cp bgc/schema/bondgraph.schema.json schemas/")
    assert validate.schema() == json.loads(PACKAGED_SCHEMA.read_text(encoding="utf-8"))


def run(*command, cwd: Path) -> subprocess.CompletedProcess:
    """Run ``command`` without PYTHONPATH and with a display-free matplotlib; it must succeed."""
    env = {name: value for name, value in os.environ.items() if name != "PYTHONPATH"}
    env["MPLBACKEND"] = "Agg"
    r = subprocess.run([str(part) for part in command], cwd=cwd, env=env, capture_output=True, text=True)
    shown = " ".join(str(part) for part in command)
    assert r.returncode == 0, f"{shown} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr, f"{shown}\n{r.stderr}"
    return r


@pytest.mark.slow
@pytest.mark.install  # pip builds a wheel and installs it into a new environment: real processes
def test_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    # Build from a copy without build/: setuptools builds in the source tree and
    # reuses build/lib, so a file an earlier build left there would reach the
    # wheel even once package-data stops listing it (and two test runs at once
    # would share that folder).
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=NOT_IN_A_CLONE)
    dist = tmp_path / "dist"
    run(sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
        "-w", dist, source, cwd=tmp_path)
    (wheel,) = dist.glob("bgc-*.whl")

    fresh = tmp_path / "fresh"
    run(sys.executable, "-m", "venv", "--without-pip", fresh, cwd=tmp_path)
    python = fresh / "bin" / "python"
    run(sys.executable, "-m", "pip", "--python", python, "install", "--quiet", "--no-deps", "--no-index", wheel,
        cwd=tmp_path)
    site_packages = Path(run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))",
                             cwd=tmp_path).stdout.strip())
    # The dependencies come from the test environment's site-packages, listed as
    # a plain path: Python adds it to sys.path but does not run the .pth files
    # in it, so the editable bgc's finder stays off.
    dependencies = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib")}
    (site_packages / "test-environment.pth").write_text("".join(f"{path}\n" for path in sorted(dependencies)))

    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(MODELS / "circuit.yaml", work)
    imported = Path(run(python, "-c", "import bgc; print(bgc.__file__)", cwd=work).stdout.strip())
    assert imported.resolve().is_relative_to(site_packages.resolve()), imported

    bgc = fresh / "bin" / "bgc"
    check = run(bgc, "check", "circuit.yaml", cwd=work)
    assert check.stdout.startswith("circuit.yaml: ok: circuit"), check.stdout
    run(bgc, "compile", "circuit.yaml", "-o", "gen", "--no-pictures", cwd=work)
    assert (work / "gen" / "circuit" / "numpy_model" / "__init__.py").is_file()
    run(bgc, "simulate", "circuit.yaml", "--steps", "40", "--fault", "R2:abrupt:1.0@1", "-o", "run.csv", cwd=work)
    nominal = run(bgc, "filter", "circuit.yaml", "run.csv", "--generated", "gen", "--particles", "100",
                  "--filter", "gpf", cwd=work)
    assert "GPF on nominal" in nominal.stdout, nominal.stdout
    tracked = run(bgc, "filter", "circuit.yaml", "run.csv", "--fault", "R2:abrupt", "--start", "1.5",
                  "--generated", "gen", "--particles", "100", "--filter", "gpf", cwd=work)
    assert "estimate of R2" in tracked.stdout, tracked.stdout
