"""Plots people would rather look at than numbers: runs, residuals, estimates.

A picture is drawn by one function, which returns the laid-out
:class:`matplotlib.figure.Figure` (:func:`new_figure`, :func:`laid_out`), and
saved by another (:func:`picture`): a report folder gets the PNG bytes, a
notebook the live figure (:meth:`bgc.api.DiagnosisReport.figures`). Figures
are plain matplotlib figures, not pyplot's: no backend is chosen and nothing
is left open."""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import printable
from ..kinds import fault_kind
from .artifacts import mark_picture

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _measured(ax, run, name: str) -> None:
    """Sensor ``name``'s samples as crosses (none for a sensor the data lack)."""
    if name in run.measurements:
        ax.plot(run.time, run.measurements[name], "x", ms=3, color="#c03030", label="measured")


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
    return fig


def picture(fig: Figure, fmt: str = "png") -> bytes:
    """The bytes of figure ``fig`` (:func:`laid_out`) as a ``png`` or ``svg``
    file, with bgc's mark and no date."""
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=100, metadata={"Software": None} if fmt == "png" else {"Date": None})
    return mark_picture(buf.getvalue(), fmt)


def simulation_figure(r, fmt: str = "png") -> bytes:
    """Measurements (noisy and clean) and, last, the faulty parameter, against time."""
    n = len(r.output_names) + (1 if r.fault else 0)
    fig, axes = new_figure(n)
    for j, name in enumerate(r.output_names):
        ax = axes[j]
        ax.plot(r.time, r.measurements[:, j], ".", ms=2.5, color="#c03030", label="measured")
        ax.plot(r.time, r.clean_measurements[:, j], "-", lw=1.0, color="#202020", label="noise-free")
        ax.set_ylabel(name)
        if r.fault:
            ax.axvline(r.fault.time, color="#808080", ls=":", lw=1)
    if r.fault:
        ax = axes[-1]
        ax.plot(r.time, r.parameter, color="#2060c0")
        ax.set_ylabel(r.fault.parameter)
    axes[0].legend(loc="best", fontsize=7)
    axes[0].set_title(f"{r.model}: simulated run ({r.fault.describe() if r.fault else 'no fault'})")
    axes[-1].set_xlabel("time")
    return picture(laid_out(fig), fmt)


def tracking_figure(run, results, fmt: str = "png") -> bytes:
    """Measurements with each filter's predicted measurement (mean +- 2 std), then
    the states (true and estimated), like the thesis's Figs. IV.4 and IV.6."""
    first = results[0]
    names_y = first.output_names
    names_x = [n for n in first.state_names]
    n = len(names_y) + len(names_x)
    fig, axes = new_figure(n, height_per_row=1.5)
    colors = ["#2060c0", "#20a040", "#c08020", "#8040c0"]
    for j, name in enumerate(names_y):
        ax = axes[j]
        _measured(ax, run, name)
        for r, c in zip(results, colors):
            ax.plot(r.time, r.y_mean[:, j], "-", lw=1.0, color=c, label=f"{r.method.upper()} {r.model}")
            ax.fill_between(r.time, r.y_mean[:, j] - 2 * r.y_std[:, j], r.y_mean[:, j] + 2 * r.y_std[:, j],
                            color=c, alpha=0.15, lw=0)
        ax.set_ylabel(name)
    for i, name in enumerate(names_x):
        ax = axes[len(names_y) + i]
        truth = run.states.get(name, run.parameters.get(name))
        if truth is None and first.fault and name == f"delta_{first.fault['parameter']}" \
                and first.fault["parameter"] in run.parameters:  # the magnitude: a bias, or a slope
            p = run.parameters[first.fault["parameter"]]
            truth = fault_kind(first.fault["kind"]).truth_series(run.time, p, p[0])
        if truth is not None:
            ax.plot(run.time, truth, "-", lw=1.0, color="#202020", label="true")
        for r, c in zip(results, colors):
            if name in r.state_names:
                k = r.state_names.index(name)
                ax.plot(r.time, r.mean[:, k], "--", lw=1.0, color=c)
                ax.fill_between(r.time, r.mean[:, k] - 2 * r.std[:, k], r.mean[:, k] + 2 * r.std[:, k],
                                color=c, alpha=0.15, lw=0)
        ax.set_ylabel(name)
    axes[0].legend(loc="best", fontsize=7)
    axes[0].set_title(f"{first.model}: filter estimates (bands: +-2 std)")
    axes[-1].set_xlabel("time")
    return picture(laid_out(fig), fmt)


# ------------------------------------------------------------------ diagnosis
_COLORS = ["#2060c0", "#20a040", "#c08020", "#8040c0", "#c04080", "#40a0a0"]


def _marks(ax, d) -> None:
    """Vertical marks: onset (dashed) and detection (solid)."""
    if d.onset is not None:
        ax.axvline(d.time[d.onset], color="#808080", ls="--", lw=0.9)
    if d.detection is not None:
        ax.axvline(d.time[d.detection.step], color="#c03030", ls="-", lw=0.9)


def diagnosis_measurements(r) -> Figure:
    """Measurements and the nominal observer's predicted measurements (mean +-
    2 std), onset and detection marked (thesis Fig. IV.4)."""
    d, run = r.diagnosis, r.run
    fig, axes = new_figure(len(d.outputs))
    for j, name in enumerate(d.outputs):
        ax = axes[j]
        _measured(ax, run, name)
        ax.plot(d.time, d.nominal_y_mean[:, j], "-", lw=1.0, color="#2060c0", label="nominal observer")
        ax.fill_between(d.time, d.nominal_y_mean[:, j] - 2 * d.nominal_y_std[:, j],
                        d.nominal_y_mean[:, j] + 2 * d.nominal_y_std[:, j], color="#2060c0", alpha=0.15, lw=0)
        _marks(ax, d)
        ax.set_ylabel(name)
    axes[0].legend(loc="best", fontsize=7)
    axes[0].set_title(f"{d.model}: measurements and the nominal observer (dashed: onset, red: detection)")
    axes[-1].set_xlabel("time")
    return laid_out(fig)


def diagnosis_residuals(r) -> Figure:
    """Each sensor's normalised residual and its largest windowed |Z|, with the
    detection threshold and mark."""
    d = r.diagnosis
    fig, axes = new_figure(len(d.outputs))
    for j, name in enumerate(d.outputs):
        ax = axes[j]
        ax.plot(d.time, d.nominal_z[:, j], ".", ms=2.5, color="#808080", label="normalised residual")
        ax.plot(d.time, d.statistics[:, j], "-", lw=1.0, color="#2060c0", label="largest windowed |Z|")
        ax.axhline(d.threshold, color="#c03030", ls=":", lw=1.0, label=f"threshold {d.threshold:.2f}")
        _marks(ax, d)
        ax.set_ylabel(name)
    axes[0].legend(loc="best", fontsize=7)
    per = "run" if d.options.horizon is None else f"{d.options.horizon:g} time units"
    axes[0].set_title(f"{d.model}: detection (false-alarm probability {d.options.false_alarm:g} per {per})")
    axes[-1].set_xlabel("time")
    return laid_out(fig)


def diagnosis_hypotheses(r) -> Figure:
    """Each hypothesis's predicted measurements against the data from its
    onset, a cross where it was dropped (thesis Fig. IV.6)."""
    d, run = r.diagnosis, r.run
    fig, axes = new_figure(len(d.outputs))
    for j, name in enumerate(d.outputs):
        ax = axes[j]
        _measured(ax, run, name)
        for h, c in zip(sorted(d.hypotheses, key=lambda h: -h.posterior), _COLORS * 4):
            t = d.time[h.start:]
            style = "-" if h.dropped is None else ":"
            ax.plot(t, h.y_mean[:, j], style, lw=1.0, color=c, label=f"{h.name} (p = {h.posterior:.2g})")
            if h.dropped is not None:
                ax.plot(d.time[h.dropped], h.y_mean[h.dropped - h.start, j], "X", color=c, ms=6)
        _marks(ax, d)
        ax.set_ylabel(name)
    if d.hypotheses:
        axes[0].legend(loc="best", fontsize=6)
    axes[0].set_title(f"{d.model}: fault hypotheses' predicted measurements (dotted: dropped, X: where)")
    axes[-1].set_xlabel("time")
    return laid_out(fig)


def diagnosis_estimate(r) -> Figure:
    """The fault magnitude of the diagnosed hypotheses over time, its interval
    and the truth when known (thesis Fig. IV.7)."""
    d, run = r.diagnosis, r.run
    shown = [h for h in d.hypotheses if h.name in d.candidates] or list(d.hypotheses[:1])
    fig, axes = new_figure(max(1, len(shown)), height_per_row=2.4)
    for ax, h, c in zip(axes, shown, _COLORS * 4):
        t = d.time[h.start:]
        e = h.estimate
        static = h.filter_estimate is not None  # the estimate is the static posterior's (or --refine's grid's)
        ax.plot(t, h.magnitude, "-", lw=1.2, color=c, label="particle filter" if static else "estimate")
        ax.fill_between(t, h.magnitude_band[:, 0], h.magnitude_band[:, 1], color=c, alpha=0.2, lw=0,
                        label=f"{100 * e.level:.0f} % interval" + (" (particle filter)" if static else ""))
        if static:
            span = d.time[h.onset:]
            ax.plot(span, np.full(len(span), e.value), "--", lw=1.4, color="#d62728",
                    label=("static posterior (Kalman filters)" if e.method == "kalman"
                           else "grid posterior (particle filters)") + ", from its onset")
            ax.fill_between(span, e.low, e.high, color="#d62728", alpha=0.15, lw=0,
                            label=f"its {100 * e.level:.0f} % interval")
        truth = run.parameters.get(h.parameter)
        if truth is not None and e.truth is not None:  # the run's fault is of this hypothesis's kind
            truth = fault_kind(h.kind).truth_series(run.time, truth, e.nominal)
            ax.plot(run.time, truth, "-", lw=1.0, color="#202020", label="truth")
        _marks(ax, d)
        ax.set_ylabel(f"{e.magnitude} of {h.parameter}")
        ax.legend(loc="best", fontsize=7)
    axes[0].set_title(f"{d.model}: fault magnitude" + (f" ({d.verdict})" if d.hypotheses else ": no fault"))
    axes[-1].set_xlabel("time")
    return laid_out(fig)


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


def diagnosis_figures(r) -> dict[str, bytes]:
    """Every diagnosis picture as PNG bytes, by file name."""
    return {name: picture(fig) for name, fig in diagnosis_plots(r).items()}


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
            ax.boxplot([d if d else [np.nan] for d in data], showfliers=True)
            ax.set_xticks(range(1, len(filters) + 1), [f.upper() for f in filters])
        ax.set_title(title, fontsize=9)
        ax.grid(True, alpha=0.3)
    out["distributions.png"] = picture(laid_out(fig), "png")
    for axis, label in (("particles", "particles"), ("noise", "noise level")):
        levels = list(dict.fromkeys(r[axis] for r in rows))
        if len(levels) < 2:
            continue
        fig, axes = new_grid(2)
        for f in filters:
            err = [np.mean(_values(rows, "est_error", filter=f, **{axis: x}) or [np.nan]) * 100 for x in levels]
            right = [np.mean(_values(rows, "right", filter=f, **{axis: x}) or [np.nan]) * 100 for x in levels]
            xs = levels if axis == "particles" else list(range(len(levels)))
            axes[0].plot(xs, err, "o-", label=f.upper())
            axes[1].plot(xs, right, "o-", label=f.upper())
        for ax, title in ((axes[0], "mean magnitude error (%)"), (axes[1], "right isolation (%)")):
            ax.set_title(title, fontsize=9)
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
    """A heat map of :class:`bgc.api.DistinguishabilityReport`: per fault
    (rows) and rival fault model (columns), the probability that the data name
    the fault over the rival; a cell under the level is outlined."""
    rows = [d.label for d in r.distinctions]
    cols = sorted({x.name for d in r.distinctions for x in d.rivals})
    m = np.full((len(rows), len(cols)), np.nan)
    for i, d in enumerate(r.distinctions):
        for x in d.rivals:
            m[i, cols.index(x.name)] = x.probability
    fig, ax = new_axes(max(4.0, 0.45 * len(cols) + 3), max(2.5, 0.35 * len(rows) + 2))
    ax.imshow(m, cmap="RdYlGn", vmin=0.5, vmax=1.0, aspect="auto")
    for i, d in enumerate(r.distinctions):
        for j in range(len(cols)):
            if np.isfinite(m[i, j]) and m[i, j] < d.level:
                ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=6)
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=7)
    ax.set_xlabel("rival fault model", fontsize=8)
    ax.set_ylabel("true fault", fontsize=8)
    ax.set_title(f"{r.model}: P(the data name the truth over the rival); numbers: under the level", fontsize=8)
    return picture(laid_out(fig), fmt)
