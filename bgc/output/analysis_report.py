"""``bgc analyse -o DIR``: the analysis as ``analysis.md`` and
``analysis.html`` (one self-contained page, :mod:`bgc.output.html`), made
from the same pieces: the faults each level detects, the isolability matrix
(a letter per level in each cell), the groups each level cannot tell apart,
what one level tells apart and another does not, sensor placement and input
tests when asked for, and why each pair is not told apart; the picture of
the matrices (``isolability.png``) in both."""

from __future__ import annotations

from . import html
from .render import LEVEL_LETTERS, placement_lines

#: The picture of the folder and its caption.
CAPTIONS = {"isolability.png": "which fault (row) each level tells from which (column): filled, told apart; "
                               "a grey row, a fault the level does not detect"}


def _pieces(r) -> dict:
    """What both pages say, as plain text and rows."""
    f, levels = r.faults, r.levels
    letters = "".join(LEVEL_LETTERS[lv.name] for lv in levels)
    detect = [(str(i + 1), name, r.targets[i], *("yes" if lv.detectable[i] else "no" for lv in levels))
              for i, name in enumerate(f)]
    matrix = [(f"{i + 1} {name}", *("-" * len(letters) if i == j else
                                    "".join(LEVEL_LETTERS[lv.name] if lv.isolable[i][j] else "." for lv in levels)
                                    for j in range(len(f)))) for i, name in enumerate(f)]
    classes = [f"{lv.name}: not detected: {', '.join(x for x, d in zip(f, lv.detectable) if not d) or 'none'}; "
               "not told apart (both ways): "
               + ("; ".join("{" + ", ".join(g) + "}" for g in lv.classes(f)) or "none") for lv in levels]
    for mode, pair in r.by_mode.items():
        classes += [f"in {mode}, {lv.name}: not told apart: "
                    + ("; ".join("{" + ", ".join(g) + "}" for g in lv.classes(f)) or "none") for lv in pair]
    between = []
    for a, b in zip(levels, levels[1:]):
        for x, y in ((a, b), (b, a)):
            pairs = r.more(x.name, y.name)
            if pairs:
                between.append(f"{x.name} tells apart what {y.name} does not: "
                               + ", ".join(f"{i} from {j}" for i, j in pairs))
    why = []
    for i, name in enumerate(f):
        for j, other in enumerate(f):
            reasons = [f"{lv.name}: {lv.why[i, j]}" for lv in levels if (i, j) in lv.why]
            if reasons:
                why.append((f"{name} not detected" if i == j else f"{name} not told from {other}", reasons))
    tests = [f"{x}: P {p0:.2f}, no input test tried does better" if u is None else
             f"{x}: P {p0:.2f} -> {p:.2f} with {u}={text}" for x, u, text, p, p0 in (r.input_tests or ())]
    return {"title": f"What the sensors of {r.model} can detect and tell apart",
            "meta": f"Model file {r.source}; levels " + ", ".join(f"{LEVEL_LETTERS[lv.name]} {lv.name}"
                                                                   for lv in levels) + ".",
            "detect_head": ("#", "fault", "target", *(lv.name for lv in levels)), "detect": detect,
            "matrix_head": ("fault that happened \\ told from", *(str(j + 1) for j in range(len(f)))),
            "matrix": matrix, "letters": letters, "classes": classes, "between": between, "why": why,
            "placement": [] if r.placement is None else placement_lines(r.placement), "tests": tests}


def _md_table(head, rows) -> list[str]:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in rows]


def markdown(r) -> str:
    """``analysis.md``."""
    p = _pieces(r)
    lines = [f"# {p['title']}", "", p["meta"], "", "## Which faults each level detects", ""]
    lines += _md_table(p["detect_head"], p["detect"])
    lines += ["", "## Which fault each level tells from which", "",
              f"Row: the fault that happened; column: the fault it is told from (its number); {p['letters']}: "
              "the levels that tell them apart, `.` where one cannot.", ""]
    lines += _md_table(p["matrix_head"], p["matrix"])
    lines += ["", "![" + CAPTIONS["isolability.png"] + "](isolability.png)", "", "## Not told apart", ""]
    lines += [f"- {x}" for x in p["classes"] + p["between"]]
    if p["placement"]:
        lines += ["", "## Sensor placement", "", "```", *p["placement"], "```"]
    if p["tests"]:
        lines += ["", "## Input tests", ""] + [f"- {x}" for x in p["tests"]]
    lines += ["", "## Why not", ""] + [f"- {what}: " + "; ".join(reasons) for what, reasons in p["why"]]
    return "\n".join(lines) + "\n"


def page(r, pictures: dict[str, bytes]) -> str:
    """``analysis.html``."""
    p = _pieces(r)
    return html.page("analysis.html.j2", r.source, **p, detect_table=html.table(p["detect_head"], p["detect"]),
                     matrix_table=html.table(p["matrix_head"], p["matrix"]),
                     pictures={x.name: x for x in html.pictures(pictures, CAPTIONS)})
