"""Plots: text from outside (a model file's name) is drawn as it is, and two
models whose files share a name get a plot each; axes say what each
variable is and its unit, as the model file declares them (read here with
yaml); legends show what is drawn."""

import numpy as np
import pytest
import yaml

from bgc.kinds import DOMAINS
from bgc.output import plots
from bgc.output.labels import labels_of
from bgc.data import runs
from bgc.analysis import simulate as sim
from bgc.model import package as packages
from bgc.analysis import track

from conftest import MODELS, ROOT, compiled, fast_session


def test_campaign_plots_draw_any_model_file_name_and_keep_one_per_model():
    rows = [{"status": "ok", "model": model, "fault": "R1", "kind": "abrupt", "diagnosed": "R1_abrupt",
             "filter": "gpf", "est_error": 0.1, "ct": 2.0, "particles": 100, "noise": "model", "right": True}
            for model in ("a/$x.yaml", "b/$x.yaml", "c/100$ \\alpha$ ^{}.yaml", "d/../e\n.yaml")]
    out = plots.campaign_figures(rows)
    confusion = sorted(name for name in out if name.startswith("confusion_"))
    # $, space, backslash, ^, {, } and the newline each become _; the second $x gets -2
    assert confusion == ["confusion_100___alpha_____.png", "confusion__x-2.png", "confusion__x.png",
                         "confusion_e_.png"]
    assert all(data.startswith(b"\x89PNG") for data in out.values())


def test_a_run_with_a_measurement_at_the_edge_of_the_floats_is_drawn():
    from bgc.analysis.simulate import SimulationResult

    t = np.arange(1.0, 11.0)
    y = np.ones((10, 1))
    y[4, 0] = -1e308
    r = SimulationResult("m", "m.yaml", t, (), np.zeros((10, 0)), ("e3",), y, np.ones((10, 1)), ("q2",),
                         np.ones((10, 1)), None, None, ())
    assert plots.simulation_figure(r, "png").startswith(b"\x89PNG")


# ---------------------------------------------------------- labels and legends
def _text(label: str) -> str:
    """An axis label as one line (plots break long ones over lines)."""
    return " ".join(label.split())


def _state_of(doc: dict, element: str) -> str:
    """The state of storage element ``element``, read from the YAML: a C's effort, an I's flow."""
    bond = next(k for k, ends in doc["bonds"].items() if element in ends)
    return f"{'e' if doc['elements'][element]['kind'] == 'C' else 'f'}{bond}"


def _tracked(model: str, fault: str | None, name: str = "nominal", start: int | None = None):
    num = compiled(model).numerics
    options = sim.SimulationOptions(steps=60, seed=1, fault=sim.parse_fault(fault, num) if fault else None)
    run = runs.parse_run(sim.to_csv(sim.simulate(num, options)))
    package = packages.load_package(ROOT / "generated", model)
    return run, [track.track(run, package, name, m, 100, seed=0, start=start) for m in ("gpf", "apf")]


def test_the_ro_tracking_plot_names_state_e6_by_its_element_and_domain_and_legends_the_truth_and_dashes():
    doc = yaml.safe_load((MODELS / "ro.yaml").read_text())
    run, results = _tracked("ro", "R_pipe:incipient:0.5@20", "R_pipe_incipient", start=22)
    fig = plots.tracking_plot(run, results, labels_of(compiled("ro").model))
    ylabels = [_text(ax.get_ylabel()) for ax in fig.axes]
    state = _state_of(doc, "C_res")
    (label,) = [x for x in ylabels if x.startswith(f"{state}:")]
    assert label == f"{state}: {DOMAINS[doc['domain']].effort} at C_res"  # RO declares no units: no brackets
    assert not any("[" in x for x in ylabels[:len(doc["measurements"])])
    assert any(x.endswith(f"[per {doc['simulation']['time_unit']}]") for x in ylabels)  # the drift's slope
    assert fig.axes[-1].get_xlabel() == f"time [{doc['simulation']['time_unit']}]"
    legend = fig.axes[0].get_legend()
    texts = [t.get_text() for t in legend.get_texts()]
    assert any(t.startswith("true") for t in texts)
    styles = {t.get_text(): h.get_linestyle() for t, h in zip(legend.get_texts(), legend.legend_handles)
              if hasattr(h, "get_linestyle")}
    assert styles["GPF: state estimate"] == "--" and styles["GPF: predicted measurement"] == "-"
    # the estimated states are drawn dashed, as the legend says
    state_axis = fig.axes[ylabels.index(label)]
    assert "--" in {line.get_linestyle() for line in state_axis.get_lines()}


def test_a_model_with_units_labels_its_axes_with_them_and_one_without_shows_no_brackets():
    doc = yaml.safe_load((MODELS / "circuit.yaml").read_text())
    num = compiled("circuit").numerics
    options = sim.SimulationOptions(steps=40, seed=1)
    r = sim.simulate(num, options)
    fig = plots.simulation_plot(r, labels_of(compiled("circuit").model), sim.noise_free(num, options).clean_measurements)
    ylabels = [_text(ax.get_ylabel()) for ax in fig.axes]
    for name, spec in doc["measurements"].items():
        assert f"{name} [{spec['unit']}]" in ylabels
    for name, spec in doc["inputs"].items():
        assert f"{name} [{spec['unit']}]" in ylabels  # the run plot shows the input
    bare = [_text(ax.get_ylabel()) for ax in plots.simulation_plot(r).axes]
    assert bare == [*r.output_names, *r.input_names] and fig.axes[-1].get_xlabel() == "time [s]"
    assert plots.simulation_plot(r).axes[-1].get_xlabel() == "time"


def test_the_noise_free_line_of_a_run_carries_no_process_noise():
    num = compiled("two_tank").numerics
    options = sim.SimulationOptions(steps=80, seed=3, process_noise=0.05)
    r = sim.simulate(num, options)
    clean = sim.noise_free(num, options).clean_measurements
    again = sim.noise_free(num, sim.SimulationOptions(steps=80, seed=4, process_noise=0.05)).clean_measurements
    assert np.array_equal(clean, again)                       # no draw of any seed reaches it
    assert not np.allclose(clean, r.clean_measurements)        # the run's own states wander with process noise
    fig = plots.simulation_plot(r, noise_free=clean)
    line = next(ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "-")
    assert np.array_equal(line.get_ydata(), clean[:, 0])


@pytest.mark.slow
@pytest.mark.long
def test_the_hypotheses_legend_keeps_the_most_probable_and_groups_the_others(ro_report):
    d = ro_report.diagnosis
    fig = plots.diagnosis_hypotheses(ro_report)
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    shown, others = plots.ranked_hypotheses(d)
    assert len(d.hypotheses) > plots.SHOWN_HYPOTHESES and len(texts) <= plots.SHOWN_HYPOTHESES + 6
    best = max(d.hypotheses, key=lambda h: h.posterior)
    assert any(t.startswith(f"{best.name} (p = ") for t in texts)
    assert any(t.startswith(f"{len(d.hypotheses) - plots.SHOWN_HYPOTHESES} others") for t in texts)
    assert all(h.posterior >= o.posterior for h in shown for o in others)
    # every hypothesis is drawn: the grouped ones too (one line per sensor each, and an X where dropped)
    drawn = len(fig.axes[0].get_lines())
    assert drawn >= 1 + len(d.hypotheses) + sum(h.dropped_step is not None for h in d.hypotheses)


def test_the_distinguishability_map_has_a_colour_bar():
    import types

    rival = types.SimpleNamespace(name="B", probability=0.7)
    r = types.SimpleNamespace(model="m", distinctions=[types.SimpleNamespace(label="A", level=0.95, rivals=[rival])])
    fig = plots.distinguishability_plot(r)
    (bar,) = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert bar.get_ylabel().startswith("P(")
    assert plots.distinguishability_figure(r).startswith(b"\x89PNG")


@pytest.fixture(scope="module")
def ro_report():
    """The RO plant's R_pipe drifting from t = 165, on the compiled backend
    when numba is installed (the same diagnosis, tests/test_backend.py checks
    it; its tests are marked slow, as make check compiles no kernel)."""
    import bgc

    from bgc.diagnosis.options import DiagnosisOptions

    return bgc.diagnose(fast_session("ro"), scenario="R_pipe:incipient:0.5@165", seed=1,
                        options=DiagnosisOptions(seed=1, workers=1))


@pytest.mark.slow
def test_the_diagnosis_plots_and_tables_say_the_time_unit_and_the_magnitude_s_unit(ro_report):
    from bgc.output import report

    doc = yaml.safe_load((MODELS / "ro.yaml").read_text())
    per = f"per {doc['simulation']['time_unit']}"
    for name, fig in plots.diagnosis_plots(ro_report).items():
        assert fig.axes[-1].get_xlabel() == f"time [{doc['simulation']['time_unit']}]", name
    estimate = plots.diagnosis_estimate(ro_report)
    assert _text(estimate.axes[0].get_ylabel()) == f"slope of R_pipe [{per}]"
    row = report.hypothesis_rows(ro_report.diagnosis, ro_report.labels)[0]
    assert row[0] == "R_pipe_incipient" and row[3].startswith("slope ") and per in row[3] and row[4].endswith(per)
    assert report.plain_words(ro_report.diagnosis, ro_report.labels)[0].startswith("parameter R_pipe drifts up by")
    assert per in report.plain_words(ro_report.diagnosis, ro_report.labels)[0]


# ------------------------------------------------------- what reads over what
def _diagnosed(start: float):
    """A diagnosis report as the plots read it: one sensor, its samples from
    time ``start`` on, one hypothesis predicting it from sample 10."""
    import types

    from bgc.output.labels import Labels

    t = start + np.arange(50.0)
    y = np.sin(np.arange(50.0) / 8)[:, None]
    h = types.SimpleNamespace(name="R1_abrupt", posterior=0.9, dropped_step=None, start_step=10, y_mean=y[10:] + 0.1)
    d = types.SimpleNamespace(model="m", outputs=("y1",), time=t, hypotheses=[h], onset_step=10,
                              detection=types.SimpleNamespace(step=12))
    run = types.SimpleNamespace(time=t, measurements={"y1": y[:, 0]})
    return types.SimpleNamespace(diagnosis=d, run=run, labels=Labels("s"))


def test_the_hypotheses_predictions_are_drawn_over_the_measured_points():
    ax = plots.diagnosis_hypotheses(_diagnosed(0.0)).axes[0]
    measured = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
    predicted = [ln for ln in ax.get_lines() if ln.get_linestyle() == "-" and len(ln.get_xdata()) == 40]
    assert measured and predicted
    assert min(ln.get_zorder() for ln in predicted) > max(ln.get_zorder() for ln in measured)
    assert all(ln.get_alpha() is not None and ln.get_alpha() < 1 and ln.get_markersize() <= 2 for ln in measured)


@pytest.mark.parametrize("dropped", [3, 8, 25])
def test_a_hypothesis_dropped_before_or_after_its_filters_ran_is_marked_where_it_was_dropped(dropped):
    """The static test replays a fault model from an onset earlier than the
    onsets its filters tracked: its drop may fall before their first step
    (here they ran from step 10; step 3 and 8 are before it, 8 within the
    length of the prediction counted back from its end)."""
    r = _diagnosed(0.0)
    h = r.diagnosis.hypotheses[0]
    h.dropped_step = dropped
    ax = plots.diagnosis_hypotheses(r).axes[0]
    (cross,) = [ln for ln in ax.get_lines() if ln.get_marker() == "X"]
    assert cross.get_xdata()[0] == r.diagnosis.time[dropped]
    if dropped >= h.start_step:  # on its prediction
        assert cross.get_ydata()[0] == h.y_mean[dropped - h.start_step, 0]
    else:  # at the bottom of the axes: no prediction there
        assert cross.get_ydata()[0] == 0.0 and cross.get_transform() is not ax.transData


UNIX_START = 1764669600.0  # 2025-12-02 10:00:00 UTC


def _drawn(fig):
    """``fig`` drawn (tick labels and offset texts are made when it is)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    return fig


def _run(t: np.ndarray):
    from bgc.analysis.simulate import SimulationResult

    y = np.linspace(0.0, 1.0, len(t))[:, None]
    return SimulationResult("m", "m.yaml", t, (), np.zeros((len(t), 0)), ("e3",), y, y, ("q2",), y, None, None, ())


def test_a_run_in_unix_seconds_is_plotted_from_its_start_without_an_offset():
    from bgc.output.labels import Labels

    t = UNIX_START + np.arange(0.0, 600.0, 10.0)
    for fig in (plots.simulation_plot(_run(t), Labels("s")), plots.diagnosis_hypotheses(_diagnosed(UNIX_START))):
        _drawn(fig)
        assert fig.axes[-1].get_xlabel() == "time since 2025-12-02 10:00:00 UTC [s]"
        assert all(ax.xaxis.get_offset_text().get_text() == "" for ax in fig.axes)
        assert min(min(ln.get_xdata()) for ln in fig.axes[0].get_lines() if len(ln.get_xdata()) > 2) == 0.0
    # the same instant in minutes (an ISO time in a model counted in minutes is read so)
    minutes = plots.simulation_plot(_run(t / 60.0), Labels("min"))
    assert minutes.axes[-1].get_xlabel() == "time since 2025-12-02 10:00:00 UTC [min]"
    relative = _drawn(plots.simulation_plot(_run(t - UNIX_START), Labels("s")))
    assert relative.axes[-1].get_xlabel() == "time [s]"
    assert relative.axes[0].get_lines()[0].get_xdata()[-1] == 590.0


@pytest.mark.parametrize("first, absolute", [(0.0, False), (99_999_999.0, False), (1e8, True),
                                             (float("nan"), False)])
def test_which_times_are_absolute(first, absolute):
    from bgc.output.labels import Labels

    clock = plots.time_axis(np.array([first, first + 1.0]), Labels("s"))
    assert (clock.origin != 0.0) == absolute and ("since" in clock.label) == absolute
