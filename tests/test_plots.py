"""Plots: text from outside (a model file's name) is drawn as it is, and two
models whose files share a name get a plot each."""

from bgc.output import plots


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
    import numpy as np

    from bgc.runtime.simulate import SimulationResult

    t = np.arange(1.0, 11.0)
    y = np.ones((10, 1))
    y[4, 0] = -1e308
    r = SimulationResult("m", "m.yaml", t, (), np.zeros((10, 0)), ("e3",), y, np.ones((10, 1)), ("q2",),
                         np.ones((10, 1)), None, None, ())
    assert plots.simulation_figure(r, "png").startswith(b"\x89PNG")
