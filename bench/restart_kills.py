"""A monitor killed anywhere goes on as if it had never stopped (issue 47,
point 4): ``bgc monitor --state DIR`` SIGKILLed at 20 points of a long stream
with faults, then started again on the whole stream, ends with the report of
the uninterrupted run, every time.

    .venv/bin/python bench/restart_kills.py

The stream: the circuit of models/circuit.yaml simulated by the exact
solution of its equations (tests/test_episodes.py's ``plant``), 600 rows to
t = 30: R2 at 1.6 times its value from t = 6, R1 at 1.5 times from t = 18
(both closed as episodes and accommodated), sensor f2 reading 0.5 high from
t = 28 (an episode still open when the stream ends: the final report's
verdict, candidates, onset and estimates are of it). The monitor runs with
``--episodes --checkpoint 1``, 300 particles, seed 3 (the state holds a
fault log and accommodated faults), ``--state DIR --state-every 5``.

Each run is a real process (``python -m bgc monitor ... --data -``) fed
through a real pipe. The target is the report of the uninterrupted run of
the same stream (no --state, the whole stream written at once). A second
uninterrupted run is fed one row at a time, each once the monitor took the
one before (the pipe is empty and its main thread sleeps in read(2) on
standard input: /proc/PID/syscall): its report must be the same, and it
times each row. The 20 kill points (rows) are drawn by a seeded RNG,
stratified so that some fall before the first save, inside each episode
(between its alarm and its close, read off the uninterrupted run's fault
log), right after each episode closes, inside the episode open at the end,
and the rest anywhere. At kill point k the rows before row k are written
and the monitor is let take them all; then rows k to k + 4 (five rows: one
save among them; before the first save, rows k to 4) are written and the
monitor is SIGKILLed after a fraction, drawn by the same RNG, of the time
the paced run took for those rows: the kill lands at a random moment of
their processing (a step, a checkpoint, an episode's close, a save: not
only right after a save), or just after it when this run is faster. The
monitor is then started again on the same state folder with the whole
stream on standard input, and its report.json is compared with the
uninterrupted one. The monitors import a copy of the checkout's bgc made
when the benchmark starts (an edit of the checkout meanwhile would change
the code's digest, part of a state's identity, and the numbers).

Equality: every field of report.json, numbers to 1e-9 (relative above 1),
but ``seconds`` (the wall-clock time the diagnosis took, the one field a
clock and not the data makes; tests/test_monitor_state.py's ``report()``
leaves it out likewise); the fault log (the EpisodeClosed and Repaired
events leading the report's events) is compared and shown on its own too.

The table: the kill point (row k, its time, where it falls), the rows
written after the wait, the kill's delay (and its fraction of their time),
the state at the kill (the stream row its last row is, the rows it holds:
since the last episode closed; "save cut": killed inside a save, its new
file written in part or whole but not renamed over the last state), what
the restart said it resumed from, whether the report and the fault log are
equal, and what differed. Exits 1 when any of the 20 differs. Two busy
cores: about 10 minutes.
"""

from __future__ import annotations

import array
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

from _claims import ROOT, run  # noqa: E402  (first: the suite's set-up before NumPy loads)

import numpy as np  # noqa: E402

CIRCUIT = ROOT / "models" / "circuit.yaml"
OPTIONS = ("--particles", "300", "--seed", "3", "--checkpoint", "1", "--episodes")
ROWS, DT = 600, 0.05
#: R2 x1.6 from t = 6, R1 x1.5 from t = 18, f2 reading 0.5 high from t = 28 (sensor index 0).
CHANGES, BIAS = [(6.0, {"R2": 1.6}), (18.0, {"R1": 1.5})], (28.0, 0, 0.5)
EVERY = 5  # --state-every
KILLS, SEED = 20, 47
TOLERANCE = 1e-9
#: report.json's fields a clock makes, not the data: left out of the comparison.
CLOCK = ("seconds",)


def stream() -> list[str]:
    from test_episodes import plant

    return plant(ROWS, CHANGES, bias=BIAS).splitlines(keepends=True)


def command(out: Path, state: Path | None = None) -> list[str]:
    more = () if state is None else ("--state", str(state), "--state-every", str(EVERY))
    return [sys.executable, "-m", "bgc", "monitor", str(CIRCUIT), "--data", "-", *OPTIONS, "-o", str(out), *more]


def report(folder: Path) -> dict:
    return _no_clock(json.loads((folder / "report.json").read_text(encoding="utf-8")))


def _no_clock(value):
    if isinstance(value, dict):
        return {k: _no_clock(v) for k, v in value.items() if k not in CLOCK}
    if isinstance(value, list):
        return [_no_clock(v) for v in value]
    return value


def fault_log(r: dict) -> list:
    return [e for e in r["events"] if e["event"] in ("EpisodeClosed", "Repaired")]


def differences(a, b, path: str = "") -> list[str]:
    """Where ``a`` and ``b`` differ (numbers within TOLERANCE are equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}.{k}: only in one" for k in sorted(set(a) ^ set(b))]
        for k in a:
            if k in b:
                out += differences(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} vs {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        return [] if abs(a - b) <= TOLERANCE * max(1.0, abs(a), abs(b)) else [f"{path}: {a!r} vs {b!r}"]
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


def state_at(folder: Path) -> tuple[float | None, int]:
    """The saved state's last row's time (None: no state) and the rows it holds."""
    f = folder / "monitor.state"
    if not f.is_file():
        return None, 0
    header = json.loads(f.read_bytes().split(b"\n")[1])
    return header["last_time"], header["rows"]


def _waiting(p: subprocess.Popen) -> bool:
    """Whether monitor ``p`` took every byte written to it and sleeps reading its standard input."""
    count = array.array("i", [0])
    fcntl.ioctl(p.stdin.fileno(), termios.FIONREAD, count)
    if count[0]:
        return False
    try:
        stat = Path(f"/proc/{p.pid}/stat").read_text().rsplit(")", 1)[1].split()
        call = Path(f"/proc/{p.pid}/syscall").read_text().split()
    except OSError:
        return False
    return stat[0] == "S" and call[:2] == ["0", "0x0"]  # read(2) on fd 0


#: Where the monitors' bgc is imported from: a copy of the checkout's, made when the benchmark starts
#: (:func:`frozen`); None: the checkout's own.
CODE: Path | None = None


def frozen(tmp: Path) -> Path:
    """A copy of the checkout's bgc package in ``tmp``, which every monitor
    here imports (their working folder, first on their ``sys.path``): an
    edit of the checkout while the benchmark runs changes neither the code
    under test nor its digest, part of a state's identity."""
    code = tmp / "code"
    shutil.copytree(ROOT / "bgc", code / "bgc", ignore=shutil.ignore_patterns("__pycache__"))
    return code


def environment() -> dict:
    return dict(os.environ, MPLBACKEND="Agg")


def process(how, cmd: list[str], **more):
    """``how`` (subprocess.run or Popen) of ``cmd`` with the frozen bgc."""
    return how(cmd, env=environment(), cwd=CODE, **more)


def paced(out: Path, lines: list[str]) -> tuple[int, list[float]]:
    """The monitor fed one row at a time, each once it took the one before:
    (its exit status, the seconds it took each row, index 0 the column line
    and the start)."""
    p = process(subprocess.Popen, command(out), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL)
    seconds = []
    try:
        for line in lines:
            start = time.perf_counter()
            p.stdin.write(line.encode())
            p.stdin.flush()
            while not _waiting(p) and p.poll() is None:
                time.sleep(0.001)
            seconds.append(time.perf_counter() - start)
        p.stdin.close()
        return p.wait(timeout=300), seconds
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def killed_at(out: Path, lines: list[str], k: int, window: int, delay: float,
              state: Path) -> tuple[int | None, str]:
    """Feed the rows before row ``k``, wait until the monitor took them, write
    rows ``k`` to ``k + window - 1``, SIGKILL it ``delay`` seconds later:
    (its exit status, a note)."""
    p = process(subprocess.Popen, command(out, state), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE)
    try:
        p.stdin.write("".join(lines[:k]).encode())  # the column line and rows 1 to k - 1
        p.stdin.flush()
        deadline = time.monotonic() + 300
        while not _waiting(p) and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if p.poll() is not None:
            return p.returncode, "ended before the kill: " + p.stderr.read().decode()[-300:]
        if not _waiting(p):
            return None, "never waited for row k"
        p.stdin.write("".join(lines[k:k + window]).encode())
        p.stdin.flush()
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
        return p.returncode, ""
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        for f in (p.stdin, p.stderr):
            try:
                f.close()
            except OSError:  # the pipe's reader is gone
                pass


def kill_points(rng, log: list, final: dict) -> list[tuple[int, str]]:
    """The 20 kill points (row, where), stratified over the stream."""
    def row(t: float) -> int:
        return int(round(t / DT))

    strata = [((1, EVERY - 1), 2, "before the first save")]
    for e in log:
        if e["event"] == "EpisodeClosed":
            a, c = row(e["alarm"]), row(e["time"])
            strata += [((a + 1, c), 3, f"in episode {e['number']}"),
                       ((c + 1, c + 3), 2, f"just after episode {e['number']} closed")]
    alarm = (final.get("detection") or {}).get("time")
    if alarm is not None:
        strata.append(((row(alarm) + 1, ROWS - 1), 2, "in the episode open at the end"))
    points: dict[int, str] = {}
    for (low, high), n, where in strata:
        for k in rng.choice(np.arange(low, high + 1), size=min(n, high - low + 1), replace=False):
            points.setdefault(int(k), where)
    while len(points) < KILLS:
        points.setdefault(int(rng.integers(1, ROWS)), "anywhere")
    return sorted(points.items())


def restart_kills():
    global CODE
    lines = stream()
    rng = np.random.default_rng(SEED)
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        CODE = frozen(tmp)
        where = process(subprocess.run, [sys.executable, "-c", "import bgc; print(bgc.__file__)"],
                        capture_output=True, text=True).stdout.strip()
        if not where.startswith(str(CODE)):
            return [f"  bgc imported from {where}"], [("the monitors import the frozen copy of bgc", False)]
        whole = process(subprocess.run, command(tmp / "whole"), input="".join(lines), capture_output=True,
                        text=True)
        if whole.returncode != 0:
            return [whole.stderr[-2000:]], [("the uninterrupted run ends well", False)]
        target = report(tmp / "whole")
        log = fault_log(target)
        code, seconds = paced(tmp / "paced", lines)
        paced_same = code == 0 and not differences(target, report(tmp / "paced"))
        rows = ["  the uninterrupted run: " + "; ".join(
                    f"episode {e['number']} alarm t = {e['alarm']:g}, closed t = {e['time']:g} "
                    f"({e['action']} {e['parameter']} = {e['value']})" for e in log if e["event"] == "EpisodeClosed")
                + f"; at the end: {target['verdict']}: {', '.join(target.get('diagnosis') or [])}, "
                  f"onset t = {target.get('onset')}",
                f"  fed one row at a time: {sum(seconds):.1f} s, a row {1000 * min(seconds[1:]):.1f} to "
                f"{1000 * max(seconds[1:]):.0f} ms",
                f"  {'kill row':>8} {'t':>6}  {'where':<30} {'rows fed':>9} {'kill at':>15}  {'state at kill':<30} "
                f"{'resumed from':<22} {'equal':<5} {'log':<5} what differed"]
        points = kill_points(rng, log, target)
        fractions = rng.uniform(0, 1, size=len(points))
        equal = 0
        for i, ((k, where), fraction) in enumerate(zip(points, fractions)):
            state = tmp / f"state{i}"
            window = EVERY - k if where == "before the first save" else EVERY  # rows k to k + window - 1
            delay = float(fraction) * sum(seconds[k:k + window])
            code, note = killed_at(tmp / f"killed{i}", lines, k, window, delay, state)
            last, held = state_at(state)
            at = "none" if last is None else f"row {int(round(last / DT))} ({held} held)"
            if (state / ".monitor.state.partial").exists():
                at += ", save cut"  # killed inside a save: its new file written, not yet renamed
            problems = [] if code == -signal.SIGKILL else [f"not killed ({code}) {note}".strip()]
            if (tmp / f"killed{i}" / "report.json").exists():
                problems.append("the killed run wrote a report")
            again = process(subprocess.run, command(tmp / f"again{i}", state), input="".join(lines),
                            capture_output=True, text=True)
            first = again.stdout.split("\n", 1)[0]
            resumed = first.split(": ", 1)[1].split(";")[0] if first.startswith("resumed from") else \
                "afresh" if again.returncode == 0 else "(failed)"
            if again.returncode != 0:
                problems.append("restart failed: " + again.stderr.strip()[-300:])
                same_log = False
            else:
                got = report(tmp / f"again{i}")
                problems += differences(target, got)
                same_log = not differences(log, fault_log(got))
            ok = not problems
            equal += ok
            differed = "" if ok else f"{len(problems)}: " + "; ".join(problems[:3])
            fed = f"{k}-{k + window - 1}"
            rows.append(f"  {k:>8} {k * DT:>6.2f}  {where:<30} {fed:>9} "
                        f"{1000 * delay:>5.0f} ms ({100 * fraction:>2.0f} %)  {at:<30} {resumed:<22} {'yes' if ok else 'NO':<5} {'yes' if same_log else 'NO':<5} "
                        f"{differed}")
            print(rows[-1], flush=True)
    checks = [("fed one row at a time, the uninterrupted run gives the same report", paced_same),
              (f"{len(points)} kill points drawn (seed {SEED})", len(points) == KILLS),
              (f"{equal} of {len(points)} final reports equal the uninterrupted one "
               f"(numbers to {TOLERANCE:g}, but {', '.join(CLOCK)})", equal == len(points) == KILLS)]
    return rows, checks


CLAIMS = {"restart-kills": restart_kills}


def main(argv=None) -> int:
    return run(CLAIMS, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
