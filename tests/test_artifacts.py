"""Writing outputs: bgc never deletes or overwrites a file it did not write.

A compiled folder holds a manifest of what bgc wrote there; a later compile
removes only files that manifest lists, and refuses a non-empty folder without
one. A single output replaces only a file that carries bgc's mark.
"""

import json
import subprocess
import sys

import pytest

from bgc.errors import OutputError
from bgc.output import artifacts

from conftest import ROOT

CIRCUIT = (ROOT / "models" / "circuit.yaml").read_text()


def bgc(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "bgc", *args], cwd=cwd, capture_output=True, text=True)


def one_line(r) -> str:
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_compiling_into_the_folder_that_holds_the_model_is_refused_and_deletes_nothing(tmp_path):
    """The issue's case: plants/circuit/circuit.yaml (model name circuit) with
    notes beside it; -o plants means plants/circuit/, which bgc did not write."""
    plant = tmp_path / "plants" / "circuit"
    plant.mkdir(parents=True)
    (plant / "circuit.yaml").write_text(CIRCUIT)
    (plant / "notes.txt").write_text("my notes\n")
    line = one_line(bgc("compile", str(plant / "circuit.yaml"), "-o", str(tmp_path / "plants"), "--no-pictures"))
    assert line == (f"{plant} is not empty and holds no bgc manifest.json (bgc writes only into an empty folder "
                    "or one it wrote before: choose another -o)")
    assert sorted(p.name for p in plant.iterdir()) == ["circuit.yaml", "notes.txt"]
    assert (plant / "circuit.yaml").read_text() == CIRCUIT and (plant / "notes.txt").read_text() == "my notes\n"


def test_a_recompile_keeps_user_files_and_removes_the_files_of_a_removed_fault(tmp_path):
    model = tmp_path / "circuit.yaml"
    model.write_text(CIRCUIT)
    out = tmp_path / "gen"
    assert bgc("compile", str(model), "-o", str(out), "--no-pictures").returncode == 0
    folder = out / "circuit"
    stale = [folder / "numpy_model" / "R1_abrupt.py", folder / "dbn" / "R1_abrupt.txt"]
    assert all(p.exists() for p in stale)
    (folder / "notes.txt").write_text("mine\n")                  # a user file beside the output
    (folder / "numpy_model" / "scratch.py").write_text("x = 1\n")
    (folder / "circuit.yaml").write_text(CIRCUIT)               # the model kept inside the output folder
    without_r1 = CIRCUIT.replace("  R1: [abrupt, incipient]\n", "")
    assert without_r1 != CIRCUIT
    model.write_text(without_r1)
    r = bgc("compile", str(model), "-o", str(out), "--no-pictures")
    assert r.returncode == 0, r.stderr
    assert not any(p.exists() for p in stale)                   # stale generated files are cleaned
    assert (folder / "notes.txt").read_text() == "mine\n"
    assert (folder / "numpy_model" / "scratch.py").read_text() == "x = 1\n"
    assert (folder / "circuit.yaml").read_text() == CIRCUIT
    listed = json.loads((folder / "manifest.json").read_text())["files"]
    assert "numpy_model/R1_abrupt.py" not in listed and "numpy_model/C1_abrupt.py" in listed


def test_a_file_bgc_did_not_write_is_not_overwritten_even_in_its_own_folder(tmp_path):
    """A user file at a path bgc now wants (not listed by the old manifest) is refused, not replaced."""
    files = {"a.txt": "one\n", "manifest.json": json.dumps({"generated_by": "bgc", "files": {"a.txt": "x"}})}
    artifacts.write_folder(tmp_path, files)
    (tmp_path / "b.txt").write_text("the user's\n")
    with pytest.raises(OutputError) as info:
        artifacts.write_folder(tmp_path, {**files, "b.txt": "bgc's\n"})
    assert info.value.line() == (f"{tmp_path / 'b.txt'} exists and bgc did not write it (move it away or choose "
                                 "another output folder with -o)")
    assert (tmp_path / "b.txt").read_text() == "the user's\n"


def test_a_manifest_cannot_make_bgc_delete_outside_its_folder(tmp_path):
    """A manifest is a file on disk: paths in it that leave the folder are ignored."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep\n")
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "manifest.json").write_text(json.dumps({"generated_by": "bgc", "files": {
        "../victim.txt": "x", str(victim): "x"}}))
    artifacts.write_folder(folder, {"a.txt": "one\n", "manifest.json": json.dumps({"generated_by": "bgc"})})
    assert victim.read_text() == "keep\n"


def test_a_folder_path_that_is_a_file_is_refused(tmp_path):
    target = tmp_path / "f"
    target.write_text("x")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        artifacts.write_folder(target, {"a.txt": "one\n"})


def test_single_outputs_replace_only_files_bgc_wrote(tmp_path):
    mine = tmp_path / "run.csv"
    mine.write_text("time,y\n1,2\n")
    r = bgc("simulate", "models/circuit.yaml", "--steps", "5", "-o", str(mine))
    assert one_line(r) == (f"{mine} exists and bgc did not write it (choose another output path, or move the "
                           "file away)")
    assert mine.read_text() == "time,y\n1,2\n"
    ours = tmp_path / "ours.csv"
    plot = tmp_path / "ours.png"
    for _ in range(2):  # the second run replaces the CSV and the plot it wrote itself
        r = bgc("simulate", "models/circuit.yaml", "--steps", "5", "-o", str(ours), "--plot", str(plot))
        assert r.returncode == 0, r.stderr
    assert artifacts.written_by_bgc(ours) and artifacts.written_by_bgc(plot)
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 64)
    r = bgc("simulate", "models/circuit.yaml", "--steps", "5", "-o", str(ours), "--plot", str(photo))
    assert one_line(r).startswith(f"{photo} exists and bgc did not write it")


@pytest.mark.parametrize("fmt", ["text", "json", "dot", "svg"])
def test_bgc_show_rewrites_the_dump_it_wrote(tmp_path, fmt):
    """Every format of ``bgc show -o`` carries the mark, so a second run may
    replace the first (and the JSON still parses)."""
    out = tmp_path / f"tcg.{fmt}"
    for _ in range(2):
        r = bgc("show", "tcg", "models/circuit.yaml", "--format", fmt, "-o", str(out), "--engine", "matplotlib")
        assert r.returncode == 0, r.stderr
    assert artifacts.written_by_bgc(out)
    if fmt == "json":
        assert json.loads(out.read_text())["generated_by"] == "bgc"


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_pictures_carry_the_mark_and_stay_valid(fmt):
    """The mark is a PNG text chunk (with its CRC) or an SVG comment."""
    import zlib
    import xml.etree.ElementTree as ET

    from bgc.output import draw
    from bgc.pipeline import compile_model

    data = draw.tcg_picture(compile_model(ROOT / "models" / "circuit.yaml").tcg, fmt, "matplotlib")
    if fmt == "svg":
        assert b"<!-- generated by bgc -->" in data[:200]
        assert ET.fromstring(data).tag.endswith("svg")
        return
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    pos, chunks = 8, []
    while pos < len(data):  # every chunk's CRC is right, the mark is one of them
        n = int.from_bytes(data[pos:pos + 4], "big")
        kind, body, crc = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n], data[pos + 8 + n:pos + 12 + n]
        assert zlib.crc32(kind + body).to_bytes(4, "big") == crc, kind
        chunks.append((kind, body))
        pos += 12 + n
    assert chunks[0][0] == b"IHDR" and (b"tEXt", b"Software\x00bgc") in chunks and chunks[-1][0] == b"IEND"
