"""Private folders: a session's compilation and generated package, removed at exit; and bgc's lasting cache of compiled packages."""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import threading
from pathlib import Path


from typing import TYPE_CHECKING

from .. import arguments
from ..ir import NUMBA_PACKAGE, PACKAGE

if TYPE_CHECKING:
    from .. import pipeline


#: The compile cache, the private folders and the package imports are shared
#: by the threads of a process (a Dask worker runs several tasks at once).
_LOCK = threading.RLock()


def private_folder(prefix: str) -> str:
    """A new temporary folder of this process, removed when it exits: at
    interpreter exit, or at the end of a multiprocessing worker (which skips
    atexit handlers).

    Raises
    ------
    ArgumentTypeError
        ``prefix`` is not a string.
    """
    import secrets
    from multiprocessing import util

    arguments.text("bgc.api.folders.private_folder", "prefix", prefix)

    base = tempfile.gettempdir()
    with _FOLDER_LOCK:  # an orphaned campaign worker removes its folders under it (remove_private_folders)
        for _ in range(100):
            folder = os.path.join(base, prefix + secrets.token_hex(6))
            # named before it is made: a worker ended between the two (SIGTERM when its campaign dies)
            # removes it all the same
            _FOLDERS.append((os.getpid(), folder))
            try:
                os.mkdir(folder, 0o700)  # as tempfile.mkdtemp: a new folder, this user's only
            except FileExistsError:
                _FOLDERS.pop()
                continue
            break
        else:
            raise FileExistsError(f"no free name for a private folder in {base}")
        atexit.register(shutil.rmtree, folder, True)
        util.Finalize(None, shutil.rmtree, args=(folder, True), exitpriority=0)
    return folder


#: The private folders of this process and of the process it was forked from: (pid, path).
_FOLDERS: list[tuple[int, str]] = []


_FOLDER_LOCK = threading.RLock()


def _new_folder_lock() -> None:  # a forked child starts with its own lock, free, whoever held its parent's
    global _FOLDER_LOCK
    _FOLDER_LOCK = threading.RLock()


def remove_private_folders() -> None:
    """Remove this process's private folders now (a campaign worker whose
    campaign has died, ending at once: :func:`bgc.experiment.dispatch._orphaned`).
    Under the lock :func:`private_folder` takes, so no folder is being made
    meanwhile; a folder named but not yet made is simply absent."""
    with _FOLDER_LOCK:
        for pid, folder in _FOLDERS:
            if pid == os.getpid():
                shutil.rmtree(folder, True)


def _compiled(model: str | Path, prior_scale: float = 1.0) -> tuple[pipeline.Compiled, str]:
    """Compile ``model`` (its priors widened by ``prior_scale``) and write
    its generated package into a new private folder of this process: (the
    compiled model, the folder). Nothing is kept between calls: a
    :class:`Session` holds what one model needs (the compile cache,
    :mod:`bgc.api.cache`, keeps it from process to process)."""
    from .. import pipeline

    c = pipeline.compile_model(model, prior_scale)
    return c, package_folder(c)


def package_folder(c: pipeline.Compiled) -> str:
    """A new private folder of this process holding ``c``'s NumPy package."""
    folder = private_folder("bgc-")
    write_package(Path(folder) / c.model.name / PACKAGE, c.package.files)
    return folder


def write_package(folder: Path, files) -> None:
    """Write a package's ``files`` ((path, text) pairs) into ``folder``, made here."""
    folder.mkdir(parents=True)
    for rel, text in files:
        (folder / rel).write_text(text, encoding="utf-8")


def write_whole(place: Path, fill) -> None:
    """Make the folder ``place`` whole or not at all: ``fill(folder)``
    writes into a new temporary folder beside it, which is then renamed into
    place (one atomic step: a reader sees all of it or none). When another
    process put it there first, that one stays and this copy is dropped.

    Raises
    ------
    OSError
        It could not be written (and is not there).
    """
    place.parent.mkdir(parents=True, exist_ok=True)
    fresh = Path(tempfile.mkdtemp(prefix=f".{place.name}-", dir=place.parent))
    try:
        fill(fresh)
        try:
            os.rename(fresh, place)
        except OSError:
            if not place.exists():
                raise
    finally:
        shutil.rmtree(fresh, ignore_errors=True)  # gone once renamed into place


def cache_root() -> Path:
    """bgc's own cache folder: ``BGC_CACHE_DIR``, else ``$XDG_CACHE_HOME/bgc``, else ``~/.cache/bgc``."""
    if os.environ.get("BGC_CACHE_DIR"):
        return Path(os.environ["BGC_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bgc"


def numba_digest(c: pipeline.Compiled) -> str:
    """The name of the folder of :func:`lasting_folder` that holds ``c``'s
    compiled package: ``<model>-<digest of its text>``, the path of the
    model file (in the package's comments only) left out: the same model
    text met at another path (a campaign worker's private copy) finds the
    same folder and its compiled kernels."""
    from ..compiler.printing import escape

    source = escape(c.model.display_source)
    digest = hashlib.sha256(repr([(rel, text.replace(source, "")) for rel, text in c.package.numba_files]).encode()
                            ).hexdigest()[:20]
    return f"{c.model.name}-{digest}"


def _lasting_folder(c: pipeline.Compiled) -> str:
    """:func:`lasting_folder` of ``c``'s compiled (numba) package."""
    return lasting_folder(numba_digest(c), c.model.name, c.package.numba_files)


def lasting_folder(name: str, model: str, files) -> str:
    """A folder that holds a compiled (numba) package (``files``: its
    (path, text) pairs; ``name``: :func:`numba_digest`) and lasts from run to
    run, so numba's disk cache beside it stays valid: under
    :func:`cache_root`, ``packages/<name>``. Written once, whole, by
    renaming a finished private folder into place (processes racing to
    write it: one wins, the others' copies are dropped)."""
    root = cache_root() / "packages" / name
    if not (root / model / NUMBA_PACKAGE / "__init__.py").exists():
        write_whole(root, lambda fresh: write_package(fresh / model / NUMBA_PACKAGE, files))
    else:
        try:
            os.utime(root)  # used now: ``bgc cache clear --unused-days`` keeps it
        except OSError:
            pass
    return str(root)


os.register_at_fork(after_in_child=_new_folder_lock)
