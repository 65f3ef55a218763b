"""Short HTML summaries for a notebook: what Jupyter shows for a diagnosis
report, a model session and a calibration report (their ``_repr_html_``).

Each is a piece of a page, not a page: the verdict in words first (with the
report page's colour for it), then the few lines a reader looks for and one
picture, embedded as a ``data:`` URI. The sentences are the report's own
(:mod:`bgc.output.report`, :mod:`bgc.output.calibration_report`,
:func:`bgc.output.render.prior_rows`) and the templates
(``bgc/templates/*_summary.html.j2``) escape every value, as the report page
does (:mod:`bgc.output.html`): a model file's path or a unit is shown as text
and cannot make markup or a script. The whole report is one call away
(``report.write(folder)``), and the summary says so.
"""

from __future__ import annotations

from . import calibration_report, html, plots, render, report

#: The verdict box's style by verdict (the report page's Okabe-Ito colours:
#: a coloured edge on a light ground; the headline says the same in words).
VERDICT_STYLES = {
    "isolated": "border-left: 0.5em solid #0072b2; background: #e8f2f9",
    "no fault": "border-left: 0.5em solid #009e73; background: #e6f5f0",
    "ambiguous": "border-left: 0.5em solid #e69f00; background: #fcf3e0",
    "unexplained": "border-left: 0.5em solid #d55e00; background: #fbebe1",
    "mismatch": "border-left: 0.5em solid #cc79a7; background: #f9eef4",
    "fits": "border-left: 0.5em solid #0072b2; background: #e8f2f9",
    "findings": "border-left: 0.5em solid #d55e00; background: #fbebe1",
}


def diagnosis_html(r) -> str:
    """A diagnosis report (:class:`bgc.api.DiagnosisReport`) in short: the
    model and the data, the verdict in words, the detection, the estimate
    with its interval, and the estimate's picture (the measurements' when no
    fault model was tried)."""
    d, labels = r.diagnosis, plots.report_labels(r)
    title, data_line, filter_line = report.heading(r)
    name = "estimate.png" if "estimate.png" in plots.diagnosis_plot_names(r) else "measurements.png"
    captions = {**report.DETECTION_PICTURES, **report.ESTIMATE_PICTURES}
    picture = html.Picture(name, captions[name], html.data_uri(plots.picture(plots.DIAGNOSIS_PLOTS[name](r))))
    return html.fragment(
        "diagnosis_summary.html.j2", title=title, data_line=data_line, filter_line=filter_line,
        style=VERDICT_STYLES[d.verdict], headline=report.verdict_text(d), words=report.plain_words(d, labels),
        detection=report.detection_lines(d, labels), no_detection=report.no_detection_text(d, labels),
        identification=report.identification_lines(d, labels), picture=picture)


def model_html(session) -> str:
    """A model session (:class:`bgc.api.Session`) in short: its name and
    file, elements, bonds and states, the sensors with their units and
    noise, the inputs, the parameters with their values and units, and the
    fault candidates with the priors of their magnitudes."""
    c = session.compiled
    m = c.model
    states = sorted(c.causal.states, key=lambda s: s.bond)
    process, measurement = session.noise
    noise = ("the model's noise levels" if session.noise == (None, None) else
             f"relative noise levels: process {'per model' if process is None else f'{process:g}'}, "
             f"measurement {'per model' if measurement is None else f'{measurement:g}'}")
    return html.fragment(
        "model_summary.html.j2", name=m.name, description=m.description, source=m.display_source,
        elements=f"{len(m.elements)} elements ({render.element_kinds_text(m)})", bonds=f"{len(m.bonds)} bonds",
        states=f"{len(states)} states" + (": " + ", ".join(f"{s.state} ({s.element})" for s in states)
                                          if states else ""),
        noise=noise,
        sensors=html.table(("sensor", "measures", "unit", "relative noise"),
                           [(y.name, y.text, y.unit or "-", f"{y.noise:g}") for y in m.measurements]),
        inputs=html.table(("input", "signal", "unit"),
                          [(u.name, u.signal.text, u.unit or "-") for u in m.inputs]),
        parameters=html.table(("parameter", "value", "unit", "description"),
                              [(p.name, f"{p.value:g}", p.unit or "-", p.description or "")
                               for p in m.parameters]),
        candidates=render.fault_candidates_text(m),
        faults=render.prior_rows(c.numerics))





def calibration_html(r) -> str:
    """A calibration report (:class:`bgc.api.CalibrationReport`) in short:
    whether the model fits the data (and the findings when not), the
    estimates with their intervals, and their picture."""
    c = r.calibration
    fits = not c.findings
    png = calibration_report.estimates_figure(r)
    picture = html.Picture("estimates.png", calibration_report.CAPTIONS["estimates.png"], html.data_uri(png))
    return html.fragment(
        "calibration_summary.html.j2", title=f"Calibration of {r.name}", model=r.model, samples=c.samples,
        sources=", ".join(c.sources), style=VERDICT_STYLES["fits" if fits else "findings"],
        verdict=calibration_report.verdict_line(fits),
        findings=list(c.findings),
        estimates=html.table(calibration_report.ESTIMATE_COLUMNS, calibration_report.estimate_rows(r)),
        picture=picture)
