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
    r = bgc.diagnose(model, scenario="none", steps=30, options=DiagnosisOptions(method="ckf", workers=1))
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
