"""Batch diagnosis no slower than before: the regression corpus diagnosed by
this checkout's code and by the code of commit 5cca73a (before the online
diagnoser), side by side in one run (issue 27's target).

    .venv/bin/python bench/batch_speed.py [--base /tmp/base] [--repeat 1] [--cases SUBSTR]

The cases: tests/regression/cases.json (the run files
tests/regression/runs/*.csv, the models, the options and noise levels of each
case), diagnosed as tests/test_regression.py does,
``bgc.api.diagnose(model, data=run, options=..., process_noise=...,
measurement_noise=...)``. The old code has no ``horizon`` option: its detector
spent the false-alarm rate over the file's length, so the new code is given
``horizon = rows * dt``, which reproduces the old thresholds (the test's
``options_for``); the old code gets the same options without it. Both sides
read the same model and run files (this checkout's).

Each side is a worker process of the venv's Python (``sys.executable``), the
old one with ``PYTHONPATH=<base>`` (a git worktree of 5cca73a; made with
``git worktree add --detach <base> 5cca73a`` when missing), the new one with
``PYTHONPATH=<this checkout>``; each first diagnoses one case of every plant
untimed (imports, compilation), then takes cases one at a time. The driver
alternates the order per case and repeat (before then after, then after then
before) so that drift of the machine's load falls on both sides alike. A
diagnosis is timed in its worker around the call: wall-clock seconds and the
worker's CPU seconds (user + system, with the children it has reaped: the
hypothesis processes of a ``workers = 2`` case when they have ended). With
``--repeat K``, a case's time is the median of its K.

Prints seconds before and after per plant and in all, and the ratio after /
before; then every case, with whether both sides gave the same verdict and
candidates (tests/test_regression.py checks every number to 1e-9). On a
shared machine the wall-clock times are noisy (other processes take turns on
the cores): the CPU columns are the steadier measure, the alternation the
fairer one; run it with ``--repeat 3`` before trusting a few per cent.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "regression" / "cases.json"
BASE_COMMIT = "5cca73a"


# -- the worker: one side's code, a case per line of stdin, a result per line of stdout ---------------------

def worker(code: str) -> None:
    """Diagnose the cases sent on stdin with the bgc of ``code`` (on
    PYTHONPATH); print a JSON line per case."""
    import dataclasses

    import bgc
    from bgc import api
    from bgc.diagnosis.options import DiagnosisOptions

    where = Path(bgc.__file__).resolve().parent
    if where != Path(code).resolve() / "bgc":
        raise SystemExit(f"worker: bgc is imported from {where}, not from {code}")
    has_horizon = "horizon" in {f.name for f in dataclasses.fields(DiagnosisOptions)}
    print(json.dumps({"bgc": str(where), "horizon": has_horizon}), flush=True)
    for line in sys.stdin:
        c = json.loads(line)
        o = c["options"]
        fields = dict(method=o["method"], particles=o["particles"], seed=o["seed"], workers=o["workers"],
                      identify=o["identify"], switch=o["switch"], rank=o["rank"], refine=o["refine"])
        if has_horizon:
            fields["horizon"] = c["horizon"]
        sim = c["simulation"]
        t0, c0 = time.perf_counter(), os.times()
        d = api.diagnose(c["model"], data=c["run"], options=DiagnosisOptions(**fields),
                         process_noise=sim["process_noise"], measurement_noise=sim["measurement_noise"]).diagnosis
        seconds, c1 = time.perf_counter() - t0, os.times()
        cpu = sum(c1[:4]) - sum(c0[:4])  # user, system, children's user, children's system
        print(json.dumps({"seconds": seconds, "cpu": cpu, "verdict": d.verdict, "candidates": list(d.candidates),
                          "method": d.options.method}), flush=True)


# -- the driver ---------------------------------------------------------------------------------------------

class Side:
    """A worker process running the bgc of ``code``."""

    def __init__(self, name: str, code: Path):
        self.name, self.code = name, code
        env = {**os.environ, "PYTHONPATH": str(code), "MPLBACKEND": "Agg"}
        self.process = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", str(code)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        self.hello = self._read()

    def _read(self) -> dict:
        line = self.process.stdout.readline()
        if not line:
            raise SystemExit(f"the {self.name} worker ({self.code}) ended (exit {self.process.wait()}); "
                             "its error is above")
        return json.loads(line)

    def diagnose(self, case: dict) -> dict:
        self.process.stdin.write(json.dumps(case) + "\n")
        self.process.stdin.flush()
        return self._read()

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def git(path: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(path), *args], capture_output=True, text=True).stdout.strip()


def version(path: Path) -> str:
    head = git(path, "rev-parse", "--short", "HEAD")
    if not head:
        return "not a git checkout"
    return head + (" with edits in bgc/" if git(path, "status", "--porcelain", "--", "bgc") else "")


def ensure_base(base: Path) -> None:
    if not base.exists():
        print(f"# {base} missing: git worktree add --detach {base} {BASE_COMMIT}", file=sys.stderr)
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base), BASE_COMMIT], check=True)
    head = git(base, "rev-parse", "HEAD")
    if not head.startswith(BASE_COMMIT) or git(base, "status", "--porcelain", "--", "bgc"):
        print(f"warning: {base} is at {head or '?'} (or its bgc/ is edited), not at {BASE_COMMIT}", file=sys.stderr)


def prepared(case: dict) -> dict:
    """What a worker needs of a case: absolute paths, and the horizon (rows x dt, as
    tests/test_regression.py's ``options_for``) for the new code."""
    sys.path.insert(0, str(ROOT))
    from bgc.data import runs

    run = ROOT / case["run"]
    t = runs.read_run(run).time
    return {"name": case["name"], "model": str(ROOT / case["model"]), "run": str(run),
            "options": case["options"], "simulation": case["simulation"],
            "horizon": len(t) * float(t[1] - t[0])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", metavar="CODE", help=argparse.SUPPRESS)
    ap.add_argument("--base", type=Path, default=Path("/tmp/base"),
                    help=f"a checkout of {BASE_COMMIT} (default /tmp/base; made when missing)")
    ap.add_argument("--repeat", type=int, default=1, help="diagnoses of each case per side (default 1)")
    ap.add_argument("--cases", default="", metavar="SUBSTR", help="only the cases whose name holds SUBSTR")
    args = ap.parse_args()
    if args.worker:
        worker(args.worker)
        return
    print("$ .venv/bin/python bench/batch_speed.py " + " ".join(sys.argv[1:]))
    ensure_base(args.base)
    cases = [prepared(c) for c in json.loads(CORPUS.read_text(encoding="utf-8"))["cases"] if args.cases in c["name"]]
    if not cases:
        raise SystemExit(f"no case of {CORPUS.relative_to(ROOT)} has {args.cases!r} in its name")
    sides = {"before": Side("before", args.base.resolve()), "after": Side("after", ROOT)}
    for name, side in sides.items():
        print(f"# {name}: bgc from {side.hello['bgc']} ({version(side.code)}; "
              f"horizon option: {'yes, rows x dt' if side.hello['horizon'] else 'no'})")
    print(f"# {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the start; "
          f"{len(cases)} cases x {args.repeat} per side\n")
    try:
        first = {}
        for c in cases:  # one case of every plant, untimed: imports, compilation
            first.setdefault(c["model"], c)
        for c in first.values():
            for side in sides.values():
                side.diagnose(c)
        began = time.perf_counter()
        results: dict[str, dict[str, list[dict]]] = {c["name"]: {"before": [], "after": []} for c in cases}
        for r in range(args.repeat):
            for i, c in enumerate(cases):
                order = ("before", "after") if (i + r) % 2 == 0 else ("after", "before")
                for name in order:
                    results[c["name"]][name].append(sides[name].diagnose(c))
                got = results[c["name"]]
                print(f"# {c['name']}: before {got['before'][-1]['seconds']:.2f} s, "
                      f"after {got['after'][-1]['seconds']:.2f} s", file=sys.stderr, flush=True)
    finally:
        for side in sides.values():
            side.close()

    def median(c: dict, side: str, key: str) -> float:
        return statistics.median(x[key] for x in results[c["name"]][side])

    def same(c: dict) -> bool:
        b, a = results[c["name"]]["before"][0], results[c["name"]]["after"][0]
        return (b["verdict"], b["candidates"], b["method"]) == (a["verdict"], a["candidates"], a["method"])

    plants: dict[str, list[dict]] = {}
    for c in cases:
        plants.setdefault(Path(c["model"]).stem, []).append(c)
    print(f"Regression corpus ({CORPUS.relative_to(ROOT)}), batch diagnosis, before = {BASE_COMMIT}, "
          f"after = this checkout; {time.perf_counter() - began:.0f} s of timed runs\n")
    print("| plant | cases | before s | after s | after / before | before CPU s | after CPU s | after / before (CPU) "
          "| same verdict and candidates |")
    print("|---|---|---|---|---|---|---|---|---|")

    def row(label: str, group: list[dict]) -> None:
        b = sum(median(c, "before", "seconds") for c in group)
        a = sum(median(c, "after", "seconds") for c in group)
        bc = sum(median(c, "before", "cpu") for c in group)
        ac = sum(median(c, "after", "cpu") for c in group)
        print(f"| {label} | {len(group)} | {b:.2f} | {a:.2f} | {a / b:.3f} | {bc:.2f} | {ac:.2f} | {ac / bc:.3f} "
              f"| {sum(same(c) for c in group)}/{len(group)} |")

    for plant, group in plants.items():
        row(plant, group)
    row("**total**", cases)
    ratios = [median(c, "after", "seconds") / median(c, "before", "seconds") for c in cases]
    print(f"\nPer case, after / before (wall): median {statistics.median(ratios):.3f}, "
          f"min {min(ratios):.3f}, max {max(ratios):.3f}\n")
    print("| case | method | workers | before s | after s | after / before | same |")
    print("|---|---|---|---|---|---|---|")
    for c, ratio in zip(cases, ratios):
        print(f"| {c['name']} | {c['options']['method']} | {c['options']['workers']} "
              f"| {median(c, 'before', 'seconds'):.3f} | {median(c, 'after', 'seconds'):.3f} | {ratio:.3f} "
              f"| {'yes' if same(c) else '**no**'} |")
    print("\nWall-clock seconds around bgc.api.diagnose in each side's worker process (reading the run file "
          "included); CPU: the worker's user + system seconds with its reaped children. A shared machine: "
          "the wall-clock ratio of one case moves by tens of per cent from run to run, the totals less.")


if __name__ == "__main__":
    main()
