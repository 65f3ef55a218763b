"""The API reference (docs/reference) is generated from the docstrings by Sphinx, and built here with
warnings as errors: a docstring Sphinx cannot read, or a public name missing from the pages, fails.

Built as text (the html builder takes longer and reads the same docstrings); the pages to read are
built by ``.venv/bin/python -m sphinx -b html docs/reference out/reference``."""

import re
from pathlib import Path

import pytest

pytest.importorskip("sphinx")

from sphinx.cmd.build import build_main  # noqa: E402  (after the skip: sphinx is the test extra's)

import bgc  # noqa: E402
import bgc.api  # noqa: E402
from bgc import errors, events  # noqa: E402
from bgc.data import runs  # noqa: E402
from bgc.diagnosis import options, values  # noqa: E402
from bgc.experiment import public  # noqa: E402
from bgc.service import public as service  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "docs" / "reference"

#: Sphinx 9's napoleon reads autodoc's options the way Sphinx 9 deprecates (its own warning, once a docstring).
pytestmark = pytest.mark.filterwarnings("ignore:The mapping interface for autodoc options objects is deprecated")


def _squeeze(text: str) -> str:
    """``text`` without what the text builder adds or moves: white space (it wraps lines, after a
    hyphen too), quotes (around a literal) and ``()`` (after a function's name)."""
    return re.sub(r'\s|"|\(\)', "", text)


def _role(m: re.Match) -> str:
    """What the text builder writes for a cross-reference (``:class:`~a.B``` is ``B``)."""
    target = m[1]
    if "<" in target:
        return target.split("<")[0]
    return target[1:].split(".")[-1] if target.startswith("~") else target


def _first_paragraph(obj) -> str:
    """The first paragraph of ``obj``'s docstring as the text builder writes it, squeezed."""
    first = obj.__doc__.strip().split("\n\n")[0]
    first = re.sub(r"``(.+?)``", r"\1", first, flags=re.S)
    return _squeeze(re.sub(r":[a-z]+:`([^`]+)`", _role, first))


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    """The built reference's pages by name (``api``, ``errors``, ...), squeezed."""
    tmp = tmp_path_factory.mktemp("reference")
    out = tmp / "text"
    code = build_main(["-b", "text", "-q", "-W", "--keep-going", "-d", str(tmp / "doctrees"), str(SOURCE), str(out)])
    assert code == 0, "sphinx reported problems (its warnings are in the captured stderr)"
    return {p.stem: _squeeze(p.read_text(encoding="utf-8")) for p in out.glob("*.txt")}


def _documented(page: str, module, names) -> None:
    for name in names:
        assert f"{module.__name__}.{name}" in page, f"{module.__name__}.{name} is not in the reference"
        assert _first_paragraph(getattr(module, name)) in page, f"{module.__name__}.{name}'s docstring is not"


def test_every_name_bgc_gives_is_documented(pages):
    """``bgc``'s ``__all__`` is the public API: the names of :mod:`bgc.api` on its page (all of its
    ``__all__``), the errors on theirs, each with its docstring."""
    _documented(pages["api"], bgc.api, bgc.api.__all__)
    _documented(pages["api"], public, public.__all__)
    _documented(pages["api"], service, service.__all__)
    given = [name for name in bgc.__all__ if name not in (*bgc.API, *bgc.CAMPAIGN, *bgc.SERVICE) and name != "__version__"]
    _documented(pages["errors"], errors, given)
    assert set(bgc.API) <= set(bgc.api.__all__), "bgc gives a name bgc.api does not list in __all__"
    assert set(bgc.CAMPAIGN) == set(public.__all__)
    assert set(bgc.SERVICE) == set(service.__all__)
    assert _squeeze("A recorded run (CSV) cannot be read or does not fit the model.") in pages["errors"]


def test_what_a_diagnosis_holds_is_documented(pages):
    """The options, the values a report holds, a run and every event, each with its docstring."""
    _documented(pages["options"], options, ("DiagnosisOptions", "KalmanOptions", "GridOptions"))
    _documented(pages["values"], values, ("Diagnosis", "Hypothesis", "Estimate", "Detection"))
    _documented(pages["runs"], runs, ("Run",))
    _documented(pages["events"], events, [cls.__name__ for cls in events.Event.__args__])
