"""The input's timing, a choice the data can state (issue 48, point 5).

bgc reads a ``u:`` cell as the value held over the step that *ends* at the
row's time; many loggers write the value set *at* that time, acting until
the next row. The plant here is the circuit of models/circuit.yaml, its
source V a square wave (10 V and 12 V, 20 samples each), simulated by the
exact solution of its hand-derived equations (tests/test_mismatch.py) and
logged both ways: ``end`` (bgc's convention) and ``start`` (the logger's:
row k holds the value V takes from t_k on). f2 = (V - e4) / R1 reads the
source itself, so an input read one step off shows at once, at each change.
The slow tests run on the FAST backend (conftest.fast_session: numba when
installed; the diagnosis does not depend on it, tests/test_backend.py).
"""

import math

import numpy as np
import pytest

import bgc
from bgc.data import runs
from bgc.data.sampler import Sampler
from bgc.diagnosis import fit as fit_module
from bgc import events as ev
from bgc.errors import DataError

from conftest import bgc_cli, fast_session, session
from test_mismatch import DT, NOMINAL, START, circuit, readings

STEPS, HALF = 240, 20


def square(k: int) -> float:
    """The source over the step that ends at sample k (steps (k - 1) dt to k dt)."""
    return 10.0 if ((k - 1) // HALF) % 2 == 0 else 12.0


def square_csv(path, timing: str, seed: int = 1, header: bool = False, off: float = 0.0, noise: float = 1.0,
               steps: int = STEPS) -> None:
    """The circuit driven by :func:`square`, logged with inputs of
    ``timing``: ``end``, row k holds the value over the step that ends at it;
    ``start``, the value from t_k on (the next step's). Its parameters each
    off the model's by up to ``off`` (relative; drawn after the noise's
    seed), its noise ``noise`` times the model's; ``steps`` rows."""
    rng = np.random.default_rng(seed)
    p = {k: v * (1 + rng.uniform(-off, off)) for k, v in NOMINAL.items()} if off else NOMINAL
    e, process, sensor = circuit(p, noise)
    x = np.array(START)
    lines = (["# input timing: start"] if header else []) + ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, steps + 1):
        v = square(k)  # over the step that ends at t_k: the state moves under it, f2 reads it at t_k
        x = e[:3, :3] @ x + e[:3, 3] * v + process * rng.standard_normal(3)
        y = readings(p, x, v) + sensor * rng.standard_normal(3)
        logged = v if timing == "end" else square(k + 1)
        lines.append(",".join(f"{value:.6g}" for value in (k * DT, logged, *y)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_the_models_sensors_read_as_the_simulator_draws_them():
    nominal = session("circuit").package.MODELS["nominal"]
    assert set(nominal.OUTPUTS) == {"f2", "f6", "e11"} and set(nominal.STATES) == {"e4", "e8", "f10"}
    assert len(set(np.asarray(nominal.MEASUREMENT_STD, dtype=float).tolist())) == 1


# ------------------------------------------------------------ the sampler, by hand
def _sampler(timing: str) -> Sampler:
    nominal = session("circuit").package.MODELS["nominal"]
    return Sampler(nominal, ("V",), ("f2",), "rows.csv", None, timing)


def test_with_timing_start_a_rows_value_acts_from_the_next_step_on():
    """Rows at steps 0, 1, 2, 4 (step 3 a gap) with V = 11, 12, (empty), 14:
    read as ``end``, steps 0..4 get 11, 12, 12, 12, 14; as ``start`` each
    step gets the value set before it: the model's 10 at step 0, then 11,
    12, 12 (held), 12."""
    rows = [(0.05, 11.0), (0.10, 12.0), (0.15, math.nan), (0.25, 14.0)]
    got = {}
    for timing in ("end", "start"):
        s = _sampler(timing)
        samples = [x for t, v in rows for x in s.push(t, {"V": v}, {"f2": 1.0})]
        got[timing] = ([x.k for x in samples], [float(x.u[0]) for x in samples], samples)
    assert got["end"][:2] == ([0, 1, 2, 3, 4], [11.0, 12.0, 12.0, 12.0, 14.0])
    assert got["start"][:2] == ([0, 1, 2, 3, 4], [10.0, 11.0, 12.0, 12.0, 12.0])
    first, _, _, _, last = got["start"][2]
    assert ev.InputFromModel("V", "before-data", 0) in first.events
    held = [e for x in got["start"][2] for e in x.events if isinstance(e, ev.InputHeld)]
    assert held == [ev.InputHeld("V", 2, 12.0)]
    assert s.summary().timing == "start"


def test_reread_moves_the_datas_inputs_one_step_and_holds_the_edge():
    us = np.array([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]])
    assert fit_module.reread(us, [0], "start")[:, 0].tolist() == [1.0, 1.0, 2.0]
    assert fit_module.reread(us, [0], "end")[:, 0].tolist() == [2.0, 3.0, 3.0]
    assert fit_module.reread(us, [0], "end")[:, 1].tolist() == [5.0, 5.0, 5.0]  # a column not the data's


# ------------------------------------------------------------ stated by the header or the flag
def test_the_header_or_the_flag_states_it_and_they_may_not_disagree(tmp_path):
    assert runs.header_timing(("model circuit: x", "input timing: start"), "r.csv") == "start"
    assert runs.header_timing(("Input Timing: END",), "r.csv") == "end"
    assert runs.header_timing(("model circuit: x",), "r.csv") is None
    assert runs.resolve_timing((), None, "r.csv", "--input-timing") == "end"
    with pytest.raises(DataError, match=r"r.csv: its header line '# input timing: later'"):
        runs.header_timing(("input timing: later",), "r.csv")
    square_csv(tmp_path / "run.csv", "start", header=True)
    r = bgc_cli("diagnose", "models/circuit.yaml", "--data", tmp_path / "run.csv", "--input-timing", "end")
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "its header says 'input timing: start', and --input-timing says end" in r.stderr


@pytest.mark.slow
def test_a_loggers_timing_read_as_bgcs_is_a_mismatch_that_names_the_timing(tmp_path):
    """The start-timed log read as bgc's own: the residuals spike at every
    change of V. The verdict is "mismatch" saying the other timing, never a
    fault; read as it is logged (the flag, or the file's header), and the
    end-timed log read as bgc's: "no fault", the whole record fitting."""
    square_csv(tmp_path / "start.csv", "start")
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "start.csv", filter="ckf").diagnosis
    assert d.verdict == "mismatch", (d.verdict, d.candidates)
    said = [e for e in d.events if isinstance(e, ev.Mismatched)]
    assert len(said) == 1 and said[0].timing == "start" and said[0].timing_fits and said[0].timing_ratio > 100
    from bgc.output.events import sentence
    assert "--input-timing start" in sentence(said[0], d.time_of)
    for path, kwargs in ((tmp_path / "start.csv", {"options": bgc.DiagnosisOptions(input_timing="start")}),
                         (tmp_path / "header.csv", {}), (tmp_path / "end.csv", {})):
        if path.name == "header.csv":
            square_csv(path, "start", header=True)
        elif path.name == "end.csv":
            square_csv(path, "end")
        d = bgc.diagnose(fast_session("circuit"), path, **kwargs).diagnosis
        assert d.verdict == "no fault" and d.fit.fits, (path.name, d.verdict, d.fit.findings)
        assert d.data.timing == ("end" if path.name == "end.csv" else "start")


@pytest.mark.slow
def test_calibration_reads_the_inputs_as_the_flag_or_the_header_says(tmp_path):
    """bgc calibrate of the start-logged square wave: read as logged (the
    argument, or the file's header), f2's noise comes out at the simulator's
    own (its 95 % interval holds it); read as bgc's own timing, f2 takes the
    spikes at the changes of V as noise, several times the truth (0.43
    against 0.05). 120 rows, six changes of V: each calibration's
    likelihoods run over the rows (measured: 240 rows took 37 s against
    18 s, and narrowed the interval to 0.040 to 0.067 from 0.032 to 0.070,
    around the truth either way)."""
    square_csv(tmp_path / "start.csv", "start", seed=2, steps=120)
    square_csv(tmp_path / "header.csv", "start", seed=2, header=True, steps=120)
    s = fast_session("circuit")
    truth = float(np.asarray(s.package.MODELS["nominal"].MEASUREMENT_STD, dtype=float)[0])

    def f2(**kwargs):
        report = s.calibrate(kwargs.pop("path"), "measurement_noise", **kwargs)
        return next(e for e in report.calibration.estimates if e.subject == "f2")

    for e in (f2(path=tmp_path / "start.csv", input_timing="start"), f2(path=tmp_path / "header.csv")):
        assert e.low <= truth <= e.high, (e.low, truth, e.high)
    assert f2(path=tmp_path / "start.csv").value > 3 * truth
    with pytest.raises(DataError, match="its header says 'input timing: start', and input_timing says end"):
        s.calibrate(tmp_path / "header.csv", "measurement_noise", input_timing="end")
