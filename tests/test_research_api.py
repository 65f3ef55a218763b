"""The public Python API a paper is written with (issue 45): bgc.simulate, one name for the filter,
times in the model's unit, errors that name the Python argument, the model's parts as Python
objects, results as tables and DataFrames, and the filter-comparison recipe of docs/api.md."""

from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path

import networkx as nx
import numpy as np
import pytest

import bgc
from bgc.errors import (ArgumentTypeError, ArgumentValueError, CausalityError, ModelError, ValidationError)

from conftest import FAST, numba_package

ROOT = Path(__file__).resolve().parents[1]
TANKS = ROOT / "models" / "two_tank.yaml"


@pytest.fixture(scope="module")
def tanks():
    return bgc.open(TANKS, backend="numpy")


# ------------------------------------------------------------------ simulate
def test_a_simulation_reaches_the_steady_state_derived_by_hand(tanks):
    """R12 2 -> 2.5 at t = 75, no process noise: by t = 150 (time constants C1 R10 = 8 s, C2 R20 = 4.5 s)
    the tanks sit at the steady state of f_in = 1 = e2/R10 + (e2 - e7)/R12, (e2 - e7)/R12 = e7/R20:
    e7 = 24/19, e2 = 44/19; F12 reads (e2 - e7)/R12 = 8/19 but for its noise."""
    sim = bgc.simulate(TANKS, "R12:abrupt:0.5@75", seed=3, process_noise=0.0)
    assert sim.truth == {"fault": "R12:abrupt", "hypothesis": "R12_abrupt", "target": "parameter", "magnitude": 0.5,
                         "onset": 75.0}
    assert sim.time[-1] == 150.0 and len(sim.time) == 300
    assert sim.states["e2"][-1] == pytest.approx(44 / 19, abs=1e-4)
    assert sim.states["e7"][-1] == pytest.approx(24 / 19, abs=1e-4)
    assert sim.parameters["R12"][sim.time < 75].max() == 2.0 and sim.parameters["R12"][-1] == 2.5
    tail = sim.measurements["F12"][sim.time > 120]
    assert abs(tail.mean() - 8 / 19) < 4 * tail.std() / math.sqrt(len(tail))


@pytest.mark.slow
def test_a_simulation_is_its_seed_and_goes_into_a_diagnosis_with_its_truth(tanks):
    a, b = (bgc.simulate(tanks, "R12:abrupt:0.5@75", seed=7, steps=200) for _ in range(2))
    c = bgc.simulate(tanks, "R12:abrupt:0.5@75", seed=8, steps=200)
    assert all(np.array_equal(a.measurements[y], b.measurements[y]) for y in a.measurements)
    assert not np.array_equal(a.measurements["F12"], c.measurements["F12"])
    r = bgc.diagnose(tanks, data=a, filter="ckf", seed=1)
    d = r.diagnosis
    assert r.injected == a.fault and r.scenario == "R12:abrupt:0.5@75" and d.estimate.truth == 0.5
    assert d.candidates == ("R12_abrupt",)
    # times in the model's unit: the onset is a time, onset_step its step of the grid
    assert d.onset == d.time[d.onset_step] == pytest.approx(75.0, abs=1.0)
    assert r.to_dict()["onset"] == d.onset and r.to_dict()["estimate_method"] == d.estimate.method == "kalman"


def test_a_simulation_written_reads_back_as_the_same_run(tanks, tmp_path):
    sim = bgc.simulate(tanks, "none", seed=2, steps=40)
    path = sim.write(tmp_path / "run.csv")
    run = tanks.read_run(path)
    assert np.array_equal(run.time, sim.time) and np.array_equal(run.measurements["F10"], sim.measurements["F10"])
    frame = pytest.importorskip("pandas").read_csv(path, comment="#")
    assert list(frame.columns) == list(sim.to_frame().columns) and frame["y:F10"].dtype == float


# ------------------------------------------------------------------ one vocabulary
def test_the_filter_has_one_name_and_the_old_one_warns(tanks):
    with pytest.warns(DeprecationWarning, match="method= is deprecated, its name is filter="):
        old = bgc.diagnose(tanks, scenario="none", steps=30, method="ckf", seed=1)
    assert old.diagnosis.options.filter == "ckf"
    with pytest.warns(DeprecationWarning, match=r"DiagnosisOptions\(method=...\) is deprecated"):
        assert bgc.DiagnosisOptions(method="apf").filter == "apf"
    with pytest.raises(ArgumentValueError, match="filter='ckf' and method='gpf' name one thing"):
        bgc.diagnose(tanks, scenario="none", filter="ckf", method="gpf")


def test_a_filter_that_cannot_identify_says_so(tanks):
    with pytest.raises(ArgumentValueError, match="has no particle filter of the magnitude to identify with"):
        bgc.diagnose(tanks, scenario="none", steps=30, filter="ckf", identify="filter")
    with pytest.raises(ArgumentValueError, match="identify='grid' is not one of kalman, filter"):
        bgc.diagnose(tanks, scenario="none", steps=30, identify="grid")


@pytest.mark.parametrize("call, text", [
    (lambda s: bgc.diagnose(s, scenario="Q9:abrupt:1@5"), "bgc.diagnose: scenario: 'Q9' is no parameter"),
    (lambda s: bgc.diagnose(s, scenario="R12:abrupt@5"), "bgc.diagnose: scenario 'R12:abrupt@5' is not NAME:KIND"),
    (lambda s: bgc.diagnose(s, scenario="R12:abrupt:0.5@100", steps=40), "or more steps)"),
    (lambda s: bgc.simulate(s, "R12:abrupt:0.5@500"), "bgc.simulate: scenario R12:abrupt:0.5@500: onset 500"),
    (lambda s: bgc.diagnose(s, scenario="none", options=bgc.DiagnosisOptions(particles=0)),
     "bgc.diagnose: options.particles=0"),
    (lambda s: bgc.distinguishability(s, steps=10_000_000), "bgc.distinguishability: steps: 10000000 steps"),
])
def test_errors_raised_in_python_name_the_argument_not_a_flag(tanks, call, text):
    with pytest.raises(bgc.Error) as info:
        call(tanks)
    line = str(info.value)
    assert text in line and "--" not in line, line


def test_the_errors_form_one_hierarchy():
    assert issubclass(ValidationError, ModelError) and issubclass(CausalityError, ModelError)
    assert issubclass(ModelError, bgc.Error) and issubclass(bgc.DataError, bgc.Error)
    assert issubclass(ArgumentValueError, ValueError) and issubclass(ArgumentTypeError, TypeError)
    assert bgc.ArgumentValueError is ArgumentValueError and bgc.Error is bgc.errors.BgcError
    with pytest.raises(ValueError):  # a malformed scenario from Python is a ValueError
        bgc.simulate(TANKS, "not a scenario")


def test_a_scenario_outside_the_prior_warns(tanks):
    with pytest.warns(bgc.ScenarioWarning, match="bias 50 is outside the prior of R12:abrupt"):
        bgc.simulate(tanks, "R12:abrupt:50@75", steps=200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bgc.simulate(tanks, "R12:abrupt:0.5@75", steps=200)  # inside: no warning


# ------------------------------------------------------------------ the model's parts
def test_the_equations_graphs_and_signatures_are_python_objects(tanks):
    import sympy

    eq = tanks.equations("sympy")
    e2, e7, R12, R20, C2 = sympy.symbols("e2 e7 R12 R20 C2")
    assert sympy.simplify(eq.derivatives["e7"] - ((e2 - e7) / R12 - e7 / R20) / C2) == 0  # by hand from the graph
    assert eq.parameters["R12"] == 2.0 and eq.inputs == ("f_in",)
    latex = tanks.equations("latex")
    assert latex.rstrip().endswith(r"\end{aligned}") and not latex.rstrip()[:-len(r"\end{aligned}")].rstrip()\
        .endswith("\\\\")
    assert "e7" in tanks.equations("text")
    tcg, dbn = tanks.tcg(), tanks.dbn("R12:abrupt")
    assert isinstance(tcg, nx.DiGraph) and isinstance(dbn, nx.DiGraph)
    tcg.add_node("mine")  # a copy: the session's graph is left as it was
    assert "mine" not in tanks.tcg()
    roles = dict(dbn.nodes(data="role"))
    assert roles["delta_R12@t+1"] == "fault_bias" and roles["D_R12@t"] == "fault_indicator"
    assert {n for n, role in roles.items() if role == "state"} == {"e2@t", "e2@t+1", "e7@t", "e7@t+1"}
    assert dbn.has_edge("delta_R12@t", "delta_R12@t+1")  # the bias persists from slice to slice
    assert tanks.dbns()[0] == "nominal" and "R12:abrupt" in tanks.dbns()
    # by the name a diagnosis gives the fault model, and a sensor's fault as the scenario names it
    assert tanks.dbn("R12_abrupt").nodes == dbn.nodes and tanks.dbn("F12:bias").nodes == tanks.dbn("F12_offset_bias").nodes
    assert bgc.simulate(tanks, "F12:bias:0.05@75", steps=200).truth["hypothesis"] == "F12_offset_bias"
    with pytest.raises(ArgumentValueError, match="give one of Session.dbns"):
        tanks.dbn("R99:abrupt")
    sig = tanks.signatures()
    row = next(r for r in sig if r["fault"] == "R12+:abrupt")
    # R12 up: less flow from tank 1 to tank 2 at once (F12 -), then P1 rises (F10 +) and P2 falls (F20 -)
    assert row["F12"][:2] == "-+" and row["F10"][1] == "+" and row["F20"][1] == "-" and row["first"] == ["F12"]


def test_a_diagnosis_comes_out_as_tables(tanks):
    sim = bgc.simulate(tanks, "R12:abrupt:0.5@75", seed=1, steps=200)
    r = bgc.diagnose(tanks, data=sim, filter="gpf", identify="filter", particles=150, seed=1)
    d = r.diagnosis
    hyps = r.table("hypotheses")
    assert len(hyps) == len(d.hypotheses) and {row["estimate_method"] for row in hyps} == {"filter"}
    best = next(row for row in hyps if row["model"] == d.candidates[0])
    assert best["candidate"] and best["onset"] == d.onset and best["estimate"] == d.estimate.value
    series = r.table("series")
    assert series.column("time") == list(d.time) and len(series.columns) == 1 + 3 * len(d.outputs)
    assert r.table("events").column("event")[-1] == "Decided"
    alarm = next(e for e in r.to_dict()["events"] if e["event"] == "Alarmed")  # an event's steps as times too
    assert alarm["onset"] == d.time[alarm["onset_step"]] and alarm["time"] == d.time[d.detection.step]
    assert "steps>" in repr(d) and len(repr(d)) < 300 and len(repr(d.hypotheses[0])) < 300
    pd = pytest.importorskip("pandas")
    frame = r.to_frame()
    assert isinstance(frame, pd.DataFrame) and frame["onset"].dtype == float and frame["candidate"].dtype == bool


# ------------------------------------------------------------------ the recipe
def _recipe():
    spec = importlib.util.spec_from_file_location("compare_filters", ROOT / "docs" / "examples" / "compare_filters.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_recipe_counts_a_nan_beside_the_mean():
    pd = pytest.importorskip("pandas")
    runs = pd.DataFrame([
        {"filter": "gpf", "right": True, "onset_error": 1.0, "size_error_pct": -2.0, "estimate_method": "filter"},
        {"filter": "gpf", "right": False, "onset_error": math.nan, "size_error_pct": math.nan,
         "estimate_method": None},
        {"filter": "ckf", "right": True, "onset_error": -3.0, "size_error_pct": 4.0, "estimate_method": "kalman"}])
    s = _recipe().summary(runs)
    assert s.loc["gpf", "runs"] == 2 and s.loc["gpf", "onset_nan"] == 1 and s.loc["gpf", "size_nan"] == 1
    assert s.loc["gpf", "mean_abs_onset_error"] == 1.0 and s.loc["ckf", "mean_abs_size_error_pct"] == 4.0


# The recipe's run itself (GPF, APF, OPF and CKF on their own estimates, the output as printed) is the slow
# transcript of docs/api.md, section 3 (tests/test_docs.py).


def test_bgc_filter_takes_filter_and_its_old_name_with_a_warning(capsys):
    from bgc.cli.main import build_parser

    new = build_parser().parse_args(["filter", "m.yaml", "r.csv", "--filter", "opf"])
    assert new.method == "opf" and capsys.readouterr().err == ""
    old = build_parser().parse_args(["filter", "m.yaml", "r.csv", "--method", "apf"])
    assert old.method == "apf" and "--method is deprecated, its name is --filter" in capsys.readouterr().err


def test_help_of_bgc_lists_the_public_api():
    import pydoc

    text = pydoc.render_doc(bgc, renderer=pydoc.plaintext)
    for name in ("open", "simulate", "diagnose", "distinguishability", "run_campaign", "Table", "DiagnosisOptions",
                 "Error", "ModelError", "DataError", "ArgumentValueError", "ScenarioWarning"):
        assert name in text, name
    for name in bgc.__all__:
        assert getattr(bgc, name) is not None  # every name bgc lists is given, none behind an underscore


@pytest.mark.slow
@pytest.mark.long
def test_a_campaigns_frame_has_the_columns_pandas_reads_from_its_runs_csv(tmp_path):
    pd = pytest.importorskip("pandas")
    # on the FAST backend (the rows do not depend on it but for the run time: docs/experiments.md), its
    # kernels compiled once per test run (conftest.numba_package)
    if FAST == "numba":
        numba_package("two_tank")
    result = bgc.run_campaign(ROOT / "docs" / "examples" / "campaign.yaml", tmp_path / "out", workers=1,
                              progress=False, backend=FAST)
    frame, read = result.to_frame(), pd.read_csv(tmp_path / "out" / "runs.csv")
    assert list(frame.columns) == list(read.columns) and {"mse_e2", "mse_e7"} <= set(frame.columns)
    assert frame["candidates"].tolist() == read["candidates"].str.split(" ").tolist()  # lists, not text
    for column in ("onset", "mse", "mse_e2", "estimate"):
        assert frame[column].dtype == read[column].dtype == float
    assert "2 rows" in repr(result) and len(repr(result)) < 200
