"""The Python API (bgc/api.py): every public function checks its arguments
as the command line does, before any work, with one-line errors that are
also TypeError / ValueError; a Run from Python goes through a file's checks;
a scenario's onset must lie inside the run; a sensor never read is named in
a note; requests beyond the memory are refused with the most steps allowed."""

import io
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import bgc
from bgc import api, cli
from bgc.api import folders as api_folders
from bgc.api import limits as api_limits
from bgc.errors import (ArgumentTypeError, ArgumentValueError, BgcError, DataError, SimulationError,
                        TrackingError)
from bgc.output.events import sentence
from bgc import events
from bgc.data import runs
from bgc.analysis import simulate
from bgc.diagnosis.options import DiagnosisOptions

from conftest import ROOT, compiled, peak_memory, session

CIRCUIT = ROOT / "models" / "circuit.yaml"
TWO_TANK = ROOT / "models" / "two_tank.yaml"
GENERATED = ROOT / "generated"


def refused(call, kind, start: str) -> str:
    """The one-line message ``call()`` raises (of class ``kind``), checked to start with ``start``."""
    started = time.perf_counter()
    with pytest.raises(kind) as info:
        call()
    line = info.value.line()
    assert line.startswith(start), line
    assert "\n" not in line and time.perf_counter() - started < 10  # before any work
    return line


# ------------------------------------------------------------ bgc.diagnose: types and ranges
@pytest.mark.parametrize("kwargs, kind, start", [
    (dict(model=5, data="run.csv"), ArgumentTypeError, "bgc.diagnose: model=5 is not a path"),
    (dict(scenario=5), ArgumentTypeError, "bgc.diagnose: scenario=5 is not a string"),
    (dict(scenario="none", seed=-1), ArgumentValueError, "bgc.diagnose: seed=-1 is negative"),
    (dict(scenario="none", seed=True), ArgumentTypeError, "bgc.diagnose: seed=True is not an integer"),
    (dict(scenario="none", seed=1.0), ArgumentTypeError, "bgc.diagnose: seed=1.0 is not an integer"),
    (dict(scenario="none", particles=None), ArgumentTypeError, "bgc.diagnose: particles=None is not an integer"),
    (dict(scenario="none", particles=100.5), ArgumentTypeError, "bgc.diagnose: particles=100.5 is not an integer"),
    (dict(scenario="none", particles=True), ArgumentTypeError, "bgc.diagnose: particles=True is not an integer"),
    (dict(scenario="none", particles=np.bool_(True)), ArgumentTypeError, "bgc.diagnose: particles=np.True_"),
    (dict(scenario="none", particles="200"), ArgumentTypeError, "bgc.diagnose: particles='200' is not an integer"),
    (dict(scenario="none", particles=0), ArgumentValueError,
     "bgc.diagnose: particles=0: at least 1 particle is needed"),
    (dict(scenario="none", process_noise=-1.0), ArgumentValueError,
     "bgc.diagnose: process_noise=-1: a level must be a finite number >= 0 and at most 1e6"),
    (dict(scenario="none", process_noise=float("inf")), ArgumentValueError, "bgc.diagnose: process_noise=inf"),
    (dict(scenario="none", process_noise=2e6), ArgumentValueError, "bgc.diagnose: process_noise=2e+06"),
    (dict(scenario="none", process_noise="0.1"), ArgumentTypeError, "bgc.diagnose: process_noise='0.1' is not"),
    (dict(scenario="none", measurement_noise=0.0), ArgumentValueError,
     "bgc.diagnose: measurement_noise=0: a noiseless sensor makes the filters' likelihood degenerate"),
    (dict(scenario="none", measurement_noise=float("nan")), ArgumentValueError, "bgc.diagnose: measurement_noise=nan"),
    (dict(scenario="none", filter="pf"), ArgumentValueError, "bgc.diagnose: filter='pf' is not one of gpf, apf"),
    (dict(scenario="none", filter=1), ArgumentTypeError, "bgc.diagnose: filter=1 is not one of"),
    (dict(scenario="none", steps=0), ArgumentValueError, "bgc.diagnose: steps=0: simulate at least 1 step"),
    (dict(scenario="none", steps=30.0), ArgumentTypeError, "bgc.diagnose: steps=30.0 is not an integer"),
    (dict(data="run.csv", steps=30), ArgumentValueError, "bgc.diagnose: steps=30 with data"),
    (dict(), ArgumentValueError, "bgc.diagnose: give either data or a scenario, not neither"),
    (dict(data="run.csv", scenario="none"), ArgumentValueError,
     "bgc.diagnose: give either data or a scenario, not both"),
    (dict(data=5), ArgumentTypeError, "bgc.diagnose: data=5 is not a path, a Run or a Simulation"),
    (dict(data=np.zeros((3, 2))), ArgumentTypeError, "bgc.diagnose: data=array("),
    (dict(scenario="none", generated=3), ArgumentTypeError, "bgc.diagnose: generated=3 is not a path"),
    (dict(scenario="none", options={}), ArgumentTypeError, "bgc.diagnose: options={} is not a DiagnosisOptions"),
    (dict(scenario="none", progress="yes"), ArgumentTypeError, "bgc.diagnose: progress='yes' is not callable"),
    (dict(scenario="none", options=DiagnosisOptions(particles=100.5)), ArgumentTypeError,
     "bgc.diagnose: options.particles=100.5 is not an integer"),
    (dict(scenario="none", options=DiagnosisOptions(particles=0)), ArgumentValueError,
     "bgc.diagnose: options.particles=0: at least 1 particle is needed"),  # the CLI: "--particles 0: ..."
    (dict(scenario="none", options=DiagnosisOptions(seed=-3)), ArgumentValueError,
     "bgc.diagnose: options.seed=-3 is negative"),
    (dict(scenario="none", options=DiagnosisOptions(filter="kf")), ArgumentValueError,
     "bgc.diagnose: options.filter='kf' is not one of"),
    (dict(scenario="none", options=DiagnosisOptions(identify="both")), ArgumentValueError,
     "bgc.diagnose: options.identify='both' is not one of kalman, filter"),
    (dict(scenario="none", options=DiagnosisOptions(windows=[1, 8])), ArgumentTypeError,
     "bgc.diagnose: options.windows=[1, 8] is not a non-empty tuple"),
    (dict(scenario="none", options=DiagnosisOptions(windows=(1, 0))), ArgumentValueError,
     "bgc.diagnose: options.windows=0: a window holds at least 1 sample"),
    (dict(scenario="none", options=DiagnosisOptions(false_alarm=1.0)), ArgumentValueError,
     "bgc.diagnose: options.false_alarm=1 is out of range"),
    (dict(scenario="none", options=DiagnosisOptions(workers=0)), ArgumentValueError,
     "bgc.diagnose: options.workers=0: give at least 1"),
    (dict(scenario="none", options=DiagnosisOptions(refine=1)), ArgumentTypeError,
     "bgc.diagnose: options.refine=1 is not True or False"),
    (dict(scenario="none", options=DiagnosisOptions(kalman=None)), ArgumentTypeError,
     "bgc.diagnose: options.kalman=None is not a KalmanOptions"),
])
def test_diagnose_refuses_bad_arguments_before_any_work(kwargs, kind, start):
    model = kwargs.pop("model", CIRCUIT)
    refused(lambda: bgc.diagnose(model, **kwargs), kind, start)
    assert issubclass(kind, TypeError if kind is ArgumentTypeError else ValueError)


def test_the_issue_cases_raise_what_python_expects():
    """bgc.diagnose(5, data=...) was a TypeError from deep inside, scenario=5
    an AttributeError, seed=-1 NumPy's ValueError, options={} an
    AttributeError; now each is the API's own error, still catchable as
    TypeError or ValueError, and a BgcError for the CLI's one line."""
    for call, base in ((lambda: bgc.diagnose(5, data="run.csv"), TypeError),
                       (lambda: bgc.diagnose(CIRCUIT, scenario=5), TypeError),
                       (lambda: bgc.diagnose(CIRCUIT, scenario="none", seed=-1), ValueError),
                       (lambda: bgc.diagnose(CIRCUIT, scenario="none", options={}), TypeError),
                       (lambda: bgc.diagnose(CIRCUIT, scenario="none", particles=100.5), TypeError),
                       (lambda: bgc.diagnose(CIRCUIT, scenario="none", process_noise=-1.0), ValueError)):
        with pytest.raises(base) as info:
            call()
        assert isinstance(info.value, BgcError)


def test_numpy_integers_are_integers():
    r = bgc.diagnose(session(TWO_TANK, generated=GENERATED), scenario="none", steps=np.int64(40),
                     particles=np.int32(100), seed=np.uint8(1), options=None)
    assert r.diagnosis.verdict == "no fault" and len(r.run.time) == 40 and r.run.source == "scenario none"


# ------------------------------------------------------------ a scenario's onset inside the run
@pytest.mark.parametrize("scenario", ["R2:abrupt:0.5@100", "R2:abrupt:0.5@2", "R2:abrupt:0.5@0",
                                      "R2:abrupt:0.5@1e300", "R2:incipient:0.1@2.5"])
def test_an_onset_outside_the_run_is_refused(scenario):
    """The issue's case (onset 100, run to t = 4 said 'no fault'), the last
    sample's time (a fault seen by no sample after it), 0, far away."""
    refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), scenario=scenario, steps=40),
            ArgumentValueError, f"bgc.diagnose: scenario {scenario}: onset")


def test_an_onset_inside_the_run_is_diagnosed():
    r = bgc.diagnose(session(CIRCUIT, generated=GENERATED), scenario="R2:abrupt:0.6@1.5", steps=40, seed=1,
                     options=DiagnosisOptions(particles=200, workers=1))
    assert r.injected.time == 1.5 and r.run.source == "scenario R2:abrupt:0.6@1.5"


# ------------------------------------------------------------ a Run from Python, files and sources
def circuit_run(steps: int = 60, seed: int = 1) -> runs.Run:
    num = compiled("circuit").numerics
    result = simulate.simulate(num, simulate.SimulationOptions(steps=steps, seed=seed))
    return runs.parse_run(simulate.to_csv(result), "circuit.csv")


def replace(run: runs.Run, **change) -> runs.Run:
    fields = {f: getattr(run, f) for f in runs.Run.__slots__}
    fields.update(change)
    return runs.Run(**fields)


@pytest.mark.parametrize("change, start", [
    (dict(time=np.array([])), "<Run from Python>: the run has no data rows"),
    (dict(time=np.r_[0.05, np.nan, np.arange(3, 61) * 0.05]), "<Run from Python>, index 1: time nan"),
    (dict(time=np.r_[0.1, 0.05, np.arange(3, 61) * 0.05]), "<Run from Python>, index 1: time 0.05 does not increase"),
    (dict(time=np.r_[0.05, 0.05, np.arange(3, 61) * 0.05]), "<Run from Python>, index 1: time 0.05 does not"),
    (dict(header=("model ro: 60 steps",)), "<Run from Python> is a run of model 'ro', not of 'circuit'"),
    (dict(measurements={"e11": np.ones((60, 1))}), "<Run from Python>: column y:e11 has shape (60, 1)"),
    (dict(measurements={"e11": np.ones(59)}), "<Run from Python>: column y:e11 has 59 values, the time 60"),
    (dict(measurements={"e11": np.array(["1.0"] * 60)}), "<Run from Python>: column y:e11 holds <U3 values"),
    (dict(measurements={"e11": np.full(60, np.inf)}), "<Run from Python>, index 0: inf in column y:e11"),
    (dict(measurements={"q9": np.ones(60)}), "<Run from Python>: the data have none of the model's sensors"),
    (dict(source="bench 4", measurements={}), "bench 4: the data have none of the model's sensors"),
])
def test_a_run_from_python_goes_through_the_checks_of_a_csv(change, start):
    run = replace(circuit_run(), **{"source": runs.PYTHON_SOURCE, "header": (), **change})
    refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=run), DataError, start)


def test_data_messages_name_the_file_and_line(tmp_path):
    """The issue's second half: a run without a sensor's column, and infinite
    samples, named by their file (and line)."""
    path = tmp_path / "run.csv"
    text = runs.run_csv(circuit_run())
    path.write_text(text.replace("y:f2", "y:f9"))  # a sensor the model lacks, one it has missing: both said
    d = bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=path, options=DiagnosisOptions(particles=100, workers=1))
    assert {events.SensorMissing("f2"), events.ColumnIgnored("y:f9")} <= set(d.diagnosis.events)
    lines = text.splitlines(keepends=True)
    first = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    column = lines[first].rstrip().split(",").index("y:f2")
    for i in range(first + 1, len(lines)):  # the issue's case: -inf in every y:f2
        cells = lines[i].rstrip("\n").split(",")
        cells[column] = "-inf"
        lines[i] = ",".join(cells) + "\n"
    path.write_text("".join(lines))
    refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=path), DataError,
            f"{path}:{first + 2}: -inf in column y:f2 is not a finite number")


def test_a_sensor_never_read_is_named_in_an_event():
    run = circuit_run(80)
    blind = replace(run, measurements={**run.measurements, "f2": np.full(80, np.nan)}, source="bench.csv")
    d = bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=blind, options=DiagnosisOptions(particles=200, workers=1))
    silent = [e for e in d.diagnosis.events if isinstance(e, events.SensorSilent)]
    assert silent == [events.SensorSilent("f2")], d.diagnosis.events
    assert "sensor y:f2 has no sample in the run" in sentence(silent[0], d.diagnosis.time_of)
    seen = bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=run, options=DiagnosisOptions(particles=200, workers=1))
    assert not any(isinstance(e, events.SensorSilent) for e in seen.diagnosis.events)


# ------------------------------------------------------------ memory: the diagnosis step limit
def test_a_diagnosis_beyond_the_memory_is_refused_with_the_most_steps():
    num = compiled("circuit").numerics
    line = refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), scenario="none", steps=10_000_000),
                   TrackingError, "bgc.diagnose: steps=10000000: a diagnosis of 10000000 steps of circuit may take about")
    most = int(line.split("at most ")[1].split()[0])
    api_limits.check_diagnosis_steps(most, num, 1000, "gpf")
    with pytest.raises(TrackingError):
        api_limits.check_diagnosis_steps(most + 1, num, 1000, "gpf")
    fixed, per_step = api_limits.diagnosis_memory(most, num, 1000, "gpf")
    assert fixed + most * per_step <= api_limits.MAX_DIAGNOSIS_BYTES < fixed + (most + 1) * per_step
    # ckf keeps no particle clouds: it may diagnose longer runs; more particles, shorter ones
    assert api_limits.diagnosis_memory(1, num, 1000, "ckf")[0] == 0
    assert api_limits.diagnosis_memory(1, num, 4000, "gpf")[1] > per_step
    refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), scenario="none", particles=10_000_000), TrackingError,
            "10000000 particles: a diagnosis of circuit keeps 257 clouds of them")


def test_a_long_recorded_run_is_refused_by_the_same_rule(monkeypatch):
    monkeypatch.setattr(api_limits, "MAX_DIAGNOSIS_BYTES", 20_000_000)
    refused(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=circuit_run(200)), TrackingError,
            "circuit.csv: 200 samples: a diagnosis of 200 steps of circuit may take about")


@pytest.mark.slow
@pytest.mark.long
def test_the_rule_bounds_the_memory_a_diagnosis_takes():
    """tracemalloc's peak of a diagnosis (one process, a drift found and
    sized) stays under the rule's bound. Before it, a shorter diagnosis of the
    same kind (a drift found and sized) compiles and imports what the
    measured one uses: that is not counted."""
    def run_of(steps):
        return runs.parse_run(simulate.to_csv(simulate.simulate(compiled("circuit").numerics, simulate.SimulationOptions(
            steps=steps, seed=2, fault=simulate.parse_fault("R2:abrupt:0.6@3", compiled("circuit").numerics)))), "r")

    run = run_of(200)
    options = DiagnosisOptions(particles=300, workers=1)
    warm = bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=run_of(90), options=options).diagnosis
    assert warm.verdict != "no fault" and warm.estimate is not None
    d, peak = peak_memory(lambda: bgc.diagnose(session(CIRCUIT, generated=GENERATED), data=run, options=options).diagnosis)
    fixed, per_step = api_limits.diagnosis_memory(200, compiled("circuit").numerics, 300, "gpf")
    assert d.verdict != "no fault" and peak < fixed + 200 * per_step, (peak, fixed, per_step)


# ------------------------------------------------------------ bgc.distinguishability
@pytest.mark.parametrize("kwargs, kind, start", [
    (dict(model=None), ArgumentTypeError, "bgc.distinguishability: model=None is not a path"),
    (dict(scenario=3.5), ArgumentTypeError, "bgc.distinguishability: scenario=3.5 is not a string"),
    (dict(change=0), ArgumentValueError, "bgc.distinguishability: change=0 is out of range"),
    (dict(change=True), ArgumentTypeError, "bgc.distinguishability: change=True is not a number"),
    (dict(at=1.0), ArgumentValueError, "bgc.distinguishability: at=1 is out of range"),
    (dict(at=1e308), ArgumentValueError, "bgc.distinguishability: at=1e+308 is out of range"),  # an OverflowError
    (dict(at=float("nan")), ArgumentValueError, "bgc.distinguishability: at=nan is out of range"),
    (dict(level=0.0), ArgumentValueError, "bgc.distinguishability: level=0 is out of range"),
    (dict(steps=-4), ArgumentValueError, "bgc.distinguishability: steps=-4: simulate at least 1 step"),
    (dict(steps=False), ArgumentTypeError, "bgc.distinguishability: steps=False is not an integer"),
    (dict(process_noise=-0.1), ArgumentValueError, "bgc.distinguishability: process_noise=-0.1"),
    (dict(measurement_noise=0), ArgumentValueError, "bgc.distinguishability: measurement_noise=0: a noiseless"),
    (dict(progress=1), ArgumentTypeError, "bgc.distinguishability: progress=1 is not callable"),
    (dict(steps=1_000_000), TrackingError, "bgc.distinguishability: steps: 1000000 steps: the prediction would take about"),
    (dict(steps=10_000_000), TrackingError, "bgc.distinguishability: steps: 10000000 steps: the prediction would take about"),
    (dict(scenario="R2:abrupt:0.5@1e9"), SimulationError, "onset 1e+09 is outside the run"),
])
def test_distinguishability_refuses_bad_arguments_before_any_work(kwargs, kind, start):
    model = kwargs.pop("model", CIRCUIT)
    refused(lambda: bgc.distinguishability(model, **kwargs), kind, start)


def test_private_folders_are_this_processs_own_and_removed_on_demand(tmp_path, monkeypatch):
    """What a campaign worker whose campaign died runs before it ends:
    its own private folders go (the one being made too: it is named before
    it is made); a folder listed for another process (the parent a worker
    was forked from) stays."""
    monkeypatch.setattr(api_folders, "_FOLDERS", [])
    monkeypatch.setattr(api_folders.tempfile, "gettempdir", lambda: str(tmp_path))
    mine = Path(api_folders.private_folder("bgc-test-"))
    assert mine.is_dir() and mine.parent == tmp_path and (os.stat(mine).st_mode & 0o777) == 0o700
    (mine / "x.yaml").write_text("x", encoding="utf-8")
    other = tmp_path / "bgc-parent"
    other.mkdir()
    api_folders._FOLDERS.append((os.getpid() + 1, str(other)))
    api_folders._FOLDERS.append((os.getpid(), str(tmp_path / "bgc-named-not-made")))
    api_folders.remove_private_folders()
    assert not mine.exists() and other.is_dir()


def test_private_folder_takes_a_prefix_string():
    refused(lambda: api_folders.private_folder(5), ArgumentTypeError, "bgc.api.folders.private_folder: prefix=5 is not a string")


def test_bgc_gives_the_api_functions():
    assert bgc.distinguishability is api.distinguishability and bgc.DistinguishabilityReport is \
        api.DistinguishabilityReport
    with pytest.raises(AttributeError):
        bgc.no_such_function  # noqa: B018


# ------------------------------------------------------------ the command line
class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bgc_distinguish_reports_progress_on_a_terminal(monkeypatch, capsys):
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    assert cli.main(["distinguish", str(TWO_TANK), "--steps", "40", "--change", "0.5"]) == 0
    text = err.getvalue()
    assert "\rbgc distinguish: preparing the families: the nominal run" in text
    # models/two_tank.yaml: 8 parameter fault models, 3 sensors x (bias, drift), the inflow's bias: 15;
    # scenarios, one per direction: 12 of the parameters', 12 of the sensors', 2 of the inflow's
    assert "bgc distinguish: preparing the families: fault model 1 of 15 (" in text
    assert "bgc distinguish: scenario 26 of 26: " in text
    assert text.endswith("\r")  # the line is cleared at the end
    assert "R10" in capsys.readouterr().out


def test_out_of_memory_names_the_command_and_its_files(monkeypatch, capsys):
    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(api, "diagnose", exhausted)
    monkeypatch.setattr(api, "distinguishability", exhausted)
    assert cli.main(["diagnose", str(CIRCUIT), "--data", "lab/run 7.csv"]) == 1
    assert capsys.readouterr().err == (f"bgc diagnose: out of memory on {CIRCUIT}, --data lab/run 7.csv (use "
                                       "fewer particles, steps or a smaller model)\n")
    assert cli.main(["distinguish", str(CIRCUIT), "--steps", "20"]) == 1
    assert capsys.readouterr().err.startswith(f"bgc distinguish: out of memory on {CIRCUIT} (")


def test_bgc_distinguish_steps_must_be_positive(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["distinguish", str(CIRCUIT), "--steps", "0"])
    assert info.value.code == 2 and "0: give an integer >= 1" in capsys.readouterr().err


def test_the_step_limit_a_campaign_calls_checks_its_arguments_too():
    num = compiled("circuit").numerics
    refused(lambda: api_limits.check_diagnosis_steps(0, num), ArgumentValueError, "bgc.api.limits.diagnosis_memory: steps=0")
    refused(lambda: api_limits.check_diagnosis_steps(300, "circuit"), ArgumentTypeError,
            "bgc.api.limits.diagnosis_memory: num='circuit' is not a Numerics")
    refused(lambda: api_limits.check_diagnosis_steps(300, num, 1000, "pf"), ArgumentValueError,
            "bgc.api.limits.diagnosis_memory: method='pf' is not one of")
    refused(lambda: api_limits.check_diagnosis_steps(300, num, True), ArgumentTypeError,
            "bgc.api.limits.diagnosis_memory: particles=True is not an integer")
    refused(lambda: api_limits.check_diagnosis_steps(10**7, num, 1000, "ckf", "steps"), TrackingError,
            "steps: a diagnosis of 10000000 steps of circuit may take about")


@pytest.mark.parametrize("kw", [{"process_noise": 10**400}, {"measurement_noise": -10**400},
                                {"particles": np.int64(2**62)}, {"particles": np.uint64(2**63)}])
def test_numbers_beyond_the_floats_or_the_machine_integers_are_bgc_errors(kw):
    with pytest.raises(BgcError) as info:
        bgc.diagnose(CIRCUIT, scenario="none", steps=30, **kw)
    assert "\n" not in info.value.line()


# ------------------------------------------------------------------ notebooks: write, figures, _repr_html_
class Cells:
    """What a browser makes of an HTML piece: its tags, its text, its table rows (cells as text)."""

    def __init__(self, text: str):
        from html.parser import HTMLParser

        cells = self

        class Parser(HTMLParser):
            def handle_starttag(self, tag, attrs):
                cells.tags.append(tag)
                cells.attrs += [(tag, k, v) for k, v in attrs]
                if tag == "tr":
                    cells.rows.append([])
                if tag in ("td", "th"):
                    cells.rows[-1].append("")
                    cells.inside = True

            def handle_endtag(self, tag):
                if tag in ("td", "th"):
                    cells.inside = False

            def handle_data(self, data):
                cells.text.append(data)
                if cells.inside:
                    cells.rows[-1][-1] += data

        self.tags: list[str] = []
        self.attrs: list[tuple[str, str, str | None]] = []
        self.text: list[str] = []
        self.rows: list[list[str]] = []
        self.inside = False
        p = Parser(convert_charrefs=True)
        p.feed(text)
        p.close()

    @property
    def words(self) -> str:
        return " ".join(" ".join(self.text).split())

    def images(self) -> list[bytes]:
        import base64

        srcs = [v for t, k, v in self.attrs if t == "img" and k == "src"]
        assert all(s.startswith("data:image/png;base64,") for s in srcs)
        return [base64.b64decode(s.split(",", 1)[1]) for s in srcs]


#: A model file's name with a script, markup and an ampersand (no slash).
HOSTILE_NAME = "<script>alert(1)<script> & <b>x"


def _no_markup(text: str, cells: Cells) -> None:
    """``text`` holds the hostile name as text only: no script, no bold, no handler."""
    assert "<script>" not in text and "<b>" not in text
    assert "&lt;script&gt;alert(1)&lt;script&gt; &amp; &lt;b&gt;x" in text
    assert "script" not in cells.tags and "b" not in cells.tags
    assert not [t for t, k, _ in cells.attrs if k.startswith("on")]


@pytest.fixture(scope="module")
def hostile_model(tmp_path_factory):
    """The circuit, its model file's path hostile."""
    model = tmp_path_factory.mktemp("nb") / f"{HOSTILE_NAME}.yaml"
    model.write_bytes((ROOT / "models" / "circuit.yaml").read_bytes())
    return model


@pytest.fixture(scope="module")
def hostile_report(hostile_model):
    """The circuit's R2 rising by 0.6 at t = 5 (sample 100 of 150: the views,
    pictures and folders are the subject); cubature Kalman filters."""
    return bgc.diagnose(hostile_model, scenario="R2:abrupt:0.6@5", seed=1, steps=150,
                        options=DiagnosisOptions(filter="ckf", seed=1, workers=1))


@pytest.fixture(scope="module")
def written(hostile_report, tmp_path_factory):
    """The folder ``hostile_report.write`` wrote (it returns the folder it was
    given), written once for the tests that read it."""
    folder = tmp_path_factory.mktemp("written") / "report"
    assert hostile_report.write(folder) == folder
    return folder


@pytest.mark.slow
def test_a_reports_notebook_view_says_the_verdict_first_and_escapes_the_model_path(hostile_report):
    r = hostile_report
    text = r._repr_html_()
    cells = Cells(text)
    _no_markup(text, cells)
    assert HOSTILE_NAME in r.source and f"Diagnosis of circuit ({r.source})" in cells.words
    d = r.diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("R2_abrupt",))
    words = cells.words
    # the verdict, then its plain words, the alarm, then the estimate with its interval
    e = d.estimate
    assert words.index("Fault isolated: R2_abrupt.") < words.index("alarm at t =") < words.index(
        f"95 % interval [{e.low:.4g}, {e.high:.4g}]")
    assert "estimate.png" in words
    (png,) = cells.images()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert repr(r) == "<bgc.DiagnosisReport of circuit: isolated: R2_abrupt>"


@pytest.mark.slow
def test_figures_are_the_reports_plots_as_live_matplotlib_figures(hostile_report, written):
    from matplotlib.figure import Figure

    from bgc.output import plots

    r = hostile_report
    figures = r.figures()
    folder = written  # r.write's folder
    pngs = sorted(p.name for p in folder.glob("*.png"))
    assert sorted(figures) == pngs == ["estimate.png", "hypotheses.png", "measurements.png", "residuals.png"]
    for name, fig in figures.items():
        assert isinstance(fig, Figure) and fig.axes and all(ax.has_data() for ax in fig.axes)
        assert plots.picture(fig) == (folder / name).read_bytes()  # drawn by the same code the folder's was
    assert len(figures["measurements.png"].axes) == len(r.diagnosis.outputs)  # a sensor an axes
    unit = yaml.safe_load((ROOT / "models" / "circuit.yaml").read_text())["parameters"]["R2"]["unit"]
    assert figures["estimate.png"].axes[0].get_ylabel() == f"bias of R2 [{unit}]"  # the model's unit


@pytest.mark.slow
@pytest.mark.long
def test_write_gives_the_folder_bgc_diagnose_writes_and_refuses_foreign_files(hostile_model, hostile_report, written,
                                                                             tmp_path, capsys):
    import json

    from bgc.errors import OutputError

    r = hostile_report
    out = tmp_path / "cli"
    done = cli.main(["diagnose", str(hostile_model), "--scenario",
                     "R2:abrupt:0.6@5", "--steps", "150", "--filter", "ckf", "--seed", "1", "-o", str(out)])
    assert done == 0 and capsys.readouterr().out.startswith("circuit: isolated: R2_abrupt")
    mine = written  # r.write's folder
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(p.name for p in mine.iterdir())
    assert {"report.md", "report.json", "report.html", "manifest.json", "run.csv"} <= set(names)
    for name in ("run.csv", "estimate.png", "measurements.png"):
        assert (mine / name).read_bytes() == (out / name).read_bytes(), name
    md = [(folder / "report.md").read_text(encoding="utf-8").splitlines() for folder in (mine, out)]
    assert md[0][:-1] == md[1][:-1] and md[0][-1].startswith("Diagnosis computed in")  # but the seconds
    manifest = json.loads((mine / "manifest.json").read_text(encoding="utf-8"))
    assert manifest["command"] == "diagnose" and sorted(manifest["files"]) == [n for n in names if n != "manifest.json"]
    r.write(mine)  # its own folder again: fine
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine\n", encoding="utf-8")
    with pytest.raises(OutputError):
        r.write(foreign)
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    with pytest.raises(ArgumentTypeError):
        r.write(3)


def test_a_sessions_notebook_view_lists_the_model_and_escapes_its_text(tmp_path):
    import yaml

    text = (ROOT / "models" / "circuit.yaml").read_text(encoding="utf-8").replace("unit: ohm, description: load",
                                                                                  "unit: <b>ohm</b>, description: load")
    model = tmp_path / f"{HOSTILE_NAME}.yaml"
    model.write_text(text, encoding="utf-8")
    session = bgc.open(model)
    html = session._repr_html_()
    cells = Cells(html)
    _no_markup(html, cells)
    assert "&lt;b&gt;ohm&lt;/b&gt;" in html
    spec = yaml.safe_load(text)
    words = cells.words
    assert words.startswith("Model circuit") and spec["description"] in words
    assert f"{len(spec['elements'])} elements" in words and f"{len(spec['bonds'])} bonds" in words
    rows = [tuple(r) for r in cells.rows]
    for name, p in spec["parameters"].items():
        assert (name, f"{p['value']:g}", p["unit"], p["description"]) in rows
    for name, y in spec["measurements"].items():
        assert (name, y.get("expr", name), y.get("unit", "-"), f"{y['noise']:g}") in rows
    for name, u in spec["inputs"].items():
        assert (name, f"constant {u['value']:g}", u["unit"]) in rows
    for name in spec["faults"]:
        assert name in words.split("Fault candidates", 1)[1]
    assert "states: e4 (C1), e8 (C2), f10 (L)" in words  # the circuit's states (the model file's comment)


@pytest.mark.slow
def test_a_calibrations_notebook_view_says_its_verdict_and_escapes_the_model_path(tmp_path):
    from test_calibrate import RC, rc_run

    model = tmp_path / f"{HOSTILE_NAME}.yaml"
    model.write_bytes(RC.read_bytes())
    session = bgc.open(model)
    run, _ = rc_run(session, 0.05, 50, 6)  # a short recording: the view is the subject
    report = session.calibrate(run, "measurement_noise")
    html = report._repr_html_()
    cells = Cells(html)
    _no_markup(html, cells)
    assert f"Model file {model}" in cells.words
    assert cells.words.index("The model explains this data.") < cells.words.index("Estimates")
    (e,) = report.calibration.estimates
    assert any(row[0] == e.name and row[3] == f"[{e.level_low:.6g}, {e.level_high:.6g}]" for row in cells.rows)
    (png,) = cells.images()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
