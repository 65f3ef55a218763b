"""A campaign's tables: the ones its file asks for (shaped like the thesis's
Tables IV.2 to IV.4, with published numbers beside ours), a summary per group,
filter, noise level and particle count, and an isolation confusion matrix per
model. Rows are the dicts of :mod:`bgc.experiment.campaign` (``runs.csv``).

Every free-text value that reaches ``tables.md`` (the campaign's name and
description, table titles, sources, scenarios, model paths, group and noise
names, failure messages) passes through :func:`bgc.output.markdown.escape`:
one line, and no Markdown of its own (a heading, a table cell's bound, a
link, HTML, emphasis).

A mean never leaves a run out without a word: a run whose metric came out
NaN (a filter that diverged) is counted, and its cell says so beside the
mean of the others (:func:`format_cell`).

>>> rows = [{"filter": "gpf", "status": "ok", "scenario": "none", "rt": 1.0, "right": None},
...         {"filter": "gpf", "status": "ok", "scenario": "none", "rt": 3.0, "right": None}]
>>> cell(rows, "rt")
Cell(mean=2.0, sd=1.4142135623730951, n=2, nan=0)
>>> format_cell(cell(rows + [{"status": "ok", "rt": float("nan")}], "rt"), "rt")
'2 (1.414; n=2, 1 NaN)'
"""

from __future__ import annotations

import math
from typing import Any, Iterable, NamedTuple

from ..analysis.distinguish import FALSE_ALARM, LEVEL, ideal_power
from . import html, render
from .markdown import comment as _comment
from .markdown import escape

#: Metrics shown as a percentage of the runs where they are defined.
RATES = ("detected", "false_alarm", "right", "covers")
#: Metrics that are relative errors, shown in percent.
PERCENT = ("est_error", "param_error")
HEAD = {"rt": "RT s", "mse": "MSE", "nmse": "NMSE %", "ct": "CT", "delay": "delay", "detected": "detected",
        "false_alarm": "false alarm", "right": "right", "estimate": "estimate", "est_error": "magnitude error %",
        "parameter": "parameter", "param_error": "parameter error %", "covers": "95 % covers"}


def _ok(rows: Iterable[dict]) -> list[dict]:
    return [r for r in rows if r.get("status") == "ok"]


class Cell(NamedTuple):
    """A table's cell: the ``mean`` and sample ``sd`` of a metric over the
    ``n`` finished runs where it is a number, and ``nan``: the runs where it
    was computed and came out NaN (counted, not in the mean: the cell says
    how many). A rate's mean is the fraction true (sd 0)."""

    mean: float
    sd: float
    n: int
    nan: int = 0


def _is_nan(v: Any) -> bool:
    return isinstance(v, float) and math.isnan(v)


def cell(rows: list[dict], metric: str) -> Cell | None:
    """The :class:`Cell` of ``metric`` over the finished rows where it is
    defined (not None); None when it is defined in none. Its runs whose
    value is NaN are counted in ``nan``, the mean and sd are those of the
    others (NaN when there are none)."""
    defined = [v for v in (r.get(metric) for r in _ok(rows)) if v is not None]
    values = [v for v in defined if not _is_nan(v)]
    nan = len(defined) - len(values)
    if not defined:
        return None
    if not values:
        return Cell(math.nan, math.nan, 0, nan)
    if metric in RATES:
        return Cell(sum(bool(v) for v in values) / len(values), 0.0, len(values), nan)
    n = len(values)
    mean = sum(values) / n
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else 0.0
    return Cell(mean, sd, n, nan)


def _fmt(x: float) -> str:
    if x == 0 or 1e-3 <= abs(x) < 1e5:
        return f"{x:.4g}" if abs(x) < 100 else f"{x:.1f}"
    return f"{x:.3g}"


def format_cell(c: Cell | None, metric: str) -> str:
    """A cell as text: ``mean (sd)``, a rate ``k/n``, ``–`` where the metric
    is defined in no run. Runs whose value is NaN are said after it:
    ``0.000511 (0; n=4, 1 NaN)`` is the mean and sd of 4 runs, and 1 more
    run whose value is NaN; ``NaN (n=0, 2 NaN)``: every one was."""
    if c is None:
        return "–"
    mean, sd, n, nan = c
    if n == 0:
        return f"NaN (n=0, {nan} NaN)"
    if metric in RATES:
        text = f"{round(mean * n)}/{n}"
        return text + (f" ({nan} NaN)" if nan else "")
    scale = 100 if metric in PERCENT or metric == "nmse" else 1
    return f"{_fmt(scale * mean)} ({_fmt(scale * sd)}" + (f"; n={n}, {nan} NaN)" if nan else ")")


def cell_json(c: Cell | None) -> dict[str, Any] | None:
    """A cell in ``summary.json``: its mean, sd, n and the runs whose value is NaN (mean and sd null
    when every one was)."""
    if c is None:
        return None
    return {"mean": c.mean if c.n else None, "sd": c.sd if c.n else None, "n": c.n, "nan": c.nan}


def row_label(row: dict, rows: str) -> str:
    """The label of a run in a table whose rows are ``rows``."""
    if rows == "fault":
        return "none" if not row.get("fault") else f"{row['fault']}:{row['kind']}"
    if rows == "particles":
        return str(row["particles"])
    if rows == "refine":
        return "grid" if row.get("refine") else "filter"
    return str(row[rows])


def table_groups(spec, rows: list[dict]) -> tuple[list[dict], list[str], dict[tuple[str, str], list[dict]]]:
    """The runs a table takes, its row labels in order, and its runs by (label,
    filter) (a filter is there when some run used it)."""
    chosen = [r for r in rows if r["group"] in spec.groups and (spec.scenarios is None or r["scenario"] in spec.scenarios)]
    labels = list(dict.fromkeys(row_label(r, spec.rows) for r in chosen))
    by: dict[tuple[str, str], list[dict]] = {}
    for r in chosen:
        by.setdefault((row_label(r, spec.rows), r["filter"]), []).append(r)
    return chosen, labels, by


def table_cells(spec, rows: list[dict]) -> tuple[list[str], list[list[str]], str]:
    """One table of the campaign file as plain text: its head, its rows (a
    row label, then for each filter the metrics as mean (sd) over the runs,
    published numbers in brackets) and the line under it (runs, failed).
    The head's first cell and each row's first are text from outside."""
    chosen, labels, by = table_groups(spec, rows)
    filters = [f for f in ("gpf", "apf", "opf", "ckf") if any(r["filter"] == f for r in chosen)]
    head = [str(spec.rows)] + [f"{f.upper()} {HEAD[m]}" for f in filters for m in spec.metrics]
    body = []
    for label in labels:
        out = [str(label)]
        for f in filters:
            mine = by.get((label, f), [])
            ref = spec.reference.values.get((label, f), {}) if spec.reference else {}
            for m in spec.metrics:
                text = format_cell(cell(mine, m), m)
                if m in ref:
                    mean, sd = ref[m]
                    text += f" [{_fmt(mean)}" + (f" ({_fmt(sd)})" if sd is not None else "") + "]"
                out.append(text)
        body.append(out)
    n_runs = len(chosen)
    n_failed = sum(r["status"] != "ok" for r in chosen)
    return head, body, f"{n_runs} runs" + (f", {n_failed} failed (not counted)" if n_failed else "") + "."


def _md_table(head: list[str], body: list[list[str]], outside: int) -> list[str]:
    """A Markdown table; the first ``outside`` cells of the head and of each row escaped (text from outside)."""
    def line(cells):
        return "| " + " | ".join([escape(c) for c in cells[:outside]] + list(cells[outside:])) + " |"

    return [line(head), "|" + "---|" * len(head)] + [line(row) for row in body]


def reference_note(spec) -> str | None:
    """What the brackets of a table hold (None: it has no published numbers)."""
    return None if spec.reference is None else f"Ours: mean (sd) over the runs; in brackets: {spec.reference.source}."


def table_markdown(spec, rows: list[dict]) -> str:
    """One table of the campaign file (:func:`table_cells`) in Markdown."""
    head, body, tail = table_cells(spec, rows)
    lines = [f"### {escape(spec.title)}", ""]
    if spec.reference is not None:
        lines += [f"Ours: mean (sd) over the runs; in brackets: {escape(spec.reference.source)}.", ""]
    lines += _md_table(head, body, 1)
    lines += ["", tail]
    return "\n".join(lines) + "\n"




def summary_rows(rows: list[dict]) -> list[dict[str, Any]]:
    """Per group, filter, noise level and particle count: how the runs went.
    Isolation is counted among the faulty runs whose fault was detected at or
    after its onset (a fault the detector does not see cannot be isolated; an
    alarm before the onset is a false alarm): the most probable
    hypothesis is right, the truth is among the survivors, the verdict is
    'isolated' and right, and the same outside the ambiguity groups the
    signatures predict, and outside those and the groups the data of the
    scenario are predicted not to separate (the row's ``separable``,
    :mod:`bgc.analysis.distinguish`; rows without it are not counted there).
    Detection is also counted among the faulty runs whose data are predicted
    to show the fault: the ideal detector, the likelihood-ratio test that
    knows the fault's onset and magnitude, held at the detector's own
    false-alarm probability per run (:data:`FALSE_ALARM`), detects it with
    probability at least ``distinguish.LEVEL``
    (:func:`~bgc.analysis.distinguish.ideal_power` of the row's
    ``detectability``): the detector's power against that bound."""
    def key(r):
        return r["group"], r["filter"], r["noise"], f"{r['particles']}" + (" +grid" if r.get("refine") else "")

    keys = list(dict.fromkeys(key(r) for r in rows))
    out = []
    for g, f, noise, n in keys:
        mine = [r for r in rows if key(r) == (g, f, noise, n)]
        ok = _ok(mine)
        free = [r for r in ok if not r.get("fault")]
        faulty = [r for r in ok if r.get("fault")]
        seen = [r for r in faulty if r["delay"] is not None]  # detected at or after the onset
        plain = [r for r in seen if not r.get("ambiguous")]
        separated = [r for r in plain if r.get("separable")]
        shown = [r for r in faulty if ideal_power(r.get("detectability") or 0.0, FALSE_ALARM) >= LEVEL]
        isolated = [r for r in seen if r["verdict"] == "isolated"]
        out.append({
            "group": g, "filter": f, "noise": noise, "particles": n, "runs": len(mine),
            "failed": len(mine) - len(ok), "fault_free": len(free),
            "false_alarms": sum(bool(r["false_alarm"]) for r in free),
            "early_alarms": sum(bool(r["false_alarm"]) for r in faulty),
            "faulty": len(faulty), "detected": len(seen),
            "shown": len(shown), "detected_shown": sum(r["delay"] is not None for r in shown),
            "right": sum(bool(r["right"]) for r in seen),
            "right_parameter": sum(right_parameter(r) for r in seen),
            "in_candidates": sum(bool(r["in_candidates"]) for r in seen),
            "isolated": len(isolated), "isolated_right": sum(bool(r["right"]) for r in isolated),
            "right_outside_ambiguity": sum(bool(r["right"]) for r in plain), "outside_ambiguity": len(plain),
            "right_separable": sum(bool(r["right"]) for r in separated), "separable": len(separated),
            "est_error": cell(faulty, "est_error"), "covers": cell(faulty, "covers"),
            "delay": cell(faulty, "delay"), "rt": cell(ok, "rt"),
        })
    return out


def right_parameter(row: dict) -> bool:
    """The diagnosed fault model (``PARAM_KIND``) names the injected parameter,
    whatever the kind (a slow drift taken for a step still points at the
    right component)."""
    from ..kinds import fault_parameter

    said = row.get("diagnosed") or ""
    return bool(row.get("fault")) and "_" in said and fault_parameter(said) == row["fault"]


def _frac(k: int, n: int) -> str:
    return "–" if n == 0 else f"{k}/{n} ({100 * k / n:.1f} %)"


#: The summary's columns (:func:`summary_cells`).
SUMMARY_HEAD = ["group", "filter", "noise", "N", "runs", "failed", "false alarms", "detected",
                "detected where the data show it (predicted)",
                "right (of detected)", "right component", "truth among survivors", "right when isolated",
                "right outside predicted ambiguity groups", "right where the data separate it (predicted)",
                "error % mean (sd)", "95 % covers", "delay", "RT s"]


def summary_cells(rows: list[dict]) -> list[list[str]]:
    """The summary (:func:`summary_rows`) as plain text, a row per group,
    filter, noise level and particle count (its first four cells are text
    from outside)."""
    out = []
    for s in summary_rows(rows):
        out.append([
            str(s["group"]), str(s["filter"]), str(s["noise"]), str(s["particles"]), str(s["runs"]),
            str(s["failed"]),
            "; ".join(x for x in (_frac(s["false_alarms"], s["fault_free"]) if s["fault_free"] else "",
                                  f"{s['early_alarms']} before the onset" if s["faulty"] else "") if x) or "–",
            _frac(s["detected"], s["faulty"]), _frac(s["detected_shown"], s["shown"]),
            _frac(s["right"], s["detected"]),
            _frac(s["right_parameter"], s["detected"]), _frac(s["in_candidates"], s["detected"]), _frac(s["isolated_right"], s["isolated"]),
            _frac(s["right_outside_ambiguity"], s["outside_ambiguity"]), _frac(s["right_separable"], s["separable"]),
            format_cell(s["est_error"], "est_error"), format_cell(s["covers"], "covers"),
            format_cell(s["delay"], "delay"), format_cell(s["rt"], "rt")])
    return out


def summary_markdown(rows: list[dict]) -> str:
    return "\n".join(_md_table(SUMMARY_HEAD, summary_cells(rows), 4)) + "\n"


def confusion(rows: list[dict], model: str) -> tuple[list[str], list[str], dict[tuple[str, str], int]]:
    """(true labels, diagnosed labels, counts) over one model's finished runs."""
    counts: dict[tuple[str, str], int] = {}
    for r in _ok(rows):
        if r["model"] != model:
            continue
        truth = f"{r['fault']}_{r['kind']}" if r.get("fault") else "none"
        said = r.get("diagnosed") or "none"
        counts[(truth, said)] = counts.get((truth, said), 0) + 1
    truths = sorted({t for t, _ in counts}, key=lambda t: (t != "none", t))
    saids = sorted({s for _, s in counts}, key=lambda s: (s != "none", s))
    return truths, saids, counts


def confusion_cells(rows: list[dict], model: str) -> tuple[list[str], list[list[str]]]:
    """One model's confusion matrix as plain text: the diagnosed labels (the
    columns), and a row per true label, its counts after it (labels are
    text from outside)."""
    truths, saids, counts = confusion(rows, model)
    return saids, [[t] + [str(counts.get((t, s), "")) for s in saids] for t in truths]


def confusion_markdown(rows: list[dict], model: str) -> str:
    saids, body = confusion_cells(rows, model)
    lines = ["| truth \\ diagnosed | " + " | ".join(escape(s) for s in saids) + " |",
             "|" + "---|" * (len(saids) + 1)]
    lines += ["| " + " | ".join([escape(row[0])] + row[1:]) + " |" for row in body]
    return "\n".join(lines) + "\n"


def _verdict_right(r: dict) -> bool:
    """Whether a run's verdict told the truth: ``isolated``, the fault it
    names is the injected one; ``ambiguous``, the injected one is in the
    group; ``unexplained``, the injected fault is not one the model expects
    (not among its candidates, or outside the candidate's prior: ``expected``
    false); ``mismatch``, never (a campaign simulates the model itself, which
    fits its own runs); ``no fault``, none was injected."""
    truth = f"{r['fault']}_{r['kind']}" if r.get("fault") else None
    verdict = r["verdict"]
    if verdict == "isolated":
        return truth is not None and r.get("diagnosed") == truth
    if verdict == "ambiguous":
        return truth is not None and truth in (r.get("candidates") or "").split()
    if verdict == "unexplained":
        return truth is not None and r.get("expected") is False
    if verdict == "mismatch":  # a campaign's runs are the model's own: it fits them
        return False
    return truth is None


#: The verdicts, in the order the reliability table lists them.
VERDICTS = ("isolated", "ambiguous", "unexplained", "mismatch", "no fault")


def reliability_rows(rows: list[dict]) -> list[dict[str, Any]]:
    """For each verdict: how many runs had it and how often it told the truth
    (:func:`_verdict_right`); and, among runs with a fault detected at or after
    its onset and a fault named, how often the named fault was of the right
    class (``parameter``, ``sensor``, ``actuator``)."""
    ok = _ok(rows)
    out = []
    for v in VERDICTS:
        mine = [r for r in ok if r["verdict"] == v]
        out.append({"verdict": v, "runs": len(mine), "right": sum(_verdict_right(r) for r in mine)})
    named = [r for r in ok if r.get("fault") and r.get("delay") is not None and r.get("diagnosed_target")]
    out.append({"verdict": "fault class (named fault)", "runs": len(named),
                "right": sum(r["diagnosed_target"] == r.get("target") for r in named)})
    return out


RELIABILITY_HEAD = ["verdict", "runs", "told the truth"]


def reliability_cells(rows: list[dict]) -> list[list[str]]:
    """The reliability of the verdicts (:func:`reliability_rows`) as plain text."""
    return [[s["verdict"], str(s["runs"]), _frac(s["right"], s["runs"])] for s in reliability_rows(rows)]


def reliability_markdown(rows: list[dict]) -> str:
    return "\n".join(_md_table(RELIABILITY_HEAD, reliability_cells(rows), 1)) + "\n"


#: What the reliability table says (the paragraph over it).
RELIABILITY_TEXT = (
    "How often each verdict told the truth: isolated, the fault named is the one injected; ambiguous, it "
    "is in the group; unexplained, the injected fault is not one the model expects (not a candidate, or "
    "outside its prior); mismatch, never (the runs are the model's own); no fault, none was injected (a "
    "fault the detector missed counts against it). "
    "The last row: among detected faults, the named fault's class (parameter, sensor, actuator).")


def runs_line(rows: list[dict]) -> str:
    return (f"{len(rows)} runs ({sum(r['status'] != 'ok' for r in rows)} failed). Metrics are defined in "
            "docs/experiments.md.")


def failed_lines(rows: list[dict], quote=str) -> list[str]:
    """The first 50 failed runs, each with its failure."""
    return [f"run {quote(r['index'])} ({quote(r['scenario'])}, {quote(r['filter'])}, seed {quote(r['seed'])}): "
            f"{quote(r['failure'])}" for r in rows if r["status"] != "ok"][:50]


def campaign_markdown(c, rows: tuple[dict, ...]) -> str:
    """``tables.md``: the campaign's tables, the summary and the confusion matrices."""
    from .artifacts import MARK

    rows = list(rows)
    out = [f"<!-- {MARK} experiment from {_comment(c.source)} -->", f"# Campaign {escape(c.name)}", ""]
    if c.description and c.description.strip():
        out += [escape(c.description, prose=True), ""]
    out += [runs_line(rows), ""]
    for spec in c.tables:
        out += [table_markdown(spec, rows), ""]
    out += ["## Summary", "", summary_markdown(rows), ""]
    out += ["## Reliability of the verdicts", "", RELIABILITY_TEXT, "", reliability_markdown(rows), ""]
    for model in dict.fromkeys(r["model"] for r in rows):
        out += [f"## Isolation confusion matrix: {escape(model)}", "", confusion_markdown(rows, model), ""]
    failed = failed_lines(rows, escape)
    if failed:
        out += ["## Failed runs", ""] + [f"- {line}" for line in failed] + [""]
    return "\n".join(out).rstrip() + "\n"


def campaign_html(c, rows: tuple[dict, ...], pictures: dict[str, bytes]) -> str:
    """``report.html``: tables.md's tables, summary, reliability and
    confusion matrices as one self-contained page (:mod:`bgc.output.html`),
    from the same cells, with the campaign's plots embedded (``pictures``:
    by file name, :func:`bgc.output.plots.campaign_figures`)."""
    rows = list(rows)
    tables = []
    for spec in c.tables:
        head, body, tail = table_cells(spec, rows)
        tables.append({"title": spec.title, "note": reference_note(spec), "table": html.table(head, body),
                       "tail": tail})
    confusions = []
    for model in dict.fromkeys(r["model"] for r in rows):
        saids, body = confusion_cells(rows, model)
        confusions.append({"model": model, "table": html.table(["truth \\ diagnosed", *saids], body)})
    captions = {name: name.removesuffix(".png").replace("_", " ") for name in pictures}
    return html.page(
        "campaign.html.j2", c.source, title=f"Campaign {c.name}", description=" ".join((c.description or "").split()),
        runs=runs_line(rows), tables=tables, summary=html.table(SUMMARY_HEAD, summary_cells(rows)),
        reliability_text=RELIABILITY_TEXT, reliability=html.table(RELIABILITY_HEAD, reliability_cells(rows)),
        confusions=confusions, pictures=html.pictures(pictures, captions), failed=failed_lines(rows))


def campaign_json(c, rows: tuple[dict, ...]) -> str:
    """``summary.json``: the summary rows and every table's cells as numbers."""
    rows = list(rows)
    tables = []
    for spec in c.tables:
        _, labels, by = table_groups(spec, rows)
        cells = []
        for label in labels:
            for f in ("gpf", "apf", "opf", "ckf"):
                mine = by.get((label, f))
                if not mine:
                    continue
                values = {}
                for m in spec.metrics:
                    values[m] = cell_json(cell(mine, m))
                cells.append({"row": label, "filter": f, "metrics": values})
        tables.append({"title": spec.title, "cells": cells})
    summary = []
    for s in summary_rows(rows):
        summary.append({k: (cell_json(v) if isinstance(v, Cell) else v) for k, v in s.items()})
    return render.to_json({"generated_by": "bgc", "campaign": c.name, "source": c.source, "runs": len(rows),
                           "tables": tables, "summary": summary, "reliability": reliability_rows(rows)})
