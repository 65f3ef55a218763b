"""The docs' transcripts run as printed, and no doc names a path of one machine.

A transcript is a fenced block marked ``console`` in README.md or docs/*.md.
Its lines that start with ``$ `` are commands, run from the repository root
with the virtual environment active (``bgc`` and ``python`` are the
checkout's); the lines after a command, up to the next one, are what it
prints, standard output and standard error as a terminal shows them. A
command may go on over lines ending in ``\\``, or feed a here-document
(``<<'EOF'`` ... ``EOF``).

How a command runs:

- ``bgc ARGS`` (optionally ``; echo "exit status: $?"``, and optionally fed
  by ``cat FILE |``) runs in this process, through ``bgc.cli.main``: fast;
- ``python -c CODE`` and ``python - <<'EOF'`` (a here-document) run their
  code in this process too, as ``__main__``: no interpreter started;
- anything else (``head``, ``grep``, ``python FILE``) runs in ``bash``.

The blocks of one document run in order in one folder (a command may read
what an earlier one wrote), which holds a link to every top-level entry of
the repository (``models``, ``docs``, ``tests``, ...): the paths read as they
do from the root, and what the commands write lands in the test's temporary
folder, never in the checkout. A document's fast blocks run on NumPy
(``BGC_BACKEND=numpy``: ``make check`` compiles no kernel), its slow test on
the compiled backend when numba is installed (conftest.FAST; a user's
install chooses it too), whose kernels the suite's lasting cache keeps from
run to run: the two backends print the same lines (tests/test_backend.py).

The printed output must equal what the command prints now, except for the
parts that vary from run to run, which are marked:

- a line ``...`` (indented or not) stands for any number of lines (none
  included);
- a duration bgc prints in seconds, ``(diagnosis 2.9 s)``, ``(63.3 s)`` or
  ``in 5.63 s``, matches any duration.

Every other character counts. The numbers are those of OpenBLAS's Haswell
kernels, which the suite asks for on any CPU that runs them (conftest.py);
other kernels may round a last digit differently.

An HTML comment on the line before a block's fence says how to run it:
``<!-- docs-test: not run: REASON -->`` (a dated benchmark, a campaign of an
hour: never), or ``<!-- docs-test: slow -->`` (more than a few seconds: only
in the test marked ``slow``, which ``make test`` runs and ``make check`` does
not). ``<!-- docs-test: all slow -->`` on a line of its own makes every block
of its document slow. A document's fast blocks run in a test of their own
(they must not read what a slow block writes); its slow test runs them all.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import pytest

from conftest import FAST

ROOT = Path(__file__).resolve().parent.parent
DOCS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))

#: A duration bgc prints: "(diagnosis 2.9 s)", "(63.3 s)", "in 5.63 s".
_DURATION = re.compile(r"(\((?:diagnosis )?|\bin )\d+(?:\.\d+)?( s\b)")
_EXIT_STATUS = '; echo "exit status: $?"'
_MARK = re.compile(r"<!--\s*docs-test:\s*(.*?)\s*-->")
_ALL_SLOW = "<!-- docs-test: all slow -->"


@dataclass(frozen=True)
class Command:
    line: int          # of the "$ " line in the document
    text: str          # the shell command, continuation lines and here-document included
    expected: tuple[str, ...]


@dataclass(frozen=True)
class Block:
    doc: Path
    line: int          # of the opening fence
    language: str
    mark: str | None   # the docs-test comment on the line before the fence: "slow", "not run: REASON"
    commands: tuple[Command, ...]

    @property
    def where(self) -> str:
        return f"{self.doc.relative_to(ROOT)}:{self.line}"


def blocks(doc: Path) -> list[Block]:
    """Every fenced block of ``doc`` with a line starting with ``$ ``."""
    lines = doc.read_text(encoding="utf-8").split("\n")
    found, i = [], 0
    while i < len(lines):
        fence = re.match(r"^(`{3,})(\w*)", lines[i])
        if not fence:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith(fence.group(1)))
        body = lines[i + 1:end]
        if any(line.startswith("$ ") for line in body):
            mark = _MARK.fullmatch(lines[i - 1].strip()) if i else None
            found.append(Block(doc, i + 1, fence.group(2), mark.group(1) if mark else None,
                               tuple(_commands(body, i + 2))))
        i = end + 1
    return found


def _commands(body: list[str], first_line: int) -> list[Command]:
    commands, k = [], 0
    while k < len(body):
        if not body[k].startswith("$ "):
            raise AssertionError(f"line {first_line + k}: output before the first command: {body[k]!r}")
        start, text = k, body[k][2:]
        while text.endswith("\\"):
            k += 1
            text += "\n" + body[k]
        heredoc = re.search(r"<<-?\s*'?(\w+)'?", text)
        if heredoc:
            while body[k] != heredoc.group(1):
                k += 1
                text += "\n" + body[k]
        k += 1
        out = k
        while k < len(body) and not body[k].startswith("$ "):
            k += 1
        commands.append(Command(first_line + start, text, tuple(body[out:k])))
    return commands


def normalise(text: str) -> list[str]:
    """Lines without trailing blanks or trailing empty lines, durations replaced."""
    lines = [_DURATION.sub(r"\1<duration>\2", line.rstrip()) for line in text.split("\n")]
    while lines and not lines[-1]:
        lines.pop()
    return lines


def matches(expected: tuple[str, ...] | list[str], actual: str) -> bool:
    """Does ``actual`` (what a command printed) match the printed ``expected``?"""
    parts = []
    for line in normalise("\n".join(expected)):
        parts.append(r"(?:[^\n]*\n)*?" if line.strip() == "..." else re.escape(line) + r"\n")
    text = "".join(line + "\n" for line in normalise(actual))
    return re.fullmatch("".join(parts), text) is not None


# ---- running a command ------------------------------------------------------------------------

_IN_PROCESS = re.compile(r"^(?:cat (?P<stdin>\S+) \| )?bgc (?P<args>[^|;&<>`$\n]*?)(?P<status>"
                         + re.escape(_EXIT_STATUS) + r")?$")


def run(command: str, cwd: Path) -> str:
    """Run one transcript command in ``cwd``; what it printed, standard error
    interleaved with standard output."""
    simple = _IN_PROCESS.match(command)
    if simple:
        return _run_in_process(shlex.split(simple["args"]), cwd, simple["stdin"], bool(simple["status"]))
    python = _PYTHON.match(command)
    if python:
        code = python["body"] if python["tag"] else shlex.split(command)[2]
        return _capture(lambda: _exec(code), cwd)[1]
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    done = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=600)
    return done.stdout


_PYTHON = re.compile(r"^python (?:-c \S.*|- <<'?(?P<tag>\w+)'?\n(?P<body>.*)\n(?P=tag))$", re.S)


def _exec(code: str) -> int:
    """Run ``code`` as ``python -c`` would: as ``__main__``, a traceback on
    standard error and status 1 when it raises."""
    try:
        exec(compile(code, "<string>", "exec"), {"__name__": "__main__"})
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    except Exception:  # what python prints, so that the transcript's comparison shows it
        traceback.print_exc()
        return 1
    return 0


def _capture(call, cwd: Path, stdin: str | None = None) -> tuple[int, str]:
    """``call()`` in ``cwd``, standard input from the file ``stdin``; its
    status and what it printed on standard output and error, interleaved."""
    out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True)
    old_cwd, old_stdin = Path.cwd(), sys.stdin
    os.chdir(cwd)
    try:
        with contextlib.ExitStack() as stack:
            if stdin is not None:
                sys.stdin = stack.enter_context(open(stdin, encoding="utf-8"))
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
                status = call()
    finally:
        sys.stdin = old_stdin
        os.chdir(old_cwd)
    out.flush()
    return status, out.buffer.getvalue().decode("utf-8")


def _run_in_process(argv: list[str], cwd: Path, stdin: str | None, status: bool) -> str:
    from bgc.cli import main

    def call() -> int:
        try:
            return main(argv)
        except SystemExit as exc:  # argparse's usage errors
            return exc.code if isinstance(exc.code, int) else 1

    code, text = _capture(call, cwd, stdin)
    if status:
        text += ("" if text.endswith("\n") or not text else "\n") + f"exit status: {code}\n"
    return text


def _checkout_view(folder: Path) -> Path:
    """``folder`` holding a link to every top-level entry of the repository."""
    for entry in ROOT.iterdir():
        if entry.name not in (".git", ".venv", "out") and not entry.name.startswith(".pytest"):
            (folder / entry.name).symlink_to(entry)
    return folder


# ---- the tests --------------------------------------------------------------------------------

def _all_slow(doc: Path) -> bool:
    return _ALL_SLOW in doc.read_text(encoding="utf-8").split("\n")


def _runs(block: Block, slow: bool) -> bool:
    return block.mark is None or (slow and block.mark == "slow")


#: A slow test's marks: it runs on the FAST backend, numba's kernels compiled or loaded when installed.
_SLOW_MARKS = [pytest.mark.slow, *([pytest.mark.numba] if FAST == "numba" else [])]


def _doc_params():
    """(document, slow): its fast blocks in a fast test, and all of them in
    a slow one when some are slow."""
    for doc in DOCS:
        found, name = blocks(doc), str(doc.relative_to(ROOT))
        if _all_slow(doc):
            if any(_runs(b, True) for b in found):
                yield pytest.param(doc, True, id=name, marks=_SLOW_MARKS)
            continue
        if any(_runs(b, False) for b in found):
            yield pytest.param(doc, False, id=name)
        if any(b.mark == "slow" for b in found):
            yield pytest.param(doc, True, id=f"{name}, with its slow blocks", marks=_SLOW_MARKS)


@pytest.mark.parametrize(("doc", "slow"), list(_doc_params()))
def test_transcripts_run_as_printed(doc: Path, slow: bool, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("BGC_BACKEND", FAST if slow else "numpy")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    folder = _checkout_view(tmp_path)
    wrong = []
    for block in blocks(doc):
        if not _runs(block, slow):
            continue
        for command in block.commands:
            actual = run(command.text, folder)
            if not matches(command.expected, actual):
                wrong.append(f"{doc.relative_to(ROOT)}:{command.line}: $ {command.text}\n"
                             f"--- printed in the doc\n" + "\n".join(command.expected)
                             + "\n--- printed now\n" + actual)
    assert not wrong, "transcripts that no longer print what the doc says:\n\n" + "\n\n".join(wrong)


def test_every_transcript_is_a_console_block_run_or_said_why_not() -> None:
    """A block with ``$ `` prompts is a ``console`` block, and one the tests
    do not run says why."""
    problems = []
    for doc in DOCS:
        for block in blocks(doc):
            if block.language != "console":
                problems.append(f"{block.where}: a block with $ prompts marked {block.language or 'nothing'!r}: "
                                "mark it console (a transcript) or drop the prompts (a list of commands)")
            if block.mark not in (None, "slow") and not re.fullmatch(r"not run: \S.*", block.mark):
                problems.append(f"{block.where}: docs-test comment {block.mark!r} before a block: write "
                                "'slow' or 'not run: REASON'")
    assert not problems, "\n".join(problems)


#: A path that exists on one machine only: a temporary folder, a home folder, a checkout's place.
_MACHINE_PATH = re.compile(r"(?<![\w.~$])(?:/(?:tmp|work|root|home|Users|mnt|private|var/folders)/"
                           r"|[A-Za-z]:\\(?:Users|Documents and Settings)\\)")


def _doc_files() -> list[Path]:
    examples = [p for p in sorted((ROOT / "docs" / "examples").rglob("*"))
                if p.is_file() and p.suffix in (".md", ".py", ".yaml", ".yml", ".csv", ".ipynb", ".txt")]
    return [*DOCS, *examples]


def test_no_doc_names_a_path_of_one_machine() -> None:
    found = []
    for path in _doc_files():
        for number, line in enumerate(path.read_text(encoding="utf-8").split("\n"), 1):
            for hit in _MACHINE_PATH.finditer(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:120]}")
    assert not found, ("paths of one machine in the docs (write a path relative to the repository "
                       "root, docs/examples/...):\n" + "\n".join(found))


# ---- the matcher can fail ---------------------------------------------------------------------

def test_the_matcher_tells_a_changed_line() -> None:
    printed = ("ro: isolated: R_pipe_abrupt", "  detected at t = 165 (F_loop), onset t = 165")
    assert matches(printed, "ro: isolated: R_pipe_abrupt\n  detected at t = 165 (F_loop), onset t = 165\n")
    assert not matches(printed, "ro: isolated: R_pipe_abrupt\n  detected at t = 166 (F_loop), onset t = 165\n")
    assert not matches(printed, "ro: isolated: R_pipe_abrupt\n")                     # a line missing
    assert not matches(printed[:1], "ro: isolated: R_pipe_abrupt\nmore\n")             # a line more


def test_the_matcher_lets_only_the_marked_parts_vary() -> None:
    printed = ("first", "...", "wrote d/: report.md (diagnosis 0.9 s)", "300 steps in 0.063 s")
    assert matches(printed, "first\na\nb\nwrote d/: report.md (diagnosis 12.25 s)\n300 steps in 7 s\n")
    assert matches(printed, "first\nwrote d/: report.md (diagnosis 1 s)\n300 steps in 0.1 s\n")
    assert not matches(printed, "first\nwrote e/: report.md (diagnosis 1 s)\n300 steps in 0.1 s\n")
    assert not matches(printed, "first\nwrote d/: report.md (diagnosis 1 s)\n301 steps in 0.1 s\n")
    assert not matches(("(true 31)",), "(true 32)\n")                                  # not a duration


def test_a_block_is_read_as_its_commands_and_their_output(tmp_path: Path) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- docs-test: all slow -->\n\ntext\n```console\n$ echo a \\\n  b\na b\n"
                   "$ cat <<'EOF'\nx\nEOF\nx\n```\n<!-- docs-test: not run: an example -->\n```console\n"
                   "$ false\n```\n<!-- docs-test: slow -->\n```console\n$ true\n```\n", encoding="utf-8")
    block, skipped, slow = blocks(doc)
    assert _all_slow(doc) and block.mark is None and skipped.mark == "not run: an example"
    assert slow.mark == "slow" and _runs(slow, True) and not _runs(slow, False) and not _runs(skipped, True)
    assert block.language == "console"
    assert [c.text for c in block.commands] == ["echo a \\\n  b", "cat <<'EOF'\nx\nEOF"]
    assert [c.expected for c in block.commands] == [("a b",), ("x",)]
    assert [run(c.text, tmp_path) for c in block.commands] == ["a b\n", "x\n"]
    assert run('python -c "print(6 * 7)"', tmp_path) == "42\n"                     # in this process
    assert run("python - <<'EOF'\nimport os\nprint(os.getcwd())\nEOF", tmp_path) == f"{tmp_path}\n"


def test_a_model_shown_in_a_doc_is_the_example_file_it_names() -> None:
    """A ``yaml`` block whose lead-in names ``docs/examples/NAME.yaml`` shows
    that file (its opening comment lines aside), so the transcripts that read
    the file read what the reader sees."""
    shown = 0
    for doc in DOCS:
        lines = doc.read_text(encoding="utf-8").split("\n")
        for i, line in enumerate(lines):
            if line != "```yaml":
                continue
            lead_in = " ".join(lines[max(0, i - 3):i])
            named = re.findall(r"`(docs/examples/[\w.-]+\.yaml)`", lead_in)
            if not named:
                continue
            end = lines.index("```", i + 1)
            text = (ROOT / named[-1]).read_text(encoding="utf-8").split("\n")
            while text and text[0].startswith("#"):
                text.pop(0)
            assert "\n".join(text).rstrip("\n") == "\n".join(lines[i + 1:end]), \
                f"{doc.relative_to(ROOT)}:{i + 1}: the block differs from {named[-1]}"
            shown += 1
    assert shown >= 2


#: Documents a link may name before they land (none now).
_PENDING: set[str] = set()


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_every_link_between_the_docs_lands() -> None:
    """Every relative link of README.md and docs/*.md names a file of the
    checkout (and, with ``#anchor``, one of its headings)."""
    broken = []
    for doc in DOCS:
        text = re.sub(r"```.*?```", "", doc.read_text(encoding="utf-8"), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue                                          # http(s), mailto
            path, _, anchor = target.partition("#")
            file = (doc.parent / path).resolve() if path else doc
            name = file.relative_to(ROOT).as_posix() if file.is_relative_to(ROOT) else str(file)
            if not file.exists():
                if name not in _PENDING:
                    broken.append(f"{doc.relative_to(ROOT)}: ({target}): no file {name}")
                continue
            if anchor and file.suffix == ".md":
                headings = [_anchor(h) for h in re.findall(r"^#+ (.*)$", file.read_text(encoding="utf-8"), re.M)]
                if anchor not in headings:
                    broken.append(f"{doc.relative_to(ROOT)}: ({target}): no heading #{anchor} in {name}")
    assert not broken, "links that land nowhere:\n" + "\n".join(broken)
