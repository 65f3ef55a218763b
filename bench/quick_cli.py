"""The quick and quiet command line (issue 43, point 7), side by side in one run on the two tanks and on RO.

    .venv/bin/python bench/quick_cli.py [--repeats 3] [--numba] [--before DIR] [--models two_tank ro]

Each model is diagnosed on a scenario of a fault (two tanks: ``R12:abrupt:1.0@60``;
RO: ``R_pipe:incipient:0.5@165``) by ``bgc diagnose`` in a new process, as a user
types it; every row gives the command, the wall-clock seconds, the CPU seconds
of the process and its children (user + system: other processes on a busy
machine do not inflate them) and, for a repeated call, the diagnosis's own
seconds (``report.json``'s ``seconds``).

- **first call on a new model**: a model text no cache has seen (the model file
  with a comment of a fresh token, in a new folder) and a new, empty
  ``BGC_CACHE_DIR`` (no compiled model, no numba kernels), once with
  ``--backend numpy`` and once with ``--backend auto`` (another new text and
  cache), ``--first`` times each, the backends taking turns; the best and the
  median. Target: auto no slower than numpy (ratio auto / numpy <= 1).
- **repeated call**: ``bgc diagnose MODEL --scenario S`` (the default backend,
  auto) ``--repeats`` times once the cache holds the model; the best and the
  median of the wall-clock seconds, against the target 1.5 x the diagnosis's
  own seconds + 1 s (ratio <= 1 meets it).
- with ``--numba``, also the repeated call once ``--backend numba`` has
  compiled the model's kernels (auto then loads them, its work repaying it).
- with ``--before DIR`` (a checkout of an earlier commit, e.g. ``mkdir
  /tmp/65624eb && git archive 65624eb | tar -x -C /tmp/65624eb``), the same
  commands run by that checkout's bgc (``PYTHONPATH=DIR``) side by side.

The machine's load is printed before and after: on a shared 2-core machine
the wall-clock seconds of one run vary by a factor of two; the CPU seconds
much less.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import secrets
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = {"two_tank": "R12:abrupt:1.0@60", "ro": "R_pipe:incipient:0.5@165"}


def run(args: list[str], env: dict, cwd: Path) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds of the process and its children, stderr) of ``python -m bgc ARGS``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "bgc", *args], cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise SystemExit(f"bgc {' '.join(args)} failed:\n{out.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, out.stderr


def seconds_of(report: Path) -> float:
    """The diagnosis's own seconds in a report folder's report.json."""
    return float(json.loads((report / "report.json").read_text(encoding="utf-8"))["seconds"])


def environment(cache: Path, checkout: Path | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("BGC_BACKEND", "BGC_CACHE_DIR")}
    env["BGC_CACHE_DIR"] = str(cache)
    env["MPLBACKEND"] = "Agg"
    if checkout is not None:
        env["PYTHONPATH"] = str(checkout)
    return env


def fresh_model(work: Path, name: str) -> Path:
    """A copy of the shipped model whose text no cache has seen."""
    folder = work / f"new-{secrets.token_hex(4)}"
    folder.mkdir()
    path = folder / f"{name}.yaml"
    path.write_text((ROOT / "models" / f"{name}.yaml").read_text(encoding="utf-8") +
                    f"# {secrets.token_hex(8)}\n", encoding="utf-8")
    return path


def bench(name: str, checkout: Path | None, label: str, work: Path, repeats: int, numba: bool,
          first: int) -> list[dict]:
    scenario = SCENARIOS[name]
    rows = []
    firsts: dict[str, list[tuple[float, float, float]]] = {"numpy": [], "auto": []}
    for _ in range(first):  # the backends take turns: a busy spell of the machine falls on both
        for backend in ("numpy", "auto"):
            model = fresh_model(work, name)
            cache = work / f"cache-{secrets.token_hex(4)}"
            out = work / f"out-{secrets.token_hex(4)}"
            args = ["diagnose", str(model), "--scenario", scenario, "--backend", backend, "-o", str(out)]
            wall, cpu, _ = run(args, environment(cache, checkout), work)
            firsts[backend].append((wall, cpu, seconds_of(out)))
    for backend, samples in firsts.items():
        wall, cpu, d = min(samples)
        rows.append(dict(model=name, bgc=label, measure=f"first call, --backend {backend}",
                         command=f"bgc diagnose NEW_{name}.yaml --scenario {scenario} --backend {backend}",
                         wall=wall, cpu=cpu, d=d, median=statistics.median(w for w, _, _ in samples)))
    rows[-1]["ratio"] = rows[-1]["wall"] / rows[-2]["wall"]
    rows[-1]["target"] = f"auto <= numpy (medians: {rows[-1]['median'] / rows[-2]['median']:.2f})"
    cache = work / f"cache-{secrets.token_hex(4)}"
    model = ROOT / "models" / f"{name}.yaml"
    env = environment(cache, checkout)
    out = work / f"out-{secrets.token_hex(4)}"
    base = ["diagnose", str(model), "--scenario", scenario, "-o", str(out)]
    run(base, env, work)  # the first: compiles, fills the cache
    phases = [("repeated call (auto)", [])]
    if numba:
        phases.append(("repeated call, numba's kernels compiled before (auto)", ["--backend", "numba"]))
    for measure, prepare in phases:
        if prepare:
            run([*base, *prepare], env, work)
        walls, cpus, ds = [], [], []
        for _ in range(repeats):
            wall, cpu, _ = run(base, env, work)
            walls.append(wall)
            cpus.append(cpu)
            ds.append(seconds_of(out))
        best = min(range(repeats), key=lambda i: walls[i])
        target = 1.5 * ds[best] + 1.0
        rows.append(dict(model=name, bgc=label, measure=measure,
                         command=f"bgc diagnose models/{name}.yaml --scenario {scenario}",
                         wall=walls[best], cpu=cpus[best], d=ds[best], median=statistics.median(walls),
                         target=f"<= 1.5 x {ds[best]:.2f} + 1 = {target:.2f} s", ratio=walls[best] / target))
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| model | bgc | measure | command | wall s (best) | wall s (median) | CPU s | diagnosis s | target "
             "| ratio |", "|---|---|---|---|---:|---:|---:|---:|---|---:|"]
    for r in rows:
        median = f"{r['median']:.2f}" if "median" in r else ""
        ratio = f"{r['ratio']:.2f}" if "ratio" in r else ""
        lines.append(f"| {r['model']} | {r['bgc']} | {r['measure']} | `{r['command']}` | {r['wall']:.2f} | {median} "
                     f"| {r['cpu']:.2f} | {r['d']:.2f} | {r.get('target', '')} | {ratio} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeated calls timed (default 3)")
    parser.add_argument("--first", type=int, default=2,
                        help="first calls timed per backend, each on a new model text and cache (default 2)")
    parser.add_argument("--numba", action="store_true", help="also the repeated call with numba's kernels cached")
    parser.add_argument("--before", type=Path, default=None, metavar="DIR",
                        help="also run the commands with the bgc of this checkout (PYTHONPATH=DIR)")
    parser.add_argument("--models", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    args = parser.parse_args()
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    checkouts = [(None, f"this ({head})")]
    if args.before is not None:
        old = subprocess.run(["git", "-C", str(args.before), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True).stdout.strip() or args.before.name
        checkouts.insert(0, (args.before.resolve(), f"before ({old})"))
    print(f"load average before: {os.getloadavg()}", flush=True)
    rows = []
    work = Path(tempfile.mkdtemp(prefix="bgc-quick-cli-"))
    try:
        for name in args.models:
            for checkout, label in checkouts:
                rows += bench(name, checkout, label, work, args.repeats, args.numba and checkout is None, args.first)
                print(table(rows[-3 - (args.numba and checkout is None):]), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"load average after: {os.getloadavg()}")
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
