"""Plots people would rather look at than numbers: runs, residuals, estimates.

A picture is drawn by one function, which returns the laid-out
:class:`matplotlib.figure.Figure` (:func:`new_figure`, :func:`laid_out`), and
saved by another (:func:`picture`): a report folder gets the PNG bytes, a
notebook the live figure (:meth:`bgc.api.DiagnosisReport.figures`). Figures
are plain matplotlib figures, not pyplot's: no backend is chosen and nothing
is left open."""

from __future__ import annotations

import io
import re
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import printable
from ..kinds import fault_kind
from .artifacts import mark_picture
from ..data.clock import Clock
from .labels import Labels, with_unit

if TYPE_CHECKING:
    from matplotlib.figure import Figure


#: Okabe and Ito's colour-blind-safe palette (*Color Universal Design*, 2002):
#: every plot of bgc takes its colours from here.
OKABE_ITO = {"black": "#000000", "orange": "#E69F00", "sky blue": "#56B4E9", "bluish green": "#009E73",
             "yellow": "#F0E442", "blue": "#0072B2", "vermillion": "#D55E00", "reddish purple": "#CC79A7"}
#: Lines that need only differ (filters, hypotheses), in order (yellow is too pale on white).
CYCLE = tuple(OKABE_ITO[c] for c in ("blue", "orange", "bluish green", "reddish purple", "sky blue"))
MEASURED, TRUTH, DETECTION = OKABE_ITO["vermillion"], OKABE_ITO["black"], OKABE_ITO["vermillion"]
#: Marks and what is drawn for context only (the onset, the hypotheses grouped as others).
GREY, LIGHT_GREY = "#808080", "#b8b8b8"


@dataclass(frozen=True, slots=True)
class TimeAxis:
    """How a plot's time axis shows a run's times: as the time elapsed
    since ``origin`` (0: the times as they are), under ``label``."""

    origin: float
    label: str

    def __call__(self, t) -> np.ndarray:
        """Times ``t`` (one or an array) as the axis shows them."""
        return np.asarray(t, dtype=float) - self.origin


def time_axis(time, labels: Labels = Labels()) -> TimeAxis:
    """The time axis of a plot of ``time`` (in the model's time unit):
    when the times are absolute (:class:`~bgc.data.clock.Clock`, the rule
    messages and reports write them by), the time since the first sample,
    its date in the label: ``time since 2025-12-02 10:00:00 UTC [s]``; else
    the times as they are, ``time [s]``."""
    t = np.asarray(time, dtype=float).ravel()
    start = Clock.of(t, labels.time_unit).instant(t[0]) if t.size else None
    if start is not None:
        return TimeAxis(float(t[0]), with_unit(f"time since {start:%Y-%m-%d %H:%M:%S} UTC", labels.time_unit))
    return TimeAxis(0.0, labels.time)


def time_label(axes, clock: TimeAxis) -> None:
    """The time axis of ``axes`` (sharing it; the label under the last):
    ``clock``'s label, tick numbers written whole (never an offset such as
    ``+1.7646e9`` beside the axis)."""
    from matplotlib.ticker import ScalarFormatter

    for ax in axes:
        if isinstance(ax.xaxis.get_major_formatter(), ScalarFormatter):
            ax.xaxis.get_major_formatter().set_useOffset(False)
    axes[-1].set_xlabel(clock.label)


def _measured(ax, run, name: str, clock: TimeAxis, light: bool = False) -> None:
    """Sensor ``name``'s samples as crosses (none for a sensor the data
    lack), under the lines drawn over them; ``light``: small and pale, so
    that the lines over them read."""
    if name in run.measurements:
        style = {"ms": 2, "alpha": 0.45} if light else {"ms": 3}
        ax.plot(clock(run.time), run.measurements[name], "x", color=MEASURED, label="measured", zorder=1, **style)


def _ylabel(ax, text: str, width: int = 22) -> None:
    """An axis label that fits a row: small, broken over lines of about
    ``width`` characters, never inside a unit's brackets."""
    kept = re.sub(r"\[[^\]]*\]", lambda m: m.group(0).replace(" ", "\u00a0"), text)
    ax.set_ylabel("\n".join(textwrap.wrap(kept, width)), fontsize=8)


def _legend_above(ax, handles=None, ncol: int = 4) -> None:
    """The legend of a figure over its first axes, off the data (``handles``:
    what it shows; None: the axes' labelled lines)."""
    ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.02), ncol=ncol, fontsize=7, frameon=False,
              borderaxespad=0.0)


def _line(label: str, color: str, style: str = "-", marker: str | None = None, lw: float = 1.0):
    """A legend entry drawn as the traces it stands for."""
    from matplotlib.lines import Line2D

    return Line2D([], [], color=color, ls=style if marker is None else "none", marker=marker, ms=5, lw=lw,
                  label=label)


def _band(label: str, color: str):
    """A legend entry for a shaded band."""
    from matplotlib.patches import Patch

    return Patch(color=color, alpha=0.2, lw=0, label=label)


def new_figure(rows: int, width: float = 9.0, height_per_row: float = 1.7) -> tuple[Figure, np.ndarray]:
    """A figure of ``rows`` axes one above the other, sharing the time axis:
    (the figure, its axes). A plain :class:`matplotlib.figure.Figure`, not
    one of pyplot's: nothing global is touched (no backend chosen, no figure
    left open), and a notebook shows it only when it is asked to."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, max(2.5, height_per_row * rows)))
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)
    return fig, axes[:, 0]


def new_grid(cols: int, width: float = 9.0, height: float = 3.2) -> tuple[Figure, np.ndarray]:
    """A figure of ``cols`` axes side by side: (the figure, its axes)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    return fig, fig.subplots(1, cols, squeeze=False)[0]


def new_axes(width: float, height: float) -> tuple[Figure, object]:
    """A figure of one axes: (the figure, its axes)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    return fig, fig.subplots()


#: Axis limits are kept within this magnitude: matplotlib cannot lay out an
#: axis whose span overflows (a measurement of 1e308 in a run).
_AXIS_LIMIT = 1e300


def laid_out(fig: Figure) -> Figure:
    """``fig`` ready to show or save: its axis limits kept finite and within
    :data:`_AXIS_LIMIT`, its axes laid out tight."""
    for ax in fig.axes:
        for get, set_ in ((ax.get_xlim, ax.set_xlim), (ax.get_ylim, ax.set_ylim)):
            lo, hi = get()
            if not (np.isfinite(lo) and np.isfinite(hi) and max(abs(lo), abs(hi)) <= _AXIS_LIMIT):
                set_(float(np.clip(np.nan_to_num(lo), -_AXIS_LIMIT, _AXIS_LIMIT)),
                     float(np.clip(np.nan_to_num(hi), -_AXIS_LIMIT, _AXIS_LIMIT)))
    fig.tight_layout()
    # tight_layout leaves a placeholder layout engine behind, and a figure with any engine is drawn
    # twice by savefig (a dry draw "to make sure the layout works", then the real one): the layout is
    # done, so none is left (the same bytes, 18 % less time per picture, measured on a diagnosis's four),
    # whatever the user's rcParams would put in its place
    import matplotlib

    with matplotlib.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
        fig.set_layout_engine(None)
    return fig


def picture(fig: Figure, fmt: str = "png") -> bytes:
    """The bytes of figure ``fig`` (:func:`laid_out`) as a ``png`` or ``svg``
    file, with bgc's mark and no date."""
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=100, metadata={"Software": None} if fmt == "png" else {"Date": None})
    return mark_picture(buf.getvalue(), fmt)


def simulation_figure(r, fmt: str = "png", labels: Labels = Labels(), noise_free: np.ndarray | None = None,
                      modes: tuple | None = None) -> bytes:
    """:func:`simulation_plot` as ``png`` or ``svg`` bytes."""
    return picture(simulation_plot(r, labels, noise_free, modes), fmt)


def simulation_plot(r, labels: Labels = Labels(), noise_free: np.ndarray | None = None,
                    modes: tuple | None = None) -> Figure:
    """The measurements, noisy and noise-free, the inputs and, last, the
    faulty parameter, against time. ``noise_free``: the measurements of the
    same run without process or sensor noise
    (:func:`bgc.analysis.simulate.noise_free`); None: the run's own, without
    sensor noise only, and so labelled. ``modes``: a model with modes, (each
    sample's mode number, the modes' names): the mode timeline under the
    rest, and each mode's stretches shaded alike on every axis."""
    changed = r.fault is not None and r.parameter is not None  # (a stuck switch changes no parameter)
    rows = [*r.output_names, *r.input_names, *([r.fault.parameter] if changed else []),
            *(["mode"] if modes is not None else [])]
    fig, axes = new_figure(len(rows))
    clock = time_axis(r.time, labels)
    clean, said = ((noise_free, "noise-free (no process or sensor noise)") if noise_free is not None
                   else (r.clean_measurements, "without sensor noise"))
    for j, name in enumerate(r.output_names):
        axes[j].plot(clock(r.time), r.measurements[:, j], ".", ms=2.5, color=MEASURED, label="measured")
        axes[j].plot(clock(r.time), clean[:, j], "-", lw=1.0, color=TRUTH, label=said)
    for i, name in enumerate(r.input_names):
        axes[len(r.output_names) + i].plot(clock(r.time), r.inputs[:, i], "-", lw=1.2, color=CYCLE[2],
                                           drawstyle="steps-pre", label="input (as commanded)")
    if changed:
        axes[len(r.output_names) + len(r.input_names)].plot(clock(r.time), r.parameter, color=CYCLE[0],
                                                             label="faulty parameter")
    if modes is not None:
        _mode_timeline(axes, clock(r.time), *modes)
    for ax, name in zip(axes, rows):
        _ylabel(ax, "mode" if modes is not None and ax is axes[-1] else labels.axis(name))
        if r.fault:
            ax.axvline(clock(r.fault.time), color=GREY, ls=":", lw=1)
    handles = [_line("measured", MEASURED, marker="."), _line(said, TRUTH)]
    if r.input_names:
        handles.append(_line("input (as commanded)", CYCLE[2], lw=1.2))
    if r.fault:
        handles += [_line("faulty parameter", CYCLE[0])] if changed else []
        handles.append(_line("fault onset", GREY, ":"))
    _legend_above(axes[0], handles, ncol=len(handles))
    fig.suptitle(f"{r.model}: simulated run ({r.fault.describe() if r.fault else 'no fault'})", fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


def _mode_timeline(axes, clock: np.ndarray, numbers: np.ndarray, names: tuple[str, ...]) -> None:
    """The last axis: the mode at each sample as a step line, its ticks named;
    every axis: each mode's stretches shaded in one light colour."""
    numbers = np.asarray(numbers, dtype=float)
    axes[-1].plot(clock, numbers, drawstyle="steps-pre", color=CYCLE[3], lw=1.2)
    axes[-1].set_yticks(range(1, len(names) + 1), names, fontsize=7)
    axes[-1].set_ylim(0.5, len(names) + 0.5)
    edges = np.flatnonzero(np.diff(numbers)) + 1
    starts, stops = np.r_[0, edges], np.r_[edges, len(numbers)]
    step = clock[1] - clock[0] if len(clock) > 1 else 1.0
    for a, b in zip(starts, stops):
        if not np.isfinite(numbers[a]):
            continue
        colour = CYCLE[int(numbers[a] - 1) % len(CYCLE)]
        for ax in axes:
            ax.axvspan(clock[a] - step, clock[b - 1], color=colour, alpha=0.1, lw=0)


def _state_truth(run, first, name: str):
    """The run's truth of filter state ``name`` (a state, the faulty
    parameter, or the fault magnitude ``delta_<parameter>``), or None."""
    truth = run.states.get(name, run.parameters.get(name))
    fault = first.fault
    if truth is None and fault and name == f"delta_{fault['parameter']}" and fault["parameter"] in run.parameters:
        p = run.parameters[fault["parameter"]]  # the magnitude: a bias, or a slope
        truth = fault_kind(fault["kind"]).truth_series(run.time, p, p[0])
    return truth


def _state_axis(labels: Labels, first, name: str) -> str:
    """A filter state's axis label: a plant state by its meaning, a fault's
    parameter and magnitude in the unit of what fails."""
    fault = first.fault
    if not fault or name not in (fault["parameter"], f"delta_{fault['parameter']}"):
        return labels.axis(name)
    unit = fault.get("unit") or labels.unit(fault["parameter"])
    if name == fault["parameter"]:
        return with_unit(name, unit)
    kind = fault_kind(fault["kind"])
    return with_unit(f"{name}: {kind.magnitude} of {fault['parameter']}", labels.magnitude_unit(unit, kind.drifts))


def tracking_figure(run, results, fmt: str = "png", labels: Labels = Labels()) -> bytes:
    """:func:`tracking_plot` as ``png`` or ``svg`` bytes."""
    return picture(tracking_plot(run, results, labels), fmt)


def tracking_plot(run, results, labels: Labels = Labels()) -> Figure:
    """Measurements with each filter's predicted measurement (mean +- 2 std), then
    the states (true and estimated), like the thesis's Figs. IV.4 and IV.6."""
    first = results[0]
    names_y, names_x = first.output_names, first.state_names
    fig, axes = new_figure(len(names_y) + len(names_x), height_per_row=1.5)
    clock = time_axis(run.time, labels)
    for j, name in enumerate(names_y):
        _measured(axes[j], run, name, clock)
        for r, c in zip(results, CYCLE):
            _with_band(axes[j], clock(r.time), r.y_mean[:, j], r.y_std[:, j], c, "-")
        _ylabel(axes[j], labels.axis(name))
    truths = 0
    for i, name in enumerate(names_x):
        ax = axes[len(names_y) + i]
        truth = _state_truth(run, first, name)
        if truth is not None:
            ax.plot(clock(run.time), truth, "-", lw=1.0, color=TRUTH)
            truths += 1
        for r, c in zip(results, CYCLE):
            if name in r.state_names:
                k = r.state_names.index(name)
                _with_band(ax, clock(r.time), r.mean[:, k], r.std[:, k], c, "--")
        _ylabel(ax, _state_axis(labels, first, name))
    handles = [_line("measured", MEASURED, marker="x")]
    for r, c in zip(results, CYCLE):
        handles += [_line(f"{r.method.upper()}: predicted measurement", c),
                    _line(f"{r.method.upper()}: state estimate", c, "--"), _band(f"{r.method.upper()}: +-2 std", c)]
    if truths:
        handles.append(_line("true (the run's)", TRUTH))
    _legend_above(axes[0], handles, ncol=4)
    fig.suptitle(f"{first.model}: filter estimates", fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


def _with_band(ax, t, mean, std, color: str, style: str) -> None:
    """A mean as a line and its +-2 std as a band around it."""
    ax.plot(t, mean, style, lw=1.0, color=color)
    ax.fill_between(t, mean - 2 * std, mean + 2 * std, color=color, alpha=0.2, lw=0)


# ------------------------------------------------------------------ diagnosis
def _marks(ax, d, clock: TimeAxis) -> None:
    """Vertical marks: onset (dashed) and detection (solid)."""
    if d.onset_step is not None:
        ax.axvline(clock(d.time[d.onset_step]), color=GREY, ls="--", lw=0.9)
    if d.detection is not None:
        ax.axvline(clock(d.time[d.detection.step]), color=DETECTION, ls="-", lw=0.9)


def _mark_handles(d) -> list:
    """The legend entries of :func:`_marks`."""
    return ([_line("onset", GREY, "--")] if d.onset_step is not None else []) + \
        ([_line("detection", DETECTION)] if d.detection is not None else [])


def report_labels(r) -> Labels:
    """A diagnosis report's labels (a report made without them: none)."""
    return getattr(r, "labels", None) or Labels()


def diagnosis_measurements(r) -> Figure:
    """Measurements and the nominal observer's predicted measurements (mean +-
    2 std), onset and detection marked (thesis Fig. IV.4)."""
    d, run, labels = r.diagnosis, r.run, report_labels(r)
    modes = run.modes is not None and bool(labels.modes)  # a model with modes: its timeline under the sensors
    fig, axes = new_figure(len(d.outputs) + modes)
    clock = time_axis(d.time, labels)
    for j, name in enumerate(d.outputs):
        _measured(axes[j], run, name, clock)
        _with_band(axes[j], clock(d.time), d.nominal_y_mean[:, j], d.nominal_y_std[:, j], CYCLE[0], "-")
        _marks(axes[j], d, clock)
        _ylabel(axes[j], labels.axis(name))
    if modes:
        _mode_timeline(axes, clock(run.time), run.modes, labels.modes)
        _marks(axes[-1], d, clock)
        _ylabel(axes[-1], "mode")
    _legend_above(axes[0], [_line("measured", MEASURED, marker="x"), _line("nominal observer", CYCLE[0]),
                            _band("+-2 std", CYCLE[0]), *_mark_handles(d)], ncol=5)
    fig.suptitle(f"{d.model}: measurements and the nominal observer", fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


def diagnosis_residuals(r) -> Figure:
    """Each sensor's normalised residual and its largest windowed |Z|, with the
    detection threshold and mark."""
    d, labels = r.diagnosis, report_labels(r)
    fig, axes = new_figure(len(d.outputs))
    clock = time_axis(d.time, labels)
    for j, name in enumerate(d.outputs):
        ax = axes[j]
        ax.plot(clock(d.time), d.nominal_z[:, j], ".", ms=2.5, color=GREY)
        ax.plot(clock(d.time), d.statistics[:, j], "-", lw=1.0, color=CYCLE[0])
        ax.axhline(d.threshold, color=DETECTION, ls=":", lw=1.0)
        _marks(ax, d, clock)
        _ylabel(ax, f"{name} (normalised)")
    _legend_above(axes[0], [_line("normalised residual", GREY, marker="."), _line("largest windowed |Z|", CYCLE[0]),
                            _line(f"threshold {d.threshold:.2f}", DETECTION, ":"), *_mark_handles(d)], ncol=5)
    per = ("run" if d.options.horizon is None else
           f"{d.options.horizon:g} {labels.time_unit or 'time units'}")
    fig.suptitle(f"{d.model}: detection (false-alarm probability {d.options.false_alarm:g} per {per})", fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


#: The hypotheses plot draws this many fault models in colours of their own,
#: the most probable first; the others share one grey legend entry.
SHOWN_HYPOTHESES = 4


def ranked_hypotheses(d) -> tuple[list, list]:
    """The fault models of diagnosis ``d`` most probable first (among equals,
    the ones not dropped first), split into those drawn in colour
    (:data:`SHOWN_HYPOTHESES`) and the others."""
    ranked = sorted(d.hypotheses, key=lambda h: (-h.posterior, h.dropped_step is not None))
    return ranked[:SHOWN_HYPOTHESES], ranked[SHOWN_HYPOTHESES:]


def diagnosis_hypotheses(r) -> Figure:
    """Each hypothesis's predicted measurements against the data from its
    onset, a cross where it was dropped (thesis Fig. IV.6): the most probable
    in colour, the others in grey under one legend entry."""
    d, run, labels = r.diagnosis, r.run, report_labels(r)
    shown, others = ranked_hypotheses(d)
    fig, axes = new_figure(len(d.outputs))
    clock = time_axis(d.time, labels)
    for j, name in enumerate(d.outputs):
        _measured(axes[j], run, name, clock, light=True)
        for h in others:
            _hypothesis(axes[j], d, h, j, LIGHT_GREY, 0.7, clock)
        for h, c in zip(shown, CYCLE):
            _hypothesis(axes[j], d, h, j, c, 1.2, clock)
        _marks(axes[j], d, clock)
        _ylabel(axes[j], labels.axis(name))
    handles = [_line("measured", MEASURED, marker="x")]
    handles += [_line(f"{h.name} (p = {h.posterior:.3g}" + (", dropped)" if h.dropped_step is not None else ")"), c,
                      "-" if h.dropped_step is None else ":", lw=1.2) for h, c in zip(shown, CYCLE)]
    if others:
        top = max(h.posterior for h in others)
        handles.append(_line(f"{len(others)} others (p {'= 0' if top == 0 else f'<= {top:.2g}'}; "
                             f"{sum(h.dropped_step is not None for h in others)} dropped)", LIGHT_GREY, ":"))
    handles += [_line("where dropped (in its colour)", GREY, marker="X"), *_mark_handles(d)]
    _legend_above(axes[0], handles, ncol=3)
    fig.suptitle(f"{d.model}: fault hypotheses' predicted measurements (dotted: dropped)", fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


def _hypothesis(ax, d, h, j: int, color: str, lw: float, clock: TimeAxis) -> None:
    """Hypothesis ``h``'s prediction of sensor ``j`` from its onset, dotted
    when it was dropped, with an X where: on its prediction, or, dropped at a
    step its filters did not run (the static test replays a fault model
    from an onset earlier than those tracked), at the bottom of the axes."""
    ax.plot(clock(d.time[h.start_step:]), h.y_mean[:, j], "-" if h.dropped_step is None else ":", lw=lw, color=color,
            zorder=3)
    if h.dropped_step is not None:
        row = h.dropped_step - h.start_step
        if 0 <= row < len(h.y_mean):
            ax.plot(clock(d.time[h.dropped_step]), h.y_mean[row, j], "X", color=color, ms=5, zorder=3)
        else:
            ax.plot(clock(d.time[h.dropped_step]), 0.0, "X", color=color, ms=5, zorder=3,
                    transform=ax.get_xaxis_transform(), clip_on=False)


def diagnosis_estimate(r) -> Figure:
    """The fault magnitude of the diagnosed hypotheses over time, its interval
    and the truth when known (thesis Fig. IV.7)."""
    d, run, labels = r.diagnosis, r.run, report_labels(r)
    shown = [h for h in d.hypotheses if h.name in d.candidates] or list(d.hypotheses[:1])
    fig, axes = new_figure(max(1, len(shown)), height_per_row=2.4)
    clock = time_axis(d.time, labels)
    for ax, h in zip(axes, shown):
        e = h.estimate
        _estimate(ax, d, h, clock)
        truth = run.parameters.get(h.parameter)
        if truth is not None and e.truth is not None:  # the run's fault is of this hypothesis's kind
            ax.plot(clock(run.time), fault_kind(h.kind).truth_series(run.time, truth, e.nominal), "-", lw=1.0,
                    color=TRUTH, label="truth")
        _marks(ax, d, clock)
        _ylabel(ax, with_unit(f"{e.magnitude} of {h.parameter}",
                              labels.magnitude_unit(e.unit, fault_kind(h.kind).drifts)), width=30)
        ax.legend(handles=[*ax.get_legend_handles_labels()[0], *_mark_handles(d)], loc="center left",
                  bbox_to_anchor=(1.01, 0.5), fontsize=7, frameon=False)
    fig.suptitle(f"{d.model}: fault magnitude" + (f" ({d.verdict})" if d.hypotheses else ": no fault"), fontsize=10)
    time_label(axes, clock)
    return laid_out(fig)


def _estimate(ax, d, h, clock: TimeAxis) -> None:
    """Hypothesis ``h``'s magnitude: the particle filter's over time with its
    band and, when the estimate is the static posterior's (or ``--refine``'s
    grid's), that estimate and its interval from the onset; a fault that
    comes and goes, its magnitude while present times the probability that
    it is, per step, and its interval where it is."""
    e = h.estimate
    t = clock(d.time[h.start_step:])
    static = h.filter_estimate is not None
    level = f"{100 * e.level:.0f} %"
    ax.plot(t, h.magnitude, "-", lw=1.2, color=CYCLE[0], label="particle filter" if static else "estimate")
    ax.fill_between(t, h.magnitude_band[:, 0], h.magnitude_band[:, 1], color=CYCLE[0], alpha=0.2, lw=0,
                    label=f"{level} interval" + (" (particle filter)" if static else ""))
    i = h.intermittent
    if i is not None:  # a fault that comes and goes: its magnitude while present, times the probability it is
        present = np.asarray(i.present, dtype=float)
        on = present > 0.5
        ax.plot(clock(d.time), i.value * present, "--", lw=1.4, color=CYCLE[1],
                label="comes and goes: magnitude while\npresent x probability present")
        ax.fill_between(clock(d.time), np.where(on, i.low, np.nan), np.where(on, i.high, np.nan), color=CYCLE[1],
                        alpha=0.25, lw=0, label=f"its {level} interval while present")
    elif static:
        span = clock(d.time[h.onset_step:])
        ax.plot(span, np.full(len(span), e.value), "--", lw=1.4, color=CYCLE[1],
                label=("static posterior (Kalman filters)" if e.method == "kalman"
                       else "grid posterior (particle filters)") + ",\nfrom its onset")
        ax.fill_between(span, e.low, e.high, color=CYCLE[1], alpha=0.25, lw=0, label=f"its {level} interval")


#: The pictures of a diagnosis by file name, and the function that draws each.
DIAGNOSIS_PLOTS = {"measurements.png": diagnosis_measurements, "residuals.png": diagnosis_residuals,
                   "hypotheses.png": diagnosis_hypotheses, "estimate.png": diagnosis_estimate}


def diagnosis_plot_names(r) -> tuple[str, ...]:
    """The pictures diagnosis report ``r`` has: the measurements and the
    residuals, and the hypotheses and the estimate when a fault model was tried."""
    names = tuple(DIAGNOSIS_PLOTS)
    return names if r.diagnosis.hypotheses else names[:2]


def diagnosis_plots(r) -> dict[str, Figure]:
    """Every diagnosis picture as a live :class:`matplotlib.figure.Figure`,
    by the file name the report folder gives it."""
    return {name: DIAGNOSIS_PLOTS[name](r) for name in diagnosis_plot_names(r)}


#: The diagnosis report whose pictures forked processes draw (:func:`diagnosis_figures`): a child
#: inherits it from its parent instead of receiving the report, arrays and all, pickled.
_DRAWING: list = []


def _diagnosis_picture(name: str) -> bytes:
    return picture(DIAGNOSIS_PLOTS[name](_DRAWING[-1]))


def diagnosis_figures(r) -> dict[str, bytes]:
    """Every diagnosis picture as PNG bytes, by file name: drawn on the
    diagnosis's ``workers`` processes (forked once matplotlib is imported,
    each drawing whole pictures; the bytes do not depend on where a picture
    was drawn), in this process when there is one."""
    from ..diagnosis.options import processes
    from ..diagnosis.parallel import parallel_map

    names = diagnosis_plot_names(r)
    workers = processes(getattr(getattr(r, "options", None), "workers", 1))
    if workers > 1:
        import matplotlib.backends.backend_agg  # noqa: F401  (imported once, before the fork)
        import matplotlib.figure  # noqa: F401
    _DRAWING.append(r)
    try:
        return dict(zip(names, parallel_map(_diagnosis_picture, list(names), workers)))
    finally:
        _DRAWING.pop()


# ------------------------------------------------------------------ campaigns
def _values(rows, metric, **match) -> list[float]:
    out = []
    for r in rows:
        if r.get("status") != "ok" or any(r.get(k) != v for k, v in match.items()):
            continue
        v = r.get(metric)
        if v is not None and np.isfinite(v):
            out.append(float(v))
    return out


def _left_out(rows, metric: str, title: str) -> str:
    """``title``, saying how many finished runs' ``metric`` is NaN or infinite (not plotted, not in
    a mean: said, never dropped without a word)."""
    n = sum(1 for r in rows if r.get("status") == "ok" and r.get(metric) is not None
            and not np.isfinite(r[metric]))
    return title if not n else f"{title}; {n} run{'s' if n > 1 else ''} NaN or infinite, left out"


def campaign_figures(rows) -> dict[str, bytes]:
    """A campaign's plots (PNG): distributions of the estimation error and of
    the time to convergence per filter, accuracy against the particle count
    and the noise level (when the campaign varies them), and an isolation
    confusion matrix per model."""
    from .tables import confusion

    rows = list(rows)
    filters = [f for f in ("gpf", "apf", "opf", "ckf") if any(r["filter"] == f for r in rows)]
    out: dict[str, bytes] = {}
    fig, axes = new_grid(2)
    for ax, metric, title in ((axes[0], "est_error", "fault-magnitude error (%)"), (axes[1], "ct", "time to convergence")):
        data = [[100 * v if metric == "est_error" else v for v in _values(rows, metric, filter=f)] for f in filters]
        if any(data):
            ax.boxplot([d if d else [np.nan] for d in data], showfliers=True, medianprops={"color": CYCLE[1]})
            ax.set_xticks(range(1, len(filters) + 1), [f.upper() for f in filters])
        ax.set_title(_left_out(rows, metric, title), fontsize=9)
        ax.grid(True, alpha=0.3)
    out["distributions.png"] = picture(laid_out(fig), "png")
    for axis, label in (("particles", "particles"), ("noise", "noise level")):
        levels = list(dict.fromkeys(r[axis] for r in rows))
        if len(levels) < 2:
            continue
        fig, axes = new_grid(2)
        for f, c in zip(filters, CYCLE):
            err = [np.mean(_values(rows, "est_error", filter=f, **{axis: x}) or [np.nan]) * 100 for x in levels]
            right = [np.mean(_values(rows, "right", filter=f, **{axis: x}) or [np.nan]) * 100 for x in levels]
            xs = levels if axis == "particles" else list(range(len(levels)))
            axes[0].plot(xs, err, "o-", color=c, label=f.upper())
            axes[1].plot(xs, right, "o-", color=c, label=f.upper())
        for ax, metric, title in ((axes[0], "est_error", "mean magnitude error (%)"),
                                  (axes[1], "right", "right isolation (%)")):
            ax.set_title(_left_out(rows, metric, title), fontsize=9)
            ax.set_xlabel(label, fontsize=8)
            if axis == "particles":
                ax.set_xscale("log")
            else:
                ax.set_xticks(range(len(levels)), [str(x) for x in levels])
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
        out[f"accuracy_by_{axis}.png"] = picture(laid_out(fig), "png")
    names: set[str] = set()
    for model in dict.fromkeys(r["model"] for r in rows):
        truths, saids, counts = confusion(rows, model)
        if not truths:
            continue
        fig, ax = new_axes(max(4.0, 0.45 * len(saids) + 3), max(3.0, 0.35 * len(truths) + 2))
        m = np.array([[counts.get((t, s), 0) for s in saids] for t in truths], dtype=float)
        share = m / np.maximum(m.sum(axis=1, keepdims=True), 1)
        ax.imshow(share, cmap="Blues", vmin=0, vmax=1, aspect="auto")
        for i in range(len(truths)):
            for j in range(len(saids)):
                if m[i, j]:
                    ax.text(j, i, str(int(m[i, j])), ha="center", va="center", fontsize=7,
                            color="white" if share[i, j] > 0.6 else "black")
        ax.set_xticks(range(len(saids)), saids, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(truths)), truths, fontsize=7)
        ax.set_xlabel("diagnosed", fontsize=8)
        ax.set_ylabel("injected", fontsize=8)
        stem = Path(model).stem
        ax.set_title(f"isolation: {_literal(stem)}", fontsize=9)
        out[_unique(f"confusion_{_file_stem(stem)}", ".png", names)] = picture(laid_out(fig), "png")
    return out


def _literal(text: str) -> str:
    """Text from outside (a file's name) as matplotlib shows it literally: a
    ``$`` would start mathematics (and an unbalanced one fail to draw)."""
    return printable(text).replace("$", r"\$")


def _file_stem(text: str) -> str:
    """A file name's stem from outside, as letters, digits, ``_ . -`` only."""
    return "".join(ch if ch.isascii() and (ch.isalnum() or ch in "_.-") else "_" for ch in text)[:80] or "model"


def _unique(stem: str, suffix: str, taken: set[str]) -> str:
    """``stem + suffix``, or with ``-2``, ``-3``... when taken (two models'
    files with the same stem)."""
    name, n = stem + suffix, 1
    while name in taken:
        n += 1
        name = f"{stem}-{n}{suffix}"
    taken.add(name)
    return name


def distinguishability_figure(r, fmt: str = "png") -> bytes:
    """:func:`distinguishability_plot` as ``png`` or ``svg`` bytes."""
    return picture(distinguishability_plot(r), fmt)


def distinguishability_plot(r) -> Figure:
    """A heat map of :class:`bgc.api.DistinguishabilityReport`: per fault
    (rows) and rival fault model (columns), the probability that the data name
    the fault over the rival, on a colour bar; a cell under the level shows its number."""
    rows = [d.label for d in r.distinctions]
    cols = sorted({x.name for d in r.distinctions for x in d.rivals})
    m = np.full((len(rows), len(cols)), np.nan)
    for i, d in enumerate(r.distinctions):
        for x in d.rivals:
            m[i, cols.index(x.name)] = x.probability
    fig, ax = new_axes(max(4.0, 0.45 * len(cols) + 3), max(2.5, 0.35 * len(rows) + 2))
    image = ax.imshow(m, cmap="cividis", vmin=0.5, vmax=1.0, aspect="auto")
    fig.colorbar(image, ax=ax, fraction=0.05, pad=0.02).set_label("P(the data name the truth)", fontsize=7)
    for i, d in enumerate(r.distinctions):
        for j in range(len(cols)):
            if np.isfinite(m[i, j]) and m[i, j] < d.level:
                ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=6,
                        color="white" if m[i, j] < 0.75 else "black")  # cividis is dark at its low end
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=7)
    ax.set_xlabel("rival fault model", fontsize=8)
    ax.set_ylabel("true fault", fontsize=8)
    ax.set_title(f"{r.model}: P(the data name the truth over the rival); numbers: under the level", fontsize=8)
    return laid_out(fig)


def analysis_figure(r, fmt: str = "png") -> bytes:
    """:func:`analysis_plot` as ``png`` or ``svg`` bytes."""
    return picture(analysis_plot(r), fmt)


def analysis_plot(r) -> Figure:
    """``bgc analyse``'s isolability matrices side by side, one per level: a
    filled cell where the row's fault is told from the column's, the row of
    a fault the level does not detect grey."""
    n, k = len(r.faults), len(r.levels)
    fig, axes = new_grid(k, max(4.0, k * (0.28 * n + 1.6)), max(2.8, 0.28 * n + 1.8))
    for a, (lv, ax) in enumerate(zip(r.levels, axes)):
        m = np.array(lv.isolable, dtype=float).reshape(n, n)
        for i, d in enumerate(lv.detectable):
            if not d:
                m[i, :] = 0.5
        ax.imshow(m, cmap="Greys", vmin=0, vmax=1.4, aspect="equal")
        ax.set_xticks(range(n), r.faults, rotation=70, ha="right", fontsize=6)
        ax.set_yticks(range(n), r.faults if a == 0 else [""] * n, fontsize=6)
        ax.set_title(f"{lv.name}: {len(lv.pairs())} pairs told apart", fontsize=8)
    fig.suptitle(f"{r.model}: which fault (row) is told from which (column)", fontsize=8)
    return laid_out(fig)
