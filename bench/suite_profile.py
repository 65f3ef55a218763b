"""Where a whole test run's time goes: cProfile in every test process.

    .venv/bin/python bench/suite_profile.py run [PYTEST ARGUMENTS]
    .venv/bin/python bench/suite_profile.py show [COUNT]

``run`` runs make test's command (two xdist processes, a file to a
process; ``-m "not long"`` unless PYTEST ARGUMENTS are given: ``-m long``
profiles make long's tier) with this file loaded as a pytest plugin: each test process
profiles itself from its session's start to its end and writes
``out/suite-profile/<process>.prof``. The processes the tests start (a
command through a pipe, a worker pool, a Dask cluster) are not profiled.
cProfile slows the run about 1.3 times.

``show`` adds the processes' profiles and prints bgc's functions by
cumulative time (the COUNT first, 60 by default), then a few entry points
by name: what a reader compares with docs/results.md section 71.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "suite-profile"
#: The entry points docs/results.md section 71 tabulates, by the name cProfile gives them.
ENTRIES = (r"static_posterior\.py:\d+\(static_posteriors\)", r"hypothesis\.py:\d+\(step\)",
           r"diagnoser\.py:\d+\(step\)", r"session\.py:\d+\(calibrate\)", r"pipeline\.py:\d+\(compile_model\)",
           r"plots\.py:\d+\(diagnosis_figures\)", r"intermittent\.py:\d+\(revised\)", r"gc\.collect")

_profile = None


def pytest_sessionstart(session) -> None:
    """This process's profile starts (a pytest hook: the file loaded with ``-p suite_profile``)."""
    import cProfile

    global _profile
    if os.environ.get("BGC_SUITE_PROFILE"):
        _profile = cProfile.Profile()
        _profile.enable()


def pytest_sessionfinish(session, exitstatus) -> None:
    """This process's profile written, named by its xdist worker."""
    if _profile is not None:
        _profile.disable()
        folder = Path(os.environ["BGC_SUITE_PROFILE"])
        folder.mkdir(parents=True, exist_ok=True)
        _profile.dump_stats(str(folder / f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}.prof"))


def run(arguments: list[str]) -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    for old in OUT.glob("*.prof"):
        old.unlink()
    env = dict(os.environ, BGC_SUITE_PROFILE=str(OUT), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MPLBACKEND="Agg", PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT / "bench"),
                                                                          os.environ.get("PYTHONPATH")])))
    command = [sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadfile", "-q", "-p", "suite_profile",
               *(arguments or ["-m", "not long"])]
    print("$ BGC_SUITE_PROFILE=out/suite-profile " + " ".join(command[1:]), flush=True)
    return subprocess.run(command, cwd=ROOT, env=env).returncode


def show(count: int) -> int:
    import pstats
    import re

    files = sorted(OUT.glob("*.prof"))
    if not files:
        print(f"no profile in {OUT.relative_to(ROOT)}: run `bench/suite_profile.py run` first", file=sys.stderr)
        return 1
    stats = pstats.Stats(str(files[0]))
    for f in files[1:]:
        stats.add(str(f))
    rows = [(ct, nc, f"{Path(file).relative_to(ROOT) if file.startswith(str(ROOT)) else file}:{line}({name})")
            for (file, line, name), (_, nc, _, ct, _) in stats.stats.items()]
    print(f"{len(files)} processes ({', '.join(f.stem for f in files)}), {stats.total_tt:.0f} s profiled")
    print("\nthe entry points of docs/results.md section 71 (cumulative s, calls):")
    for entry in ENTRIES:
        for ct, nc, where in sorted((r for r in rows if re.search(entry, r[2])), reverse=True)[:1]:
            print(f"  {ct:8.1f} {nc:9d}  {where}")
    print(f"\nbgc's functions, the {count} of most cumulative time:")
    for ct, nc, where in sorted((r for r in rows if r[2].startswith("bgc/")), reverse=True)[:count]:
        print(f"  {ct:8.1f} {nc:9d}  {where}")
    return 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["run"]:
        return run(argv[1:])
    if argv[:1] == ["show"] and len(argv) <= 2:
        return show(int(argv[1]) if len(argv) == 2 else 60)
    print(__doc__.strip().split("\n\n")[1], file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
