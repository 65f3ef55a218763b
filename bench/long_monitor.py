"""A monitor that runs for months: peak memory and per-row latency of
``bgc monitor``'s service over a long healthy stream, at two lengths side by
side (issue 47's first target: peak RSS within 10 % between 10^5 and 10^6
samples, the watching latency's p99 unchanged).

    .venv/bin/python bench/long_monitor.py [--models circuit,ro] [--samples 100000,1000000] [--particles 1000]

Each (model, length) runs in a fresh process: ``bgc.service.monitor.monitor``
(what ``bgc monitor MODEL --data -`` runs, with its default ``--keep``, 1024
steps) reads the rows of a healthy plant from a stream that makes them as
they are read: the model's own generated nominal model stepped with its
declared process and measurement noise (``transition`` and ``observe``,
``--seed``, 1 by default). The detector's horizon is the stream's length, so the false-alarm budget
(1 %) holds over the whole stream. The stream times each row: the wall-clock
seconds from the moment it hands a row over to the moment the monitor asks
for the next (the row's step, the bookkeeping, the event lines), pooled over
the first 10^4 rows after 1,000 warm-up rows, and over the last 10^4; beside
it the process's CPU seconds over the same span (``time.process_time``),
which other processes of a busy machine do not inflate (a preempted row
costs a time slice, milliseconds, on the wall clock only).

Each model's runs follow an untimed one of 21,000 rows: the compiled
backend's kernels (the backend is the one ``bgc.open`` chooses, printed after
the verdict) are compiled once there and read from numba's cache by the runs
measured, as by a monitor started where bgc ran before (a first compilation
takes tens of MB that a run reading the cache does not).

Peak memory: the process's peak resident set (``VmHWM`` of
/proc/self/status, Linux) at the end, and its resident set after the first
10^4 rows; the report the monitor makes at the end is part of the peak. A
stream whose memory grows with its length shows it in the ratio of the two
lengths' peaks.

The table prints per model and length: the seconds, the peak RSS, the ratio
of the peak to the shorter stream's, the p50 and p99 latency over the first
and the last 10^4 rows, the alarms raised (0 expected: a false alarm starts
an isolation, not a bounded record), and the steps in the record at the end.
Exit status 1 when a peak differs by more than 10 % from the shorter
stream's or an alarm was raised.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

WINDOW = 10_000
WARM = 1_000


def _status(field: str) -> float:
    """A field of /proc/self/status in MB (VmHWM, VmRSS)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class PlantStream:
    """A healthy plant's CSV rows, made as they are read (``readline``), each
    timed from its hand-over to the next read."""

    def __init__(self, package, samples: int, seed: int = 1):
        self.model = m = package.MODELS["nominal"]
        self.samples, self.k = samples, 0
        self.rng = np.random.default_rng(seed)
        self.x = np.array(m.X0, dtype=float)[:, None]
        self.theta = np.asarray(m.THETA, dtype=float)
        self.header = ("time," + ",".join(f"u:{u}" for u in m.INPUTS) + "," +
                       ",".join(f"y:{y}" for y in m.OUTPUTS) + "\n").encode()
        self.handed: float | None = None
        self.handed_cpu = 0.0
        # the times of the two windows measured only (the first after the warm-up, the last): arrays of
        # the stream's length would grow the process by 16 bytes a row (16 MB at 10^6 rows, 1.6 at 10^5)
        # as their pages are written, and the peak measured would be the bench's own, not the monitor's
        self.latency = np.zeros(2 * WINDOW)
        self.cpu = np.zeros(2 * WINDOW)
        self.rss_early = float("nan")

    def slot(self, row: int) -> int | None:
        """Where row ``row``'s times are kept: the first window's rows
        (``WARM`` to ``WARM + WINDOW``) then the last window's; None for the rest."""
        if WARM <= row < WARM + WINDOW:
            return row - WARM
        if row >= self.samples - WINDOW:
            return WINDOW + row - (self.samples - WINDOW)
        return None

    def readline(self, limit: int = -1) -> bytes:
        now, now_cpu = time.perf_counter(), time.process_time()
        if self.handed is not None and (i := self.slot(self.k - 1)) is not None:
            self.latency[i] = now - self.handed
            self.cpu[i] = now_cpu - self.handed_cpu
        if self.k == 0 and self.handed is None:
            self.handed = time.perf_counter()
            return self.header
        if self.k == WARM + WINDOW:
            self.rss_early = _status("VmRSS")
        if self.k >= self.samples:
            return b""
        m = self.model
        self.k += 1
        t = self.k * m.DT
        u = np.asarray(m.inputs(t), dtype=float)
        self.x = m.transition(self.x, u, self.theta, m.DT, self.rng)
        y = m.observe(self.x, u, self.theta)[:, 0] + np.asarray(m.MEASUREMENT_STD) * self.rng.standard_normal(len(m.OUTPUTS))
        line = ",".join(f"{v:.9g}" for v in (t, *u, *y)) + "\n"
        self.handed, self.handed_cpu = time.perf_counter(), time.process_time()
        return line.encode()


def child(model: str, samples: int, particles: int, seed: int) -> dict:
    import bgc
    from bgc import events as ev
    from bgc.diagnosis.options import DiagnosisOptions
    from bgc.service import monitor

    session = bgc.open(ROOT / "models" / f"{model}.yaml")
    dt = session.package.MODELS["nominal"].DT
    stream = PlantStream(session.package, samples, seed)
    alarms = []

    def say(line: str) -> None:
        if "fault detected" in line or "alarm" in line.lower():
            alarms.append(line)

    options = DiagnosisOptions(particles=particles, horizon=samples * dt, workers=1)
    started = time.perf_counter()
    report, failure = monitor.monitor(session, stream, "<plant>", options, say=say)
    seconds = time.perf_counter() - started
    lat, cpu = stream.latency, stream.cpu
    first, last = lat[:WINDOW], lat[WINDOW:]
    d = report.diagnosis
    return dict(model=model, samples=samples, seconds=seconds, backend=session.backend, peak_mb=_status("VmHWM"), rss_early_mb=stream.rss_early,
                p50_first=float(np.percentile(first, 50)) * 1e3, p99_first=float(np.percentile(first, 99)) * 1e3,
                p50_last=float(np.percentile(last, 50)) * 1e3, p99_last=float(np.percentile(last, 99)) * 1e3,
                cpu99_first=float(np.percentile(cpu[:WINDOW], 99)) * 1e3,
                cpu99_last=float(np.percentile(cpu[WINDOW:], 99)) * 1e3,
                alarms=len(alarms), record=len(d.time), verdict=d.verdict,
                failure=None if failure is None else str(failure),
                alarm_events=sum(isinstance(e, ev.Alarmed) for e in d.events))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="circuit,ro")
    p.add_argument("--samples", default="100000,1000000")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--seed", type=int, default=1, help="the plant's noise")
    p.add_argument("--child", nargs=2, metavar=("MODEL", "SAMPLES"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), args.particles, args.seed)))
        return 0
    lengths = [int(float(s)) for s in args.samples.split(",")]
    if min(lengths) < WARM + 2 * WINDOW:
        p.error(f"--samples: at least {WARM + 2 * WINDOW} each")
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    print(f"{'model':8} {'samples':>9} {'seconds':>8} {'peak MB':>8} {'ratio':>6} {'MB@11k':>7} "
          f"{'p50 first':>9} {'p99 first':>9} {'p50 last':>8} {'p99 last':>8} {'cpu99 first':>11} {'cpu99 last':>10} "
          f"{'alarms':>6} {'record':>6}  verdict",
          flush=True)
    ok = True
    for model in args.models.split(","):
        base = None
        # an untimed run first: the compiled backend's kernels, compiled once, are then read from numba's cache
        # by every run measured, as by a monitor started on a machine where bgc ran before
        subprocess.run([sys.executable, __file__, "--child", model, str(WARM + 2 * WINDOW), "--particles",
                        str(args.particles), "--seed", str(args.seed)], capture_output=True, text=True, env=env)
        for n in lengths:
            out = subprocess.run([sys.executable, __file__, "--child", model, str(n), "--particles",
                                  str(args.particles), "--seed", str(args.seed)], capture_output=True, text=True,
                                 env=env)
            if out.returncode != 0:
                print(f"{model} {n}: failed\n{out.stderr[-2000:]}", flush=True)
                ok = False
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            base = base or r["peak_mb"]
            ratio = r["peak_mb"] / base
            ok &= abs(ratio - 1.0) <= 0.10 and r["alarms"] == 0 and r["failure"] is None
            print(f"{model:8} {n:>9} {r['seconds']:>8.0f} {r['peak_mb']:>8.1f} {ratio:>6.3f} {r['rss_early_mb']:>7.1f} "
                  f"{r['p50_first']:>7.2f}ms {r['p99_first']:>7.2f}ms {r['p50_last']:>6.2f}ms {r['p99_last']:>6.2f}ms "
                  f"{r['cpu99_first']:>9.2f}ms {r['cpu99_last']:>8.2f}ms "
                  f"{r['alarms']:>6} {r['record']:>6}  {r['verdict']} ({r['backend']})"
                  + ("" if r["failure"] is None else f"  stopped: {r['failure']}"), flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
