"""generated/ is reproducible byte for byte: regenerate in memory and diff."""

import io
import xml.etree.ElementTree as ET

import pytest

from bgc.compiler import printing
from bgc.output import artifacts
from bgc.pipeline import compile_model, generated_files

from conftest import ROOT, compiled

MODELS = ["circuit", "two_tank", "ro"]


@pytest.mark.parametrize("name", MODELS)
def test_generated_text_matches_compiler_byte_for_byte(name):
    c = compiled(name)
    files = generated_files(c)
    diffs = artifacts.diff(ROOT / "generated" / name, files)
    assert not diffs, ("generated/ is out of date; refresh with: bgc compile models/" + name + ".yaml\n"
                       + "\n".join(diffs))


@pytest.mark.parametrize("name", MODELS)
def test_generated_packages_pass_pyflakes(name):
    """No unused or undefined names, no shadowed imports: generated code is a
    reviewed product (pyflakes on every module of the committed package)."""
    from pyflakes.api import check
    from pyflakes.reporter import Reporter

    out, err = io.StringIO(), io.StringIO()
    for path in sorted([*(ROOT / "generated" / name / "numpy_model").glob("*.py"),
                        *(ROOT / "generated" / name / "numba_model").glob("*.py")]):
        check(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)), Reporter(out, err))
    assert out.getvalue() + err.getvalue() == ""


@pytest.mark.parametrize("name", MODELS)
def test_generated_has_no_stray_files_and_pictures_parse(name):
    c = compiled(name)
    expected = set(generated_files(c)) | set(artifacts.picture_names(c.dbn))
    on_disk = {str(p.relative_to(ROOT / "generated" / name)) for p in (ROOT / "generated" / name).rglob("*")
               if p.is_file() and "__pycache__" not in p.parts}  # Python's and numba's caches: not bgc's files
    assert on_disk == expected
    for pic in artifacts.picture_names(c.dbn):
        root = ET.parse(ROOT / "generated" / name / pic).getroot()
        assert root.tag.endswith("svg")


def test_same_model_same_bytes_twice_and_independent_of_file_order(tmp_path):
    text = (ROOT / "models" / "circuit.yaml").read_text()
    a = generated_files(compile_model(ROOT / "models" / "circuit.yaml"))
    printing._cse_text.cache_clear()  # the second compilation prints its blocks again, not from the first's
    b = generated_files(compile_model(ROOT / "models" / "circuit.yaml"))
    assert a == b
    # Reorder the elements section: every artefact but the manifest's source hash is the same.
    lines = text.splitlines(keepends=True)
    start = next(i for i, l in enumerate(lines) if l.startswith("elements:")) + 1
    end = next(i for i in range(start, len(lines)) if not lines[i].startswith("  "))
    shuffled = lines[:start] + list(reversed(lines[start:end])) + lines[end:]
    (tmp_path / "models").mkdir()
    p = tmp_path / "models" / "circuit.yaml"
    p.write_text("".join(shuffled))
    printing._cse_text.cache_clear()
    c = generated_files(compile_model(p))
    for rel in a:
        if rel != "manifest.json":
            assert c[rel] == a[rel], rel


def test_diff_reports_a_changed_file(tmp_path):
    files = {"a.txt": "one\ntwo\n"}
    artifacts.write_folder(tmp_path, {**files, "manifest.json": artifacts.manifest(files, "compile")})
    assert artifacts.diff(tmp_path, files) == []
    out = artifacts.diff(tmp_path, {"a.txt": "one\nthree\n"})
    assert out and "-two" in out[0] and "+three" in out[0]
    assert artifacts.diff(tmp_path, {"b.txt": "x"}) == [f"missing: {tmp_path / 'b.txt'}"]
