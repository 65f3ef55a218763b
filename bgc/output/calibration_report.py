"""The calibration report (``bgc calibrate --report DIR``): report.md and
report.html (one self-contained page) for people, report.json for programs,
and three pictures: the estimates against
the model file's values with their intervals, the calibrated model's
normalised residuals over time, and their autocorrelation with the band a
white series stays in."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from ..errors import printable
from ..analysis.calibrate import FIT_LEVEL, Z95, Calibration, Estimate
from ..filters.residuals import autocorrelations
from . import html
from .artifacts import manifest
from .markdown import escape
from .plots import OKABE_ITO, TimeAxis, laid_out, new_figure, picture, time_axis, time_label

#: The pictures of a calibration report.
PICTURES = ("estimates.png", "residuals.png", "autocorrelation.png")
#: Lags shown in the autocorrelation picture (fewer when the data are short).
ACF_LAGS = 40


def _num(v: float) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _unit(units: dict[str, str | None], e: Estimate) -> str | None:
    """A parameter's unit, or a sensor's (its noise std is in its reading's unit); none for the others."""
    return units.get(e.subject) if e.kind in ("parameter", "measurement_noise") else None


def report_data(r) -> dict[str, Any]:
    """``report.json``: the calibration as data (NaN and infinity as null)."""
    c: Calibration = r.calibration
    spread = dict(c.spread)
    return {
        "model": r.name, "model_file": r.model, "sources": list(c.sources), "samples": c.samples,
        "verdict": c.verdict, "findings": list(c.findings),
        "loglik": _num(c.loglik), "start_loglik": _num(c.start_loglik),
        "converged": c.converged, "message": c.message, "evaluations": c.evaluations,
        "seconds": round(c.seconds, 3),
        "estimates": [{"name": e.name, "kind": e.kind, "subject": e.subject, "unit": _unit(r.units, e),
                       "value": _num(e.value), "low": _num(e.low), "high": _num(e.high),
                       "level": _num(e.level), "level_low": _num(e.level_low), "level_high": _num(e.level_high),
                       "start": _num(e.start), "start_level": _num(e.start_level),
                       "identifiable": e.identifiable, "why": e.why, "at_bound": e.at_bound}
                      for e in c.estimates],
        "correlation": {"estimates": list(c.correlated), "matrix": [list(map(_num, row)) for row in c.correlation]},
        "innovations": [{"sensor": i.sensor, "samples": i.samples, "mean": _num(i.mean),
                         "correlation_time": _num(i.correlation_time), "variance": _num(i.variance),
                         "ljung_box": _num(i.ljung_box), "lags": i.lags,
                         "p_value": _num(i.p_value), "variance_but_one": _num(i.variance_but_one),
                         "residual_variance_sd": _num(spread[i.sensor]) if i.sensor in spread else None}
                        for i in c.innovations],
    }


def _g(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.6g}"


#: What the fit is tested for (the report's paragraph under its verdict).
FIT_TEXT = ("The calibrated model's normalised residuals (the nominal filter's innovations, each divided by its "
            "predicted std) are white noise of mean 0 and variance 1 when the model fits. Each sensor is tested "
            "for a mean off 0, a variance off 1 and correlation over time (Ljung-Box), the tests sharing a "
            f"false-finding probability of {FIT_LEVEL:g}.")
INNOVATION_COLUMNS = ("sensor", "samples", "mean", "variance", "Ljung-Box Q", "lags", "p-value")
#: What the estimates' table holds (the report's paragraph over it; Markdown: ``*model file*``, ``noise`` in code).
ESTIMATES_TEXT = ("Maximum-likelihood estimates with 95 % intervals (where the log-likelihood has fallen by 1.92 "
                  "from its maximum). {model_file} is what the file holds: a sensor's relative {noise} level, the "
                  "process level, a parameter's value; the std of a sensor's noise is in the sensor's unit.")
ESTIMATE_COLUMNS = ("estimate", "was", "model file", "95 % interval", "std / value", "95 % interval", "note")
CORRELATION_TEXT = ("From the curvature of the log-likelihood at its maximum; near +-1, the data tell only a "
                    "combination of the two.")
#: The pictures and what each shows.
CAPTIONS = {"residuals.png": "normalised residuals", "autocorrelation.png": "autocorrelation",
            "estimates.png": "estimates"}


def innovation_rows(c: Calibration, quote=str) -> list[tuple[str, ...]]:
    """Per sensor, the tests of its normalised residuals (:data:`INNOVATION_COLUMNS`)."""
    return [(quote(i.sensor), str(i.samples), f"{i.mean:+.3f}", f"{i.variance:.3f}", f"{i.ljung_box:.1f}",
             str(i.lags), f"{i.p_value:.3g}") for i in c.innovations]


def estimate_rows(r, quote=str) -> list[tuple[str, ...]]:
    """Per estimate, the model file's value, the estimate and its intervals (:data:`ESTIMATE_COLUMNS`)."""
    rows = []
    for e in r.calibration.estimates:
        unit = _unit(r.units, e)
        u = f" {quote(unit)}" if unit else ""
        if not e.identifiable:
            rows.append((quote(e.name), _g(e.start_level), "kept", "", "", "",
                         f"not identifiable: {quote(e.why or '')}"))
            continue
        note = ("the data show none" if e.value == 0 else "at the end of the range searched") if e.at_bound else ""
        rows.append((quote(e.name), _g(e.start_level), _g(e.level), f"[{_g(e.level_low)}, {_g(e.level_high)}]",
                     f"{_g(e.value)}{u}", f"[{_g(e.low)}, {_g(e.high)}]{u}", note))
    return rows


def likelihood_lines(c: Calibration, quote=str) -> list[str]:
    """The log-likelihood before and after, and how the optimiser went."""
    gain = c.loglik - c.start_loglik
    return [f"log-likelihood of the data at the model file's values: {c.start_loglik:.6g}",
            f"at the estimates: {c.loglik:.6g} (higher by {gain:.4g}; twice that is the likelihood-ratio "
            f"statistic of the model file's values, chi-square with {len(c.correlated)} degrees of freedom "
            "when they are right)",
            f"optimiser: {'converged' if c.converged else 'did not converge'} ({quote(c.message)}), "
            f"{c.evaluations} likelihood evaluations, {c.seconds:.1f} s"]


def _md_row(cells) -> str:
    return "| " + " | ".join(cells) + " |"


def report_markdown(r) -> str:
    """``report.md``: what was estimated, how sure, and whether the model fits."""
    c: Calibration = r.calibration
    sources = ", ".join(escape(s) for s in c.sources)
    lines = [f"# Calibration of {escape(r.name)}", "",
             f"Model file `{escape(r.model)}`, {c.samples} samples of {sources}. "
             f"The calibrated model is the model file with the estimates below in place.", "",
             "## Does the model fit this data?", "", f"**{escape(c.verdict[0].upper() + c.verdict[1:])}.**", "",
             FIT_TEXT, "", _md_row(INNOVATION_COLUMNS), "|---|---|---|---|---|---|---|"]
    lines += [_md_row(row) for row in innovation_rows(c, escape)]
    lines += ["", "![normalised residuals](residuals.png)", "", "![autocorrelation](autocorrelation.png)", "",
              "## Estimates", "", ESTIMATES_TEXT.format(model_file="*model file*", noise="`noise`"), "",
              _md_row(ESTIMATE_COLUMNS), "|---|---|---|---|---|---|---|"]
    lines += [_md_row(row) for row in estimate_rows(r, escape)]
    lines += ["", "![estimates](estimates.png)", ""]
    if len(c.correlated) > 1:
        lines += ["## Correlation of the estimates", "", CORRELATION_TEXT, "",
                  "| | " + " | ".join(escape(n) for n in c.correlated) + " |",
                  "|---|" + "---|" * len(c.correlated)]
        for name, row in zip(c.correlated, c.correlation):
            lines.append(f"| {escape(name)} | " + " | ".join(f"{v:+.3f}" for v in row) + " |")
        lines.append("")
    lines += ["## The likelihood", ""] + [f"- {line}" for line in likelihood_lines(c, escape)] + [""]
    return "\n".join(lines)


def verdict_line(fits: bool) -> str:
    """The headline of a calibration: whether the model explains the data."""
    return "The model explains this data." if fits else "The model does not explain this data:"


def report_html(r, data: dict[str, Any], pictures: dict[str, bytes]) -> str:
    """``report.html``: report.md's sections as one self-contained page,
    from ``data`` (:func:`report_data`) and the same rows, with
    ``pictures`` embedded (:mod:`bgc.output.html`)."""
    c: Calibration = r.calibration
    fits = not data["findings"]
    return html.page(
        "calibration.html.j2", r.model, title=f"Calibration of {r.name}", name=r.name, model=r.model,
        samples=c.samples, sources=", ".join(c.sources),
        verdict=verdict_line(fits), verdict_class="v-fits" if fits else "v-findings",
        findings=data["findings"], fit_text=FIT_TEXT,
        innovations=html.table(INNOVATION_COLUMNS, innovation_rows(c)),
        estimates_text=ESTIMATES_TEXT.format(model_file="\u201cmodel file\u201d", noise="noise"),
        estimates=html.table(ESTIMATE_COLUMNS, estimate_rows(r)),
        correlation_text=CORRELATION_TEXT,
        correlation=html.table(("", *c.correlated), [(n, *(f"{v:+.3f}" for v in row))
                                                     for n, row in zip(c.correlated, c.correlation)])
        if len(c.correlated) > 1 else None,
        likelihood=likelihood_lines(c), pictures={p.name: p for p in html.pictures(pictures, CAPTIONS)})


def estimates_figure(r, fmt: str = "png") -> bytes:
    """Each identifiable estimate over the model file's value (log scale), with its 95 % interval."""
    c: Calibration = r.calibration
    shown = [e for e in c.estimates if e.identifiable and e.kind != "initial"]  # a state may be 0 or negative
    fig, axes = new_figure(1, width=8.0, height_per_row=max(2.5, 0.45 * len(shown) + 1.2))
    ax = axes[0]
    for y, e in enumerate(shown):
        ref = e.start_level if e.start_level not in (0, None) and math.isfinite(e.start_level) else None
        if ref is None:
            continue
        v, lo, hi = e.level / ref, e.level_low / ref, e.level_high / ref
        lo = lo if math.isfinite(lo) and lo > 0 else v / 1e3
        ax.errorbar([v], [y], xerr=[[v - lo], [max(hi - v, 0) if math.isfinite(hi) else v]], fmt="o",
                    color=OKABE_ITO["blue"], capsize=4, label="estimate, 95 % interval" if y == 0 else None)
    ax.axvline(1.0, color="#555555", ls="--", lw=1, label="model file's value")
    ax.set_xscale("log")
    ax.set_yticks(range(len(shown)))
    ax.set_yticklabels([printable(e.name) for e in shown])
    ax.set_ylim(-0.7, len(shown) - 0.3)
    ax.invert_yaxis()
    ax.set_xlabel("estimate / the model file's value")
    ax.set_title(printable(f"{r.name}: calibrated values"))
    ax.legend(loc="best", fontsize=8)
    return picture(laid_out(fig), fmt)


def residuals_figure(r, fmt: str = "png") -> bytes:
    """Each sensor's normalised residuals over time, with the band N(0, 1) stays in 95 % of the time."""
    c: Calibration = r.calibration
    sensors = [i.sensor for i in c.innovations]
    fig, axes = new_figure(max(1, len(sensors)))
    clock = time_axis(sorted(t[0] for t in c.times if len(t)))
    clock = TimeAxis(clock.origin, f"{clock.label} (the data's time column)")
    for ax, name in zip(axes, sensors):
        j = c.outputs.index(name)
        for k, (t, z) in enumerate(zip(c.times, c.residuals)):
            ax.plot(clock(t), z[:, j], ".", ms=2, color=OKABE_ITO["blue"], label="normalised residual" if k == 0 else None)
        ax.axhline(Z95, color=OKABE_ITO["vermillion"], ls="--", lw=1, label="+-1.96 (95 % of N(0, 1))")
        ax.axhline(-Z95, color=OKABE_ITO["vermillion"], ls="--", lw=1)
        ax.axhline(0, color="#555555", lw=0.6)
        ax.set_ylabel(printable(name))
    axes[0].legend(loc="upper right", fontsize=7)
    axes[0].set_title(printable(f"{r.name}: the calibrated model's normalised residuals"))
    time_label(axes, clock)
    return picture(laid_out(fig), fmt)


def autocorrelation(c: Calibration, j: int, lags: int) -> np.ndarray:
    """The residuals' autocorrelation of sensor column ``j`` at lags 1 ..
    ``lags``, as the Ljung-Box statistic takes it (:func:`autocorrelations`)."""
    return autocorrelations([z[:, j] for z in c.residuals], lags)[0]


def autocorrelation_figure(r, fmt: str = "png") -> bytes:
    """Each sensor's residual autocorrelation, with the band a white series stays in (+-1.96 / sqrt(n))."""
    c: Calibration = r.calibration
    fig, axes = new_figure(max(1, len(c.innovations)))
    for ax, i in zip(axes, c.innovations):
        lags = int(max(1, min(ACF_LAGS, i.samples // 5)))
        rho = autocorrelation(c, c.outputs.index(i.sensor), lags)
        ax.vlines(np.arange(1, lags + 1), 0, rho, color=OKABE_ITO["blue"], lw=2, label="autocorrelation")
        band = Z95 / math.sqrt(i.samples)
        ax.axhspan(-band, band, color="#999999", alpha=0.3, label="95 % band of white noise")
        ax.axhline(0, color="#555555", lw=0.6)
        ax.set_ylabel(printable(i.sensor))
        ax.text(0.99, 0.92, f"Ljung-Box p = {i.p_value:.3g} ({i.lags} lags)", transform=ax.transAxes, ha="right",
                va="top", fontsize=8)
    axes[0].legend(loc="upper center", fontsize=7, ncol=2)
    axes[0].set_title(printable(f"{r.name}: autocorrelation of the normalised residuals"))
    axes[-1].set_xlabel("lag (samples)")
    return picture(laid_out(fig), fmt)


def report_files(r) -> dict[str, str | bytes]:
    """Every file of the report folder, the manifest last."""
    data = report_data(r)
    pictures = {"estimates.png": estimates_figure(r), "residuals.png": residuals_figure(r),
                "autocorrelation.png": autocorrelation_figure(r)}
    files: dict[str, str | bytes] = {
        "report.json": json.dumps(data, indent=2, sort_keys=True) + "\n",
        "report.md": report_markdown(r),
        "report.html": report_html(r, data, pictures),
        **pictures,
    }
    files["manifest.json"] = manifest(files, "calibrate", model=r.name)
    return files
