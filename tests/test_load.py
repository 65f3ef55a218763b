"""The loader: YAML text -> RawModel with the line and column of every node.

Expected locations are counted by hand from the YAML texts below (lines and
columns from 1).
"""

import time

import pytest

from bgc.errors import BgcError, ErrorGroup, LoadError, SourceLoc
from bgc.compiler.load import MAX_BYTES, load, loads

MODEL = """\
name: rc
parameters:
  R: {value: 1.0, unit: ohm}
  C: 2.0
elements:
  V: {kind: Se, value: "2*R"}
  j: {kind: "1"}
  R:
    kind: R
    description: load
bonds:
  1: [V, j]
  10: [j, R]
"""


def errors_of(exc: BgcError) -> tuple[BgcError, ...]:
    return exc.errors if isinstance(exc, ErrorGroup) else (exc,)


def load_error(text: str, name: str = "m.yaml") -> tuple[BgcError, ...]:
    with pytest.raises(BgcError) as info:
        loads(text, name)
    errs = errors_of(info.value)
    assert all(isinstance(e, LoadError) for e in errs)
    assert all("\n" not in e.line() for e in errs), "a user error is one line"
    return errs


# ----------------------------------------------------------------- plain data
def test_data_is_json_like_with_keys_as_written():
    raw = loads(MODEL, "m.yaml")
    assert raw.path == "m.yaml"
    assert raw.data["parameters"] == {"R": {"value": 1.0, "unit": "ohm"}, "C": 2.0}
    assert raw.data["elements"]["j"] == {"kind": "1"}  # a quoted "1" stays text
    assert raw.data["bonds"] == {"1": ["V", "j"], "10": ["j", "R"]}  # bond keys are text
    assert list(raw.data["bonds"]) == ["1", "10"]  # in file order
    assert isinstance(raw.data["parameters"]["C"], float)


def test_locations_of_nested_nodes():
    raw = loads(MODEL, "m.yaml")
    at = lambda line, col: SourceLoc("m.yaml", line, col)  # noqa: E731
    assert raw.loc() == at(1, 1)                                 # the root mapping
    assert raw.loc("name") == at(1, 7)                           # 'rc'
    assert raw.loc("parameters", "R") == at(3, 6)                # '{value: ...'
    assert raw.loc("parameters", "R", "value") == at(3, 14)      # '1.0'
    assert raw.loc("parameters", "R", "unit") == at(3, 25)       # 'ohm'
    assert raw.loc("elements", "V", "value") == at(6, 24)        # '"2*R"' (the quote)
    assert raw.loc("elements", "R", "kind") == at(9, 11)         # block mapping value
    assert raw.loc("elements", "R", "description") == at(10, 18)
    assert raw.loc("bonds", "10") == at(13, 7)                   # '[j, R]'
    assert raw.loc("bonds", "10", 0) == at(13, 8)                # 'j'
    assert raw.loc("bonds", "10", 1) == at(13, 11)               # 'R'


def test_key_locations():
    raw = loads(MODEL, "m.yaml")
    assert raw.key_loc("parameters") == SourceLoc("m.yaml", 2, 1)
    assert raw.key_loc("parameters", "C") == SourceLoc("m.yaml", 4, 3)
    assert raw.key_loc("elements", "R") == SourceLoc("m.yaml", 8, 3)
    assert raw.key_loc("elements", "R", "description") == SourceLoc("m.yaml", 10, 5)
    assert raw.key_loc("bonds", "10") == SourceLoc("m.yaml", 13, 3)
    # a list item has no key: its own location is used
    assert raw.key_loc("bonds", "1", 1) == SourceLoc("m.yaml", 12, 10)  # the j of [V, j]


def test_loc_of_a_missing_node_is_its_deepest_existing_ancestor():
    raw = loads(MODEL, "m.yaml")
    assert raw.loc("elements", "R", "parameter") == raw.loc("elements", "R") == SourceLoc("m.yaml", 9, 5)
    assert raw.loc("nowhere", "at", "all") == SourceLoc("m.yaml", 1, 1)


def test_load_names_locations_after_the_path(tmp_path):
    path = tmp_path / "rc.yaml"
    path.write_text(MODEL, encoding="utf-8")
    raw = load(path)
    assert raw.path == str(path)
    assert raw.loc("bonds", "10") == SourceLoc(str(path), 13, 7)


# ------------------------------------------------------------ duplicate keys
def test_duplicate_element_name_is_an_error_at_the_second_key():
    text = "elements:\n  R: {kind: R}\n  C: {kind: C}\n  R: {kind: I}\n"
    (err,) = load_error(text)
    assert err.loc == SourceLoc("m.yaml", 4, 3)
    assert "duplicate key 'R'" in err.what and "first at line 2" in err.what


def test_every_duplicate_key_is_reported():
    text = "bonds:\n  1: [a, b]\n  2: [b, c]\n  1: [c, d]\nbonds: {}\nparameters: {k: 1, k: 2}\n"
    errs = load_error(text)
    assert [(e.loc.line, e.loc.col) for e in errs] == [(4, 3), (5, 1), (6, 20)]
    assert ["'1'" in errs[0].what, "'bonds'" in errs[1].what, "'k'" in errs[2].what] == [True] * 3


def test_same_name_in_different_mappings_is_not_a_duplicate():
    raw = loads("parameters: {R: 1.0}\nelements: {R: {kind: R}}\n")
    assert raw.data["parameters"]["R"] == 1.0 and raw.data["elements"]["R"] == {"kind": "R"}


# ------------------------------------------------------------- broken files
@pytest.mark.parametrize("text", ["", "   \n\n", "# only a comment\n"])
def test_empty_file(text):
    (err,) = load_error(text)
    assert err.loc == SourceLoc("m.yaml", 1, 1) and "empty" in err.what


def test_non_utf8_file(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: rc\ndescription: résistance\n".encode("latin-1"))
    with pytest.raises(LoadError) as info:
        load(path)
    assert info.value.loc == SourceLoc(str(path), 1, 1)
    assert "not UTF-8" in info.value.what
    assert "byte 23" in info.value.what  # offset of the é: 'name: rc\n' is 9 bytes, 'description: r' 14


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(LoadError) as info:
        load(path)
    assert "no such file" in info.value.line() and str(path) in info.value.line()


def test_directory_is_not_a_model(tmp_path):
    with pytest.raises(LoadError) as info:
        load(tmp_path)
    assert info.value.line() == f"{tmp_path}: not a regular file (give a model file (YAML))"


def test_too_large_file_is_refused_before_parsing(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_bytes(b"# " + b"x" * MAX_BYTES + b"\nname: rc\n")
    with pytest.raises(LoadError) as info:
        load(path)
    assert f"more than {MAX_BYTES}" in info.value.line()


@pytest.mark.parametrize("text, line, col, problem", [
    # a tab cannot indent YAML: reported where the tab is
    ("name: rc\nparameters:\n\tR: 1.0\n", 3, 1, "found character '\\t' that cannot start any token"),
    # 'C' indented deeper than 'R' continues the plain scalar '1.0', so its ':' is out of place
    ("parameters:\n  R: 1.0\n   C: 2.0\n", 3, 5, "mapping values are not allowed here"),
    # a second document
    ("name: a\n---\nname: b\n", 2, 1, "found another document"),
])
def test_yaml_syntax_error_location(text, line, col, problem):
    (err,) = load_error(text)
    assert err.loc == SourceLoc("m.yaml", line, col)
    assert err.what.startswith("YAML syntax error") and problem in err.what


def test_mapping_key_must_be_a_scalar():
    (err,) = load_error("elements:\n  ? [a, b]\n  : 1\n")
    assert err.loc == SourceLoc("m.yaml", 2, 5) and "keys must be plain" in err.what


def test_bad_scalar_value_is_a_load_error_not_a_crash():
    # looks like a date to YAML, but month 13 does not exist
    (err,) = load_error("name: rc\ndescription: 2024-13-45\n")
    assert err.loc == SourceLoc("m.yaml", 2, 14) and "bad value" in err.what


# --------------------------------------------------------- hostile documents
LAUGHS = "\n".join(
    ["a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    + [f"{c}: &{c} [{', '.join(['*' + p] * 10)}]" for p, c in zip("abcdefgh", "bcdefghi")]
) + "\n"  # 10**9 'lol' once expanded


def test_alias_blow_up_is_refused_quickly():
    start = time.perf_counter()
    (err,) = load_error(LAUGHS)
    assert time.perf_counter() - start < 10
    assert "YAML nodes" in err.what and "aliases" in err.line()


def test_a_few_aliases_are_fine():
    raw = loads("base: &b {value: 1.0}\nparameters: {R: *b, C: *b}\n")
    assert raw.data["parameters"] == {"R": {"value": 1.0}, "C": {"value": 1.0}}


@pytest.mark.parametrize("text", ["a: &x [1, *x]\n", "a: &x {b: *x}\n"])
def test_recursive_alias_is_refused(text):
    (err,) = load_error(text)
    assert "recursive" in err.what


@pytest.mark.parametrize("depth", [400, 1000])  # past the walker, past the composer
def test_deep_nesting_is_a_load_error_not_a_recursion_error(depth):
    (err,) = load_error("a: " + "[" * depth + "]" * depth + "\n")
    assert "nested too deeply" in err.what


@pytest.mark.parametrize("tagged, line, col", [
    ('!!python/object/apply:os.system ["touch {s}"]', 1, 4),
    ("!!python/object/apply:os.system\n  args: ['touch {s}']", 1, 4),
    ("!!python/object/new:subprocess.check_output [['touch', '{s}']]", 1, 4),
    ("!!python/name:os.system", 1, 4),
    ("!!python/module:os", 1, 4),
    ("{{R: !!python/object/apply:os.system ['touch {s}']}}", 1, 8),
])
def test_python_tags_are_refused_and_never_run(tmp_path, tagged, line, col):
    sentinel = tmp_path / "SENTINEL"
    (err,) = load_error("x: " + tagged.format(s=sentinel) + "\n")
    assert err.loc == SourceLoc("m.yaml", line, col)
    assert "python/" in err.what
    assert not sentinel.exists()


def test_load_of_a_file_with_a_python_tag_does_not_run_it(tmp_path):
    sentinel = tmp_path / "SENTINEL"
    path = tmp_path / "evil.yaml"
    path.write_text(f"name: !!python/object/apply:os.system ['touch {sentinel}']\n", encoding="utf-8")
    with pytest.raises(BgcError):
        load(path)
    assert not sentinel.exists()


# --------------------------------------------------------- special characters
@pytest.mark.parametrize("text, line, col, char", [
    ("name: rc\nfaults: {R: [abrupt]}\n\0", 3, 1, "#x0000 (NUL)"),       # the fuzzer's file: NUL at the end
    ("name: rc\ndescription: R\0C\n", 2, 15, "#x0000 (NUL)"),
    ("name: rc\r\ndescription: \x07\r\n", 2, 14, "#x0007"),              # CRLF is one line break
    ("name: rc\rdescription: \x1b\r", 2, 14, "#x001b"),                  # so is a lone CR, for YAML
    ("\ufeffname: \x00\n", 1, 7, "#x0000 (NUL)"),                        # a BOM is no column, as in YAML's marks
])
def test_a_special_character_is_a_one_line_error_at_its_place(text, line, col, char):
    (err,) = load_error(text)
    assert err.loc == SourceLoc("m.yaml", line, col)
    assert err.what == f"character {char} is not allowed in YAML"
    assert err.fix and "delete it" in err.fix


def test_a_nul_byte_in_a_file(tmp_path):
    path = tmp_path / "nul.yaml"
    path.write_bytes(b"name: rc\nparameters: {R: 1.0}\n\x00\n")
    with pytest.raises(LoadError) as info:
        load(path)
    assert info.value.line() == (f"{path}:3:1: character #x0000 (NUL) is not allowed in YAML "
                                 "(delete it: a model file is plain text)")


def test_any_other_yaml_error_is_one_line_with_a_place_and_a_fix(monkeypatch):
    import yaml

    def broken(*args, **kwargs):
        raise yaml.YAMLError("something odd\n  in \"<unicode string>\", position 3")

    from bgc.compiler import load as load_module

    monkeypatch.setattr(load_module._Loader, "get_single_node", broken)
    (err,) = load_error("name: rc\n")
    assert err.line() == "m.yaml:1:1: YAML error: something odd (fix the YAML syntax: see docs/format.md)"


# ------------------------------------------------- YAML 1.2 numbers, limits
def test_numbers_are_read_as_yaml_1_2_reads_them():
    """PyYAML (YAML 1.1) reads 1e5 as text; every SI-unit plant writes it so.
    Quoted, a number stays text (the validator then says to drop the quotes)."""
    raw = loads("a: [1e5, 2.5e-3, 1E+3, -.5, +3e0, 7, 1.5]\nb: '1e5'\nc: 1.2.3\nd: 0x1F\n", "m.yaml")
    assert raw.data["a"] == [1e5, 2.5e-3, 1e3, -0.5, 3.0, 7, 1.5]
    assert [type(v) for v in raw.data["a"]] == [float] * 5 + [int, float]
    assert raw.data["b"] == "1e5" and raw.data["c"] == "1.2.3" and raw.data["d"] == 31


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_a_device_or_a_fifo_is_refused_before_reading(tmp_path, special):
    """/dev/zero would be read until memory runs out, a FIFO would block
    forever: only a regular file is read, and its size is checked first."""
    import os

    path = special
    if special == "fifo":
        path = tmp_path / "model.yaml"
        os.mkfifo(path)
    with pytest.raises(LoadError) as info:
        load(path)
    assert info.value.line() == f"{path}: not a regular file (give a model file (YAML))"


@pytest.mark.parametrize("text, where, what", [
    ('d: "\\ud800"\n', "m.yaml:1:4", "text holds an invalid Unicode character"),
    ('"\\udfff": 1\n', "m.yaml:1:1", "a key holds an invalid Unicode character"),
    ('d: "\\UFFFFFFFF"\n', "m.yaml:1:7", "an escape sequence names no Unicode character"),
    ("a: {<<: 5}\n", "m.yaml:1:9", "bad merge key '<<'"),
    ("a: {<<: [1, 2]}\n", "m.yaml:1:10", "bad merge key '<<'"),
])
def test_text_that_is_not_unicode_and_bad_merges_are_located_errors(text, where, what):
    (err,) = load_error(text)
    assert err.line().startswith(f"{where}: {what}"), err.line()
