"""The state equations as LaTeX (bgc.output.render.equations_latex, the
generated ``equations.tex``) typeset: every shipped model's block is compiled
by a real LaTeX engine when one is installed, and always parsed line by line by
matplotlib's mathtext and checked for what a parser lets through (a trailing
line break, a space that math mode drops, a name typeset as a product of
letters)."""

from __future__ import annotations

import re
import shutil
import subprocess
from functools import lru_cache

import pytest

from bgc.compiler import causality, equations, load, tcg, validate
from bgc.output.render import equations_latex, latex_name

from conftest import ROOT

#: Every shipped model: the three of models/ and the plants of docs/examples.
SHIPPED = ["models/circuit.yaml", "models/two_tank.yaml", "models/ro.yaml", "docs/examples/dc_motor.yaml",
           "docs/examples/rc.yaml", "docs/examples/shaker.yaml", "docs/examples/two_mass.yaml",
           "docs/examples/joined_tanks.yaml", "docs/examples/tank_chain.yaml", "docs/examples/level_gauge.yaml"]
#: The YAML files of docs/examples that are not plants of one mode bgc compiles (errors on purpose, a
#: campaign, a column map, a sensor placement's costs, a capacitor in derivative causality, models with
#: modes: tests/test_modes.py, tests/test_hidden_mode.py, tests/test_uncommanded.py).
NOT_PLANTS = {"broken_two_tank.yaml", "campaign.yaml", "deriv.yaml", "tank_logger.yaml", "level_gauge_costs.yaml",
              "relay.yaml", "relay_switched.yaml", "level.yaml", "valve_tanks.yaml", "switched_rc.yaml"}
ENGINE = shutil.which("pdflatex") or shutil.which("latex")


@lru_cache(maxsize=None)
def ssm(path: str):
    """The model's state equations (the stages up to them only: no code is generated)."""
    return equations.derive(tcg.build(causality.assign(validate.validate(load.load(ROOT / path)))))


def aligned_lines(tex: str) -> list[str]:
    """The lines of the ``aligned`` block, each with its ``\\\\`` (if any) still on it."""
    body = tex.split(r"\begin{aligned}", 1)[1].split(r"\end{aligned}", 1)[0]
    return [line for line in body.splitlines() if line.strip()]


def test_every_plant_of_docs_examples_is_checked():
    examples = {p.name for p in (ROOT / "docs" / "examples").glob("*.yaml")}
    assert examples - NOT_PLANTS == {p.split("/")[-1] for p in SHIPPED if p.startswith("docs/")}


def test_names_are_typeset_by_one_rule():
    """Digits and underscore parts are a subscript, words in it upright and
    separated by commas; Greek names are Greek letters; a word is italic."""
    expected = {
        "f_in_offset": r"f_{\mathrm{in,offset}}", "F10": "F_{10}", "e4": "e_{4}", "tau_rp": r"\tau_{\mathrm{rp}}",
        "C_memb": r"C_{\mathrm{memb}}", "R12": "R_{12}", "p_memb": r"p_{\mathrm{memb}}", "K0": "K_{0}",
        "F10_offset": r"F_{\mathrm{10,offset}}", "e11_offset": r"e_{\mathrm{11,offset}}", "V": "V",
        "F_back_offset": r"F_{\mathrm{back,offset}}", "omega1": r"\omega_{1}", "Theta": r"\Theta",
        "speed": r"\mathit{speed}", "loadcell2": r"\mathit{loadcell}_{2}", "x1_2": "x_{1,2}",
        "lambda_": r"\mathrm{lambda\_}", "a__b": r"\mathrm{a\_\_b}",
    }
    assert {name: latex_name(name) for name in expected} == expected


@pytest.mark.parametrize("path", SHIPPED)
def test_equations_parse_as_math_and_read_right(path):
    from matplotlib.mathtext import MathTextParser

    s = ssm(path)
    tex = equations_latex(s)
    lines = aligned_lines(tex)
    assert len(lines) == len(s.states) + len(s.outputs)
    assert all(line.endswith(r" \\") for line in lines[:-1])
    assert not lines[-1].rstrip().endswith(r"\\"), "a line break before \\end{aligned} adds an empty line"
    parser = MathTextParser("path")
    for line in lines:
        math = line.removesuffix(r" \\")
        depth = 0
        for c in math.replace(r"\{", "").replace(r"\}", ""):
            depth += {"{": 1, "}": -1}.get(c, 0)
            assert depth >= 0, math
        assert depth == 0, math
        for word in re.findall(r"\\math(?:rm|it)\{([^{}]*)\}", math):
            assert not re.search(r"\s", word), f"math mode drops the space in {word!r}: {math}"
        # outside \mathrm, \mathit and \operatorname, no run of letters or letter and digit: a name is
        # a letter or a macro, its digits a subscript (not F10, not tau, not the product s p e e d)
        bare = re.sub(r"\\(?:mathrm|mathit|operatorname)\{[^{}]*\}|\\[A-Za-z]+", "",
                      math.replace(r"\frac{d", r"\frac{").replace("{dt}", "{}"))
        assert not re.search(r"[A-Za-z][A-Za-z0-9]", bare), math
        sides = math.split("&=")
        assert len(sides) == 2, math
        for side in sides:
            parser.parse(f"${side.strip()}$")  # raises ValueError where mathtext cannot parse it
    for y, line in zip(s.outputs, lines[len(s.states):]):
        assert line.startswith(latex_name(y) + " &= ")
        if re.search(r"[0-9_]", y):
            assert "_{" in line.split("&=")[0], f"output {y} is not subscripted: {line}"


@pytest.mark.process
@pytest.mark.skipif(ENGINE is None, reason="no LaTeX engine (pdflatex, latex) on PATH")
@pytest.mark.parametrize("path", SHIPPED)
def test_equations_compile_with_latex(path, tmp_path):
    doc = tmp_path / "equations.tex"
    doc.write_text("\\documentclass{article}\n\\usepackage{amsmath}\n\\begin{document}\n\\[\n"
                   + equations_latex(ssm(path)) + "\\]\n\\end{document}\n", encoding="utf-8")
    r = subprocess.run([ENGINE, "-interaction=nonstopmode", "-halt-on-error", doc.name], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:]
