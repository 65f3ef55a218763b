"""report.md: text from outside (the model file's path, a scenario, the
notes) is literal Markdown; it cannot forge a heading, a table row, a link
or HTML."""

import re
import shutil

import bgc
from bgc.diagnosis.options import DiagnosisOptions
from bgc.output import report

from conftest import ROOT


def test_a_hostile_model_path_cannot_forge_markdown(tmp_path):
    name = "a|b [x](javascript:alert(1)) <img src=x> *_z_* `c`\n# forged.yaml"
    model = tmp_path / name
    shutil.copy(ROOT / "models" / "circuit.yaml", model)
    r = bgc.diagnose(model, scenario="none", steps=30, options=DiagnosisOptions(filter="ckf", workers=1))
    text = report.report_markdown(r)
    first = text.splitlines()[0]
    assert first.startswith("# Diagnosis of circuit (")
    headings = [line for line in text.splitlines() if line.startswith("#")]
    assert headings[1:] == ["## Verdict", "## Data", "## Events"]  # the forged heading stays inside the first line
    body = first[len("# Diagnosis of circuit ("):-1]
    # every markup character of the path is escaped: none stands without its backslash
    for ch in "|[]<>*`#":
        assert re.search(r"(?<!\\)" + re.escape(ch), body) is None, (ch, body)
    assert "\\n" in body  # the newline is its escape, on the same line


def test_an_onset_the_final_weighing_moves_outside_the_tracked_ones_is_said():
    """One story: the events said "tracking R2_abrupt from 3 onset(s), t = 3.4
    to 3.7"; a verdict whose onset (sample 63, t = 3.15 at dt 0.05) lies
    outside them gets a Refined event saying from what to what; an onset
    among them, another candidate's, or no verdict get none."""
    from bgc import events as ev
    from bgc.diagnosis.finish import refined
    from bgc.output.events import sentence

    told = [ev.Started(70, "R2_abrupt", (68, 70, 74)), ev.Started(70, "R1_abrupt", (60, 70))]
    out = refined(told, ("R2_abrupt",), 63, 199)
    assert out == [ev.Refined(199, "R2_abrupt", 63, 68, 74)]
    assert sentence(out[0], lambda k: (k + 1) * 0.05) == (
        "R2_abrupt: onset refined to t = 3.2 from the onsets tracked online (t = 3.45 to 3.75) by the final "
        "weighing of the whole record")
    assert refined(told, ("R2_abrupt",), 70, 199) == []
    assert refined(told, ("R1_abrupt",), 63, 199) == []
    assert refined(told, (), None, 199) == []
