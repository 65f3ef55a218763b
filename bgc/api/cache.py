"""The compile cache: a model compiled once is reused while its file's text,
its compile options and bgc are unchanged.

An entry is named by the SHA-256 of what the compilation depends on
(:func:`key_of`): the model file's text (not its path), the prior scale,
bgc's version and the digest of bgc's own files (a checkout being edited
changes its code under one version), and the versions of Python, NumPy and
SymPy. It holds what the runtime reads: the compiled model's plain-data view
(:mod:`bgc.view`, JSON), the generated NumPy package and the compiled
package's files; a command served by it imports neither sympy nor the
compiler. Layout under :func:`~bgc.api.folders.cache_root` (``BGC_CACHE_DIR``,
else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``)::

    models/<key>/entry.json                what the entry is (bgc wrote it), read first
    models/<key>/view.json                 the view
    models/<key>/<model>/numpy_model/      the generated NumPy package
    models/<key>/<model>/numba_model/      the compiled package's files, copied to:
    packages/<model>-<digest>/<model>/numba_model/   where numba's disk cache lasts
                                           (:func:`~bgc.api.folders.lasting_folder`)
    warm/<digest>.json                     a compiled package whose kernels a warm-up
                                           put in numba's disk cache (:func:`mark_warm`)

Processes share it safely: an entry is written whole into a temporary
folder beside its place and renamed into place (one atomic step: a reader
sees the whole entry or none; of two processes writing one entry, one wins
and the other drops its copy), and never changed after. An entry that
cannot be read is compiled afresh (a warning names ``bgc cache clear``);
a cache that cannot be written leaves every call compiling, as before the
cache. Nothing in it is pickled: JSON and text bgc wrote. ``bgc cache``
lists what it holds, ``bgc cache clear`` removes it: only what bgc wrote
there (:func:`clear`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import re
import shutil
import stat
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from .. import __version__
from ..ir import NUMBA_PACKAGE, PACKAGE
from ..view import CompiledView, from_json, to_json
from .folders import cache_root, lasting_folder, package_folder

if TYPE_CHECKING:
    from ..pipeline import Compiled

#: The version of an entry's layout (part of the key: another layout is another entry).
FORMAT = 1

#: The folder of :func:`cache_root` that holds the entries.
MODELS = "models"

#: The folder of :func:`cache_root` that holds the compiled packages (:func:`~bgc.api.folders.lasting_folder`).
PACKAGES = "packages"

#: The folder of :func:`cache_root` that holds the notes of compiled packages whose kernels are in numba's
#: disk cache (:func:`mark_warm`).
WARM = "warm"

#: A model file larger than this is not cached (the compiler refuses it, in its own words).
MAX_TEXT = 16 * 2**20

#: A temporary folder of an interrupted writer this old is removed by :func:`clear` (a younger one may be in use).
STALE_SECONDS = 3600

_KEY = re.compile(r"^[0-9a-f]{64}$")
_PACKAGE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*-[0-9a-f]{20}$")
_WARM_NAME = re.compile(r"^[0-9a-f]{32}\.json$")
_TEMPORARY = re.compile(r"^\.([0-9a-f]{64}|[A-Za-z_][A-Za-z0-9_]*-[0-9a-f]{20})-[A-Za-z0-9_]+$")


@dataclass(frozen=True, slots=True)
class Opened:
    """A model opened through the cache: its ``view``, the ``folder`` whose
    ``<model>/numpy_model`` is its NumPy package (the entry, or a private
    folder when the cache could not be used), the compilation when this
    call compiled (None when the cache served it), the ``entry`` (None:
    not cached) and the ``seconds`` the call took."""

    view: CompiledView
    folder: str
    compiled: Compiled | None
    entry: Path | None
    seconds: float = 0.0


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """The SHA-256 of bgc's own files (its Python modules, templates and
    schemas): a checkout being edited changes them under one version."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".j2", ".json")
                       and "__pycache__" not in p.parts):
        h.update(str(path.relative_to(root)).encode("utf-8") + b"\0")
        h.update(path.read_bytes() + b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _versions() -> tuple[str, ...]:
    """The versions a compilation depends on besides bgc's: Python's,
    NumPy's and SymPy's (read from its ``release.py``, not imported)."""
    import importlib.util

    import numpy as np

    sympy = ""
    spec = importlib.util.find_spec("sympy")
    if spec is not None and spec.origin:
        try:
            sympy = (Path(spec.origin).parent / "release.py").read_text(encoding="utf-8")
        except OSError:
            sympy = spec.origin
    return (f"{sys.version_info[0]}.{sys.version_info[1]}", np.__version__, hashlib.sha256(sympy.encode()).hexdigest())


def key_of(text: bytes, prior_scale: float = 1.0) -> str:
    """The entry's name for a model file's ``text`` compiled with ``prior_scale``."""
    parts = {"format": FORMAT, "bgc": __version__, "code": code_digest(), "versions": _versions(),
             "text": hashlib.sha256(text).hexdigest(), "prior_scale": repr(float(prior_scale))}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def _text_of(path: str) -> bytes | None:
    """The bytes of the model file at ``path`` when it is a regular file of
    UTF-8 text of at most :data:`MAX_TEXT` bytes; else None (the compiler
    says what is wrong)."""
    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_TEXT:
            return None
        with open(path, "rb") as f:
            data = f.read(MAX_TEXT + 1)
        data.decode("utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    return data if len(data) <= MAX_TEXT else None


def open_model(model: str | os.PathLike, prior_scale: float = 1.0) -> Opened:
    """The compiled model of the file ``model`` with ``prior_scale``: from
    the cache when an entry of its text, options and bgc is there, else
    compiled (and kept in the cache when it can be written).

    Raises
    ------
    BgcError
        The model's own errors (load, validation, ...), as the compiler raises them.
    """
    start = time.perf_counter()
    opened = _open(str(model), prior_scale)
    return dataclasses.replace(opened, seconds=time.perf_counter() - start)


def open_text(text: str, source: str, prior_scale: float = 1.0) -> Opened:
    """The compiled model of the model file text ``text`` (named
    ``source`` in messages: a file bgc writes, a submodel of
    ``bgc compile --decompose``), through the cache as a file of that text."""
    start = time.perf_counter()
    opened = _open(source, prior_scale, text.encode("utf-8"))
    return dataclasses.replace(opened, seconds=time.perf_counter() - start)


def _open(source: str, prior_scale: float, text: bytes | None = None) -> Opened:
    text = _text_of(source) if text is None else text
    if text is None:
        return _uncached(source, prior_scale)
    entry = cache_root() / MODELS / key_of(text, prior_scale)
    if (entry / "entry.json").exists():
        try:
            view = _read(entry, source)
        except FileNotFoundError:  # removed meanwhile (bgc cache clear): compiled again below
            pass
        except (OSError, ValueError, TypeError, KeyError) as exc:
            _warn(f"bgc's cache entry {entry} cannot be read ({type(exc).__name__}): compiling {source} afresh; "
                  "remove it with: bgc cache clear")
            return _uncached(source, prior_scale, text)
        else:
            _touch(entry)
            return Opened(view, str(entry), None, entry)
    from .. import pipeline

    c = pipeline.compile_model(source, prior_scale, text=text.decode("utf-8"))
    written = to_json(pipeline.view(c))
    try:
        _write(entry, c, written, prior_scale)
    except OSError as exc:
        _warn(f"cannot write bgc's cache in {entry.parent} ({exc.strerror or exc}): every call compiles; set "
              "BGC_CACHE_DIR to a folder you can write")
        return Opened(from_json(written, source), package_folder(c), c, None)
    return Opened(from_json(written, source), str(entry), c, entry)


def _uncached(source: str, prior_scale: float, text: bytes | None = None) -> Opened:
    """Compiled afresh, its package in a private folder (the cache not used)."""
    from .. import pipeline

    c = pipeline.compile_model(source, prior_scale, text=None if text is None else text.decode("utf-8"))
    return Opened(from_json(to_json(pipeline.view(c)), source), package_folder(c), c, None)


def _read(entry: Path, source: str) -> CompiledView:
    """The view an entry holds, checked whole (its description and its NumPy package there)."""
    meta = json.loads((entry / "entry.json").read_text(encoding="utf-8"))
    if not isinstance(meta, dict) or meta.get("generated_by") != "bgc" or meta.get("format") != FORMAT:
        raise ValueError("not an entry of this bgc")
    view = from_json((entry / "view.json").read_text(encoding="utf-8"), source)
    if not (entry / view.model.name / PACKAGE / "__init__.py").is_file():
        raise FileNotFoundError(entry / view.model.name / PACKAGE)
    return view


def _write(entry: Path, c, view_text: str, prior_scale: float) -> None:
    """Write ``c``'s entry whole (:func:`~bgc.api.folders.write_whole`); when
    another process put it there first, its copy stays."""
    from .folders import numba_digest, write_package, write_whole

    name = c.model.name
    meta = {"generated_by": "bgc", "format": FORMAT, "bgc": __version__, "model": name,
            "source": str(c.model.source), "model_sha256": c.model.source_sha256, "prior_scale": float(prior_scale),
            "numba": numba_digest(c)}

    def fill(fresh: Path) -> None:
        write_package(fresh / name / PACKAGE, c.package.files)
        write_package(fresh / name / NUMBA_PACKAGE, c.package.numba_files)
        (fresh / "view.json").write_text(view_text, encoding="utf-8")
        (fresh / "entry.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")

    write_whole(entry, fill)


def numba_folder(opened: Opened) -> str:
    """The lasting folder of the opened model's compiled package
    (:func:`~bgc.api.folders.lasting_folder`), made from the entry's copy of
    it when it is missing."""
    if opened.entry is None:
        from .folders import _lasting_folder

        return _lasting_folder(opened.compiled)
    meta = json.loads((opened.entry / "entry.json").read_text(encoding="utf-8"))
    name = opened.view.model.name
    package = opened.entry / name / NUMBA_PACKAGE
    files = [(p.name, p.read_text(encoding="utf-8")) for p in sorted(package.glob("*.py"))]
    return lasting_folder(str(meta["numba"]), name, files)


def numba_path(opened: Opened) -> Path:
    """Where :func:`numba_folder` has (or will have) the opened model's
    compiled package, ``<folder>/<model>/numba_model``, without making it."""
    if opened.entry is None:
        from .folders import numba_digest

        name = numba_digest(opened.compiled)
    else:
        name = str(json.loads((opened.entry / "entry.json").read_text(encoding="utf-8"))["numba"])
    return cache_root() / PACKAGES / name / opened.view.model.name / NUMBA_PACKAGE


def _warm_note(package: Path) -> Path:
    return cache_root() / WARM / (hashlib.sha256(str(package.resolve()).encode()).hexdigest()[:32] + ".json")


def _stamps(package: Path) -> dict | None:
    """What a note of :func:`mark_warm` must find unchanged: the compiled
    package (its path, its ``__init__.py``'s size and time) and numba's
    installation (its ``__init__.py``'s path, size and time)."""
    import importlib.util

    spec = importlib.util.find_spec("numba")
    try:
        init = (package / "__init__.py").stat()
        numba = os.stat(spec.origin) if spec is not None and spec.origin else None
    except OSError:
        return None
    if numba is None:
        return None
    return {"package": str(package.resolve()), "init": [init.st_size, init.st_mtime_ns],
            "numba": [spec.origin, numba.st_size, numba.st_mtime_ns]}


def mark_warm(package: str | os.PathLike, kernels: int) -> None:
    """Note that the kernels of the compiled package folder ``package``
    (``.../<model>/numba_model``) are in numba's disk cache: a warm-up
    compiled or loaded them (``kernels``). ``--backend auto`` reads it
    (:func:`kernels_cached`) without importing numba. Written to a
    temporary name and renamed into place; a cache that cannot be written
    keeps no note."""
    package = Path(package)
    stamps = _stamps(package)
    if stamps is None:
        return
    note = _warm_note(package)
    try:
        note.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".", suffix=".json", dir=note.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({"generated_by": "bgc", **stamps, "kernels": int(kernels)}, f)
        os.replace(tmp, note)
    except OSError:
        pass


def kernels_cached(package: str | os.PathLike) -> bool:
    """Whether a warm-up noted (:func:`mark_warm`) the kernels of the compiled
    package folder ``package`` in numba's disk cache, the package and numba
    unchanged since. (numba's cache emptied by hand is not seen: the next
    warm-up compiles them again.)"""
    package = Path(package)
    try:
        note = json.loads(_warm_note(package).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    stamps = _stamps(package)
    return isinstance(note, dict) and stamps is not None and all(note.get(k) == v for k, v in stamps.items())


def compiled_again(model: str, prior_scale: float, view: CompiledView):
    """Every IR of the model a cached view was read from (the compiler and
    sympy imported now), its text checked to be the one the view has.

    Raises
    ------
    BgcError
        The model file changed since it was opened, or its own errors.
    """
    from .. import pipeline
    from ..errors import ArgumentValueError, printable

    c = pipeline.compile_model(model, prior_scale)
    if c.model.source_sha256 != view.model.source_sha256:
        raise ArgumentValueError(f"{printable(model)} changed since it was opened", None,
                                 "open the model again (bgc.open)")
    return c


def _touch(entry: Path) -> None:
    """Mark an entry used now (its ``entry.json``'s time: :func:`items` shows it)."""
    try:
        os.utime(entry / "entry.json")
    except OSError:
        pass


def _warn(message: str) -> None:
    warnings.warn(message, CacheWarning, stacklevel=3)


class CacheWarning(UserWarning):
    """The compile cache could not be used; the call went on without it."""


# --------------------------------------------------------------- list and clear
@dataclass(frozen=True, slots=True)
class Item:
    """One thing bgc wrote in its cache: ``kind`` ``model`` (an entry),
    ``package`` (a compiled package, numba's disk cache beside it) or
    ``unfinished`` (a temporary folder of an interrupted writer);
    ``model``: the model's name; ``bytes`` on disk; ``used``: when it was
    last written or used (seconds since the epoch); ``details``: the model
    file an entry was compiled from, its text's SHA-256 and prior scale."""

    kind: str
    path: Path
    model: str
    bytes: int
    used: float
    details: str = ""


def items(root: Path | None = None) -> list[Item]:
    """What bgc wrote in its cache (``root``, default :func:`cache_root`):
    entries, compiled packages, unfinished temporary folders. A file or
    folder it did not write (not named and made as bgc names and makes them)
    is not listed, and never removed."""
    root = cache_root() if root is None else root
    found = []
    for path in _children(root / MODELS):
        if _KEY.match(path.name) and path.is_dir() and not path.is_symlink():
            meta = _meta(path)
            if meta is not None:
                details = (f"from {meta.get('source', '?')}, text {str(meta.get('model_sha256', ''))[:12]}, "
                           f"prior scale {meta.get('prior_scale', '?')}")
                found.append(Item("model", path, str(meta.get("model", "?")), _size(path),
                                  _mtime(path / "entry.json"), details))
        elif _TEMPORARY.match(path.name) and path.is_dir() and not path.is_symlink():
            found.append(Item("unfinished", path, "", _size(path), _mtime(path)))
    for path in _children(root / PACKAGES):
        if _PACKAGE_NAME.match(path.name) and path.is_dir() and not path.is_symlink():
            model = path.name.rsplit("-", 1)[0]
            if _generated(path / model / NUMBA_PACKAGE / "__init__.py"):
                found.append(Item("package", path, model, _size(path), _mtime(path)))
        elif _TEMPORARY.match(path.name) and path.is_dir() and not path.is_symlink():
            found.append(Item("unfinished", path, "", _size(path), _mtime(path)))
    for path in _children(root / WARM):
        if _WARM_NAME.match(path.name) and path.is_file() and not path.is_symlink():
            try:
                note = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if isinstance(note, dict) and note.get("generated_by") == "bgc":
                found.append(Item("note", path, "", _size(path), _mtime(path), f"{note.get('package', '?')}"))
    return sorted(found, key=lambda i: (i.kind, i.model, -i.used))


def clear(root: Path | None = None, unused_for: float | None = None) -> list[Item]:
    """Remove what :func:`items` lists (an unfinished folder only once it is
    :data:`STALE_SECONDS` old: a younger one may be being written; with
    ``unused_for``, only what was last used that many seconds ago or more),
    then the ``models`` and ``packages`` folders if nothing else is left in
    them; what was removed. Nothing else under the cache folder is touched."""
    root = cache_root() if root is None else root
    removed = []
    now = time.time()
    for item in items(root):
        if item.kind == "unfinished" and now - item.used < STALE_SECONDS:
            continue
        if unused_for is not None and now - item.used < unused_for:
            continue
        if item.kind == "note":
            try:
                item.path.unlink()
            except OSError:
                pass
        else:
            shutil.rmtree(item.path, ignore_errors=True)
        if not item.path.exists():
            removed.append(item)
    for folder in (root / MODELS, root / PACKAGES, root / WARM):
        try:
            folder.rmdir()  # only when empty
        except OSError:
            pass
    return removed


def _children(folder: Path) -> list[Path]:
    try:
        return sorted(folder.iterdir())
    except OSError:
        return []


def _meta(entry: Path) -> dict | None:
    """An entry's ``entry.json`` when bgc wrote it (else None)."""
    try:
        meta = json.loads((entry / "entry.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) and meta.get("generated_by") == "bgc" else None


def _generated(init: Path) -> bool:
    """Whether a package's ``__init__.py`` is one bgc generated (its first line says so)."""
    try:
        with open(init, encoding="utf-8") as f:
            return f.readline().startswith("# generated by bgc from ")
    except (OSError, UnicodeDecodeError):
        return False


def _size(folder: Path) -> int:
    """The bytes of a file, or of the files under a folder."""
    if folder.is_file():
        try:
            return folder.stat().st_size
        except OSError:
            return 0
    total = 0
    for dirpath, _, files in os.walk(folder):
        for name in files:
            try:
                total += os.lstat(os.path.join(dirpath, name)).st_size
            except OSError:
                pass
    return total


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
