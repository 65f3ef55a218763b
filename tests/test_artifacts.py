"""Writing outputs: bgc never deletes or overwrites a file it did not write.

A folder holds a manifest of the command that wrote it and the hash of every
file it wrote; a later write from the same command replaces or removes only
listed files still as bgc wrote them, and refuses a non-empty folder without a
manifest or with another command's. A single output replaces only a file whose
seal (the hash of the file without it) is where bgc writes it and matches.
"""

import json
import os

import pytest
from hypothesis import given, strategies as st

from bgc.errors import InternalError, OutputError
from bgc.output import artifacts

from conftest import ROOT, bgc_cli as bgc, compiled

CIRCUIT = (ROOT / "models" / "circuit.yaml").read_text()


def one_line(r) -> str:
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def folder(files: dict, command: str = "diagnose", **fields) -> dict:
    """``files`` with the manifest of ``command``."""
    return {**files, artifacts.MANIFEST: artifacts.manifest(files, command, **fields)}


def append(path, text: str) -> None:
    """One row appended to a growing file, as a campaign does."""
    with artifacts.GrowingFile(path) as f:
        f.append(text)


def snapshot(root):
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ folders
def test_compiling_into_the_folder_that_holds_the_model_is_refused_and_deletes_nothing(tmp_path):
    """plants/circuit/circuit.yaml (model name circuit) with notes beside it;
    -o plants means plants/circuit/, which bgc did not write."""
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
    folder_ = out / "circuit"
    stale = [folder_ / "numpy_model" / "R1_abrupt.py", folder_ / "dbn" / "R1_abrupt.txt"]
    assert all(p.exists() for p in stale)
    (folder_ / "notes.txt").write_text("mine\n")                  # a user file beside the output
    (folder_ / "numpy_model" / "scratch.py").write_text("x = 1\n")
    (folder_ / "circuit.yaml").write_text(CIRCUIT)               # the model kept inside the output folder
    (folder_ / ".tcg.txt.bgc-tmp").write_text("a user's file named like bgc's old temporary files\n")
    without_r1 = CIRCUIT.replace("  R1: [abrupt, incipient]\n", "")
    assert without_r1 != CIRCUIT
    model.write_text(without_r1)
    r = bgc("compile", str(model), "-o", str(out), "--no-pictures")
    assert r.returncode == 0, r.stderr
    assert not any(p.exists() for p in stale)                   # stale generated files are cleaned
    assert (folder_ / "notes.txt").read_text() == "mine\n"
    assert (folder_ / "numpy_model" / "scratch.py").read_text() == "x = 1\n"
    assert (folder_ / "circuit.yaml").read_text() == CIRCUIT
    assert (folder_ / ".tcg.txt.bgc-tmp").read_text().startswith("a user's file")
    assert not [p for p in folder_.rglob("*.bgc-tmp") if p.name != ".tcg.txt.bgc-tmp"]  # no temporary file left
    m = json.loads((folder_ / "manifest.json").read_text())
    assert m["command"] == "compile"
    assert "numpy_model/R1_abrupt.py" not in m["files"] and "numpy_model/C1_abrupt.py" in m["files"]


def test_a_listed_file_the_user_edited_is_neither_overwritten_nor_removed(tmp_path):
    model = tmp_path / "circuit.yaml"
    model.write_text(CIRCUIT)
    out = tmp_path / "gen"
    assert bgc("compile", str(model), "-o", str(out), "--no-pictures").returncode == 0
    tcg = out / "circuit" / "tcg.txt"
    tcg.write_text(tcg.read_text() + "my remark\n")
    before = snapshot(out)
    line = one_line(bgc("compile", str(model), "-o", str(out), "--no-pictures"))
    assert line == (f"{tcg} was changed after bgc wrote it (move it away to keep it, or choose another output "
                    "folder with -o)")
    assert snapshot(out) == before
    # a stale file the user edited stays when its fault goes (it is the user's now)
    tcg.unlink()
    stale = out / "circuit" / "dbn" / "R1_abrupt.txt"
    stale.write_text("kept\n")
    model.write_text(CIRCUIT.replace("  R1: [abrupt, incipient]\n", ""))
    assert bgc("compile", str(model), "-o", str(out), "--no-pictures").returncode == 0
    assert stale.read_text() == "kept\n"
    assert "dbn/R1_abrupt.txt" not in json.loads((out / "circuit" / "manifest.json").read_text())["files"]
    assert not (out / "circuit" / "numpy_model" / "R1_abrupt.py").exists()


def test_diagnose_refuses_a_campaign_folder_and_a_compiled_package(tmp_path):
    """The issue's case: bgc diagnose -o on another command's output deleted
    runs.csv, tables.md, summary.json and plots/."""
    camp = tmp_path / "camp"
    artifacts.write_folder(camp, folder({"runs.csv": "# generated by bgc experiment from c.yaml\nid\n",
                                         "tables.md": "t\n", "summary.json": "{}\n", "plots/a.png": b"png"},
                                        "experiment", campaign="c", source="c.yaml"))
    before = snapshot(camp)
    line = one_line(bgc("diagnose", "models/circuit.yaml", "--scenario", "none", "--steps", "20", "-o", str(camp)))
    assert line == f"{camp} holds the output of bgc experiment, not of bgc diagnose (choose another output folder with -o)"
    assert snapshot(camp) == before
    assert bgc("compile", "models/circuit.yaml", "-o", str(tmp_path / "gen"), "--no-pictures").returncode == 0
    package = tmp_path / "gen" / "circuit"
    before = snapshot(package)
    line = one_line(bgc("diagnose", "models/circuit.yaml", "--scenario", "none", "--steps", "20", "-o", str(package)))
    assert line.endswith("holds the output of bgc compile, not of bgc diagnose (choose another output folder with -o)")
    assert snapshot(package) == before


@pytest.mark.parametrize("fields, owner", [({"campaign": "c", "source": "c.yaml"}, "experiment"),
                                           ({"model": "m", "source_sha256": "ab"}, "compile"),
                                           ({"model": "m"}, "diagnose")])
def test_manifests_from_before_the_command_field_say_whose_they_are(tmp_path, fields, owner):
    files = {"a.txt": "one\n"}
    old = json.loads(artifacts.manifest(files, owner, **fields))
    del old["command"]
    (tmp_path / "a.txt").write_text("one\n")
    (tmp_path / "manifest.json").write_text(json.dumps(old))
    assert artifacts.manifest_command(artifacts.read_manifest(tmp_path)) == owner
    for command in ("compile", "diagnose", "experiment"):
        if command == owner:
            artifacts.write_folder(tmp_path, folder({"a.txt": "two\n"}, command, **fields))
            assert (tmp_path / "a.txt").read_text() == "two\n"
        else:
            with pytest.raises(OutputError, match=f"holds the output of bgc {owner}, not of bgc {command}"):
                artifacts.write_folder(tmp_path, folder({"a.txt": "three\n"}, command))


def test_a_file_bgc_did_not_write_is_not_overwritten_even_in_its_own_folder(tmp_path):
    """A user file at a path bgc now wants (not listed by the old manifest) is refused, not replaced."""
    files = folder({"a.txt": "one\n"})
    artifacts.write_folder(tmp_path, files)
    (tmp_path / "b.txt").write_text("the user's\n")
    with pytest.raises(OutputError) as info:
        artifacts.write_folder(tmp_path, folder({"a.txt": "one\n", "b.txt": "bgc's\n"}))
    assert info.value.line() == (f"{tmp_path / 'b.txt'} exists and bgc did not write it (move it away or choose "
                                 "another output folder with -o)")
    assert (tmp_path / "b.txt").read_text() == "the user's\n"


@pytest.mark.parametrize("manifest", [
    '{"generated_by": "bgc", "files": {"a.txt": "not a digest"}}',     # bgc's shape, not its content
    '{"generated_by": "bgc", "files": ["a.txt"]}',
    '{"generated_by": "bgc ", "files": {}}',
    '["generated_by", "bgc"]',
    '{"note": "generated_by: bgc", "files": {}}',
    '{"generated_by": "bgc", "files": {}',                             # cut short
])
def test_a_manifest_bgc_would_not_write_does_not_make_the_folder_bgc_s(tmp_path, manifest):
    (tmp_path / "manifest.json").write_text(manifest)
    (tmp_path / "a.txt").write_text("the user's\n")
    with pytest.raises(OutputError, match="holds no bgc manifest.json"):
        artifacts.write_folder(tmp_path, folder({"a.txt": "bgc's\n"}))
    assert (tmp_path / "a.txt").read_text() == "the user's\n"
    assert (tmp_path / "manifest.json").read_text() == manifest


def test_a_manifest_cannot_make_bgc_delete_outside_its_folder(tmp_path):
    """A manifest is a file on disk: paths in it that leave the folder are ignored."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep\n")
    out = tmp_path / "out"
    out.mkdir()
    digest = "0" * 64
    (out / "manifest.json").write_text(json.dumps({"generated_by": "bgc", "command": "diagnose", "files": {
        "../victim.txt": digest, str(victim): digest}}))
    artifacts.write_folder(out, folder({"a.txt": "one\n"}))
    assert victim.read_text() == "keep\n"


def test_a_listed_file_replaced_by_a_link_is_not_followed(tmp_path):
    artifacts.write_folder(tmp_path / "out", folder({"a.txt": "one\n"}))
    target = tmp_path / "elsewhere.txt"
    target.write_text("keep\n")
    (tmp_path / "out" / "a.txt").unlink()
    (tmp_path / "out" / "a.txt").symlink_to(target)
    with pytest.raises(OutputError, match="was changed after bgc wrote it"):
        artifacts.write_folder(tmp_path / "out", folder({"a.txt": "two\n"}))
    artifacts.write_folder(tmp_path / "out", folder({"b.txt": "two\n"}))  # no longer listed: left, not removed
    assert (tmp_path / "out" / "a.txt").is_symlink() and target.read_text() == "keep\n"


def test_a_folder_path_that_is_a_file_is_refused(tmp_path):
    target = tmp_path / "f"
    target.write_text("x")
    with pytest.raises(OutputError, match="is a file or a link, not a folder"):
        artifacts.write_folder(target, folder({"a.txt": "one\n"}))
    assert target.read_text() == "x"


def test_a_growing_file_may_grow_but_not_change_its_start(tmp_path):
    head = "# generated by bgc experiment from c.yaml\nid,x\n"
    artifacts.write_folder(tmp_path, folder({"runs.csv": head}, "experiment", growing=("runs.csv",), campaign="c"))
    append(tmp_path / "runs.csv", "1,2\n")
    assert (tmp_path / "runs.csv").read_text() == head + "1,2\n"
    artifacts.write_folder(tmp_path, folder({"runs.csv": head + "1,2\n", "tables.md": "t\n"}, "experiment",
                                            campaign="c"))
    assert json.loads((tmp_path / "manifest.json").read_text()).get("growing") is None
    with pytest.raises(OutputError, match="is not a file bgc is growing"):  # no longer growing
        append(tmp_path / "runs.csv", "3,4\n")
    artifacts.write_folder(tmp_path, folder({"runs.csv": head}, "experiment", growing=("runs.csv",), campaign="c"))
    (tmp_path / "runs.csv").write_text("\ufeff" + head + "1,2\n")  # a spreadsheet's save
    with pytest.raises(OutputError, match="is not a file bgc is growing"):
        append(tmp_path / "runs.csv", "3,4\n")
    with pytest.raises(OutputError, match="was changed after bgc wrote it"):
        artifacts.write_folder(tmp_path, folder({"runs.csv": head}, "experiment", campaign="c"))
    artifacts.write_folder(tmp_path, folder({"runs.csv": head}, "experiment", campaign="c"), adopt=("runs.csv",))
    assert (tmp_path / "runs.csv").read_text() == head


def test_write_new_never_replaces_anything(tmp_path):
    path = tmp_path / "set-aside.csv"
    artifacts.write_new(path, "lines\n")
    with pytest.raises(OutputError, match="exists"):
        artifacts.write_new(path, "other\n")
    assert path.read_text() == "lines\n"


# ------------------------------------------------------------------ single files
NOTES = "# My notes\nThe runs here were generated by bgc simulate; keep them.\n"


#: (A scenario's prediction with 2 runs of the detector, not the default 50: what is written is the
#: subject, not the rate.)
WRITERS = [
    ("distinguish", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--detector-runs", "2", "-o", "{out}"),
    ("distinguish", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--detector-runs", "2", "--format", "json",
     "-o", "{out}"),
    ("show", "tcg", "models/circuit.yaml", "-o", "{out}"),
    ("show", "tcg", "models/circuit.yaml", "--format", "json", "-o", "{out}"),
    ("show", "tcg", "models/circuit.yaml", "--format", "dot", "-o", "{out}"),
    ("show", "tcg", "models/circuit.yaml", "--format", "svg", "--engine", "matplotlib", "-o", "{out}"),
    ("simulate", "models/circuit.yaml", "--steps", "5", "-o", "{out}"),
    ("simulate", "models/circuit.yaml", "--steps", "5", "-o", "{dir}/run.csv", "--plot", "{out}"),
]
MENTIONS = [
    NOTES,                                                                   # the issue's case
    "# generated by bgc from models/circuit.yaml, do not edit\nmy own table\n",  # the mark, no seal
    '{\n  "generated_by": "bgc",\n  "mine": 1\n}\n',                          # JSON mark, no seal
    '{\n  "mine": {\n    "generated_by": "bgc"\n  }\n}\n',                    # the key, nested
    "<!-- generated by bgc -->\n<svg/>\n",
    "x\n# generated by bgc sha256=" + "0" * 64 + "\n",                       # a seal, not on the first line
    "<!DOCTYPE html>\n<!-- generated by bgc from m.yaml, do not edit -->\n<p>mine</p>\n",  # HTML mark, no seal
]


@pytest.mark.parametrize("args, text", [(a, NOTES) for a in WRITERS] + [(WRITERS[2], t) for t in MENTIONS[1:]])
def test_a_users_file_that_mentions_bgc_is_not_overwritten(tmp_path, args, text):
    """Every command that writes a single output, on the issue's notes; every
    kind of mention, on one command (ownership is one function for all)."""
    out = tmp_path / "notes.md"
    out.write_text(text)
    r = bgc(*[a.format(out=out, dir=tmp_path) for a in args])
    assert one_line(r) == f"{out} exists and bgc did not write it (choose another output path, or move the file away)"
    assert out.read_text() == text


@pytest.mark.parametrize("text", MENTIONS)
def test_no_mention_of_bgc_makes_a_file_bgc_s(tmp_path, text):
    path = tmp_path / "f"
    path.write_text(text)
    assert artifacts.ownership(path) == "other"


@pytest.mark.parametrize("args, name", [
    (("distinguish", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--detector-runs", "2", "--format", "json",
      "-o"), "d.json"),
    (("show", "tcg", "models/circuit.yaml", "-o"), "tcg.txt"),
    (("show", "dbn", "models/circuit.yaml", "--format", "png", "--engine", "matplotlib", "-o"), "dbn.png"),
    (("show", "tcg", "models/circuit.yaml", "--format", "svg", "--engine", "matplotlib", "-o"), "tcg.svg"),
    (("simulate", "models/circuit.yaml", "--steps", "5", "-o"), "run.csv"),
])
def test_bgc_rewrites_its_own_output_but_not_once_edited(tmp_path, args, name):
    out = tmp_path / name
    for _ in range(2):
        r = bgc(*args, str(out))
        assert r.returncode == 0, r.stderr
        assert artifacts.ownership(out) == "bgc"
    if name.endswith(".json"):
        data = json.loads(out.read_text())
        assert data["generated_by"] == "bgc" and len(data["bgc_sha256"]) == 64
    data = out.read_bytes()
    edited = data[:-20] + bytes([data[-20] ^ 1]) + data[-19:]  # one bit, far from the seal
    out.write_bytes(edited)
    assert artifacts.ownership(out) == "changed"
    line = one_line(bgc(*args, str(out)))
    assert line == f"{out} was changed after bgc wrote it (move it away to keep it, or choose another output path)"
    assert out.read_bytes() == edited


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_pictures_carry_the_mark_and_seal_and_stay_valid(fmt):
    """The mark and seal are PNG text chunks (with their CRC) after the
    header chunk, or an SVG comment after the XML declaration."""
    import zlib
    import xml.etree.ElementTree as ET

    from bgc.output import draw

    data = artifacts.seal(draw.tcg_picture(compiled("circuit").tcg, fmt, "matplotlib"))
    if fmt == "svg":
        second = data.split(b"\n")[1]
        assert second.startswith(b"<!-- generated by bgc sha256=") and second.endswith(b" -->")
        assert ET.fromstring(data).tag.endswith("svg")
        return
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    pos, chunks = 8, []
    while pos < len(data):  # every chunk's CRC is right, the mark and seal follow the header
        n = int.from_bytes(data[pos:pos + 4], "big")
        kind, body, crc = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n], data[pos + 8 + n:pos + 12 + n]
        assert zlib.crc32(kind + body).to_bytes(4, "big") == crc, kind
        chunks.append((kind, body))
        pos += 12 + n
    assert chunks[0][0] == b"IHDR" and chunks[1] == (b"tEXt", b"Software\x00bgc") and chunks[-1][0] == b"IEND"
    assert chunks[2][0] == b"tEXt" and chunks[2][1].startswith(b"bgc-sha256\x00")


def test_a_png_with_the_mark_elsewhere_or_a_forged_seal_is_not_bgc_s(tmp_path):
    from bgc.output import draw
    png = draw.tcg_picture(compiled("circuit").tcg, "png", "matplotlib")
    plain = png[:33] + png[33 + 12 + len(b"Software\x00bgc"):]  # the picture without bgc's chunk
    path = tmp_path / "p.png"
    path.write_bytes(plain[:-12] + artifacts._png_chunk(b"tEXt", b"Software\x00bgc") + plain[-12:])  # at the end
    assert artifacts.ownership(path) == "other"
    sealed = artifacts.seal(png)
    forged = sealed.replace(sealed[sealed.index(b"bgc-sha256\x00") + 11:][:64], b"0" * 64)
    path.write_bytes(forged)
    assert artifacts.ownership(path) in ("changed", "other")
    path.write_bytes(sealed)
    assert artifacts.ownership(path) == "bgc"


@given(st.sampled_from(["# generated by bgc from m.yaml, do not edit", "// generated by bgc from m",
                        "% generated by bgc from m", "{\n  \"generated_by\": \"bgc\",",
                        "<?xml version=\"1.0\"?>\n<!-- generated by bgc -->", "<!-- generated by bgc -->"]),
       st.text(st.characters(blacklist_categories=("Cs",)), max_size=200), st.data())
def test_a_sealed_output_is_bgc_s_until_any_byte_changes(tmp_path_factory, head, body, data):
    content = head + "\n" + body
    sealed = artifacts.seal(content)
    path = tmp_path_factory.mktemp("seal") / "out"
    path.write_bytes(sealed)
    assert artifacts.ownership(path) == "bgc"
    i = data.draw(st.integers(0, len(sealed) - 1))
    flip = data.draw(st.integers(1, 255))
    changed = sealed[:i] + bytes([sealed[i] ^ flip]) + sealed[i + 1:]
    path.write_bytes(changed)
    assert artifacts.ownership(path) != "bgc"
    path.write_bytes(sealed + b"x")  # and a byte more
    assert artifacts.ownership(path) != "bgc"


def test_text_without_the_mark_in_place_cannot_be_sealed():
    with pytest.raises(InternalError):
        artifacts.seal("my notes\n# generated by bgc\n")


def test_a_link_or_a_folder_is_never_written_through(tmp_path):
    target = tmp_path / "target.csv"
    r = bgc("simulate", "models/circuit.yaml", "--steps", "5", "-o", str(target))
    assert r.returncode == 0, r.stderr
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    before = target.read_bytes()
    assert one_line(bgc("simulate", "models/circuit.yaml", "--steps", "6", "-o", str(link))).startswith(
        f"{link} exists and bgc did not write it")
    assert target.read_bytes() == before
    assert one_line(bgc("simulate", "models/circuit.yaml", "--steps", "6", "-o", str(tmp_path))).startswith(
        f"{tmp_path} is a folder")


def test_a_growing_file_is_checked_again_when_something_else_wrote_it(tmp_path):
    head = "# generated by bgc experiment from c.yaml\nid,x\n"
    artifacts.write_folder(tmp_path, folder({"runs.csv": head}, "experiment", growing=("runs.csv",), campaign="c"))
    path = tmp_path / "runs.csv"
    with artifacts.GrowingFile(path) as runs:
        runs.append("1,2\n")
        with open(path, "a") as f:  # another program appends: the start is still bgc's
            f.write("3,4\n")
        runs.append("5,6\n")
        path.write_text("my own table\n")  # another program replaces it
        with pytest.raises(OutputError, match="is not a file bgc is growing"):
            runs.append("7,8\n")
    assert path.read_text() == "my own table\n"


def test_a_link_on_the_way_to_a_listed_file_is_never_followed(tmp_path):
    """A manifest listing lnk/o.txt, lnk a link to a folder outside: the file
    there keeps its content, whatever hash the manifest gives it."""
    import hashlib

    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "o.txt").write_text("secret\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "lnk").symlink_to(victim)
    digest = hashlib.sha256(b"secret\n").hexdigest()
    (out / "manifest.json").write_text(json.dumps({"generated_by": "bgc", "command": "diagnose",
                                                   "files": {"lnk/o.txt": digest}}))
    artifacts.write_folder(out, folder({"a.txt": "one\n"}))  # lnk/o.txt is not to be written: left alone
    assert (victim / "o.txt").read_text() == "secret\n"
    with pytest.raises(OutputError, match="behind a link"):
        artifacts.write_folder(out, folder({"lnk/o.txt": "bgc's\n"}))
    assert (victim / "o.txt").read_text() == "secret\n"


def test_a_compiled_folder_whose_subfolder_became_a_link_is_refused(tmp_path):
    model = tmp_path / "circuit.yaml"
    model.write_text(CIRCUIT)
    assert bgc("compile", str(model), "-o", str(tmp_path / "gen"), "--no-pictures").returncode == 0
    elsewhere = tmp_path / "elsewhere"
    (tmp_path / "gen" / "circuit" / "dbn").rename(elsewhere)
    (tmp_path / "gen" / "circuit" / "dbn").symlink_to(elsewhere)
    before = snapshot(elsewhere)
    model.write_text(CIRCUIT.replace("  R1: [abrupt, incipient]\n", ""))
    line = one_line(bgc("compile", str(model), "-o", str(tmp_path / "gen"), "--no-pictures"))
    assert "behind a link" in line
    assert snapshot(elsewhere) == before


def test_outputs_get_the_mode_a_plain_write_gives(tmp_path):
    import stat as st

    old = os.umask(0o022)
    try:
        artifacts.write_file(tmp_path / "a.txt", "# generated by bgc from m\nx\n")
        assert st.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644
        (tmp_path / "a.txt").chmod(0o640)
        artifacts.write_file(tmp_path / "a.txt", "# generated by bgc from m\ny\n")  # a replaced file keeps its mode
        assert st.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o640
        artifacts.write_folder(tmp_path / "f", folder({"b.txt": "one\n"}))
        assert st.S_IMODE((tmp_path / "f" / "b.txt").stat().st_mode) == 0o644
    finally:
        os.umask(old)


def test_an_html_page_is_sealed_in_its_mark_comment_and_its_edits_are_seen(tmp_path):
    """An HTML page's mark is a comment after its doctype line (a comment
    before it is allowed, but the doctype first is what every page does);
    the seal goes inside that comment, which the model's path cannot close."""
    text = artifacts.mark_text("<!DOCTYPE html>\n<html><body><p>report</p></body></html>\n", "html",
                               "odd --> <b>path</b>.yaml")
    head = text.split("\n")
    assert head[0] == "<!DOCTYPE html>" and head[1].startswith("<!-- generated by bgc from ")
    assert head[1].endswith(", do not edit -->") and head[1].count("-->") == 1
    page = tmp_path / "report.html"
    artifacts.write_file(page, text)
    sealed = page.read_text()
    assert sealed.split("\n")[1].endswith(" -->") and " sha256=" in sealed.split("\n")[1]
    assert sealed.replace(sealed.split("\n")[1], head[1]) == text  # the seal is all that was added
    assert artifacts.ownership(page) == "bgc"
    artifacts.write_file(page, text.replace("report", "again"))  # bgc's own: replaced
    assert artifacts.ownership(page) == "bgc"
    page.write_text(page.read_text().replace("again", "edited"))
    assert artifacts.ownership(page) == "changed"
    with pytest.raises(OutputError, match="was changed after bgc wrote it"):
        artifacts.write_file(page, text)
    page.write_text(sealed.replace("<!DOCTYPE html>\n", ""))  # the comment without the doctype before it
    assert artifacts.ownership(page) == "other"


def test_distinguish_refuses_a_users_file_before_it_computes(tmp_path, monkeypatch):
    """The report and the plot are checked before the prediction and the
    detector runs (minutes on a big plant), not after them."""
    from bgc import api as public

    def never(*args, **kwargs):
        raise AssertionError("the prediction ran before the output was checked")

    monkeypatch.setattr(public, "distinguishability", never)
    for flag, name in (("-o", "notes.md"), ("--plot", "mine.png")):
        out = tmp_path / name
        out.write_text(NOTES)
        r = bgc("distinguish", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", flag, str(out))
        assert one_line(r) == f"{out} exists and bgc did not write it (choose another output path, or move the file away)"
        assert out.read_text() == NOTES
