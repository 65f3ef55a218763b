"""Writes and checks ``generated/<model>/``: the only module that writes files.

:func:`write` replaces the directory's content with the compiler's output;
:func:`diff` compares what is on disk with what the compiler produces now and
returns unified diffs (used by the golden test and ``bgc compile --check``).
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Mapping


def write(directory: Path, files: Mapping[str, str | bytes], clean: bool = True) -> list[Path]:
    """Write ``files`` (relative path -> content) under ``directory``.

    With ``clean``, files that the compiler no longer produces are removed.
    """
    directory = Path(directory)
    if clean and directory.exists():
        keep = {directory / p for p in files}
        for old in sorted(directory.rglob("*"), reverse=True):
            if old.is_file() and old not in keep:
                old.unlink()
            elif old.is_dir() and not any(old.iterdir()):
                old.rmdir()
    written = []
    for rel, content in sorted(files.items()):
        path = directory / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, str):
            data = content.encode("utf-8")
        else:
            data = content
        if not path.exists() or path.read_bytes() != data:
            path.write_bytes(data)
        written.append(path)
    return written


def write_file(path: Path, content: str | bytes) -> Path:
    """Write one file (``bgc show -o``, ``bgc simulate -o``)."""
    path = Path(path)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(content.encode("utf-8") if isinstance(content, str) else content)
    return path


def diff(directory: Path, files: Mapping[str, str]) -> list[str]:
    """Unified diffs between ``files`` and what ``directory`` holds (empty: identical).

    Only the given (text) files are compared, plus a note for each one missing.
    """
    directory = Path(directory)
    out = []
    for rel, want in sorted(files.items()):
        path = directory / rel
        if not path.exists():
            out.append(f"missing: {path}")
            continue
        have = path.read_text(encoding="utf-8")
        if have != want:
            out.append("".join(difflib.unified_diff(have.splitlines(True), want.splitlines(True),
                                                    fromfile=f"{path} (committed)", tofile=f"{path} (compiler now)")))
    return out

