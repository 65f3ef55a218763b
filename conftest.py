"""pytest's set-up, loaded before anything imports NumPy.

The compiled backend's kernels import numba, the ``fast`` extra; without it
they are not collected as doctests (the NumPy package never imports them).

OpenBLAS chooses its kernels by CPU (Haswell, SkylakeX, Zen, ...), and they
add the terms of a matrix product in different orders: the rounding differs
from machine to machine, and a particle filter's resampling turns a
difference in the last bit into another cloud. The regression corpus
(tests/regression) is recorded with the Haswell kernels (AVX2 and FMA, which
every x86-64 CPU of the last ten years has); on a CPU that can run them the
suite asks OpenBLAS for them (``OPENBLAS_CORETYPE``, read when NumPy loads
OpenBLAS, unless the caller set it), so the corpus replays bit for bit on
any such machine. Elsewhere, or with other kernels asked for, the corpus's
exact numbers are skipped, with that reason (tests/test_regression.py).

numba's disk cache (``NUMBA_CACHE_DIR``) and bgc's cache of compiled
packages (``BGC_CACHE_DIR``) are folders of the suite's own cache
(:data:`KEPT`: ``BGC_TEST_CACHE``, else ``$XDG_CACHE_HOME/bgc-tests``, else
``~/.cache/bgc-tests``), kept from run to run and from checkout to checkout
(``make clean`` removes it), unless the caller chose others: the kernels a
run compiles are loaded by the next, a clean clone's included, and the suite
writes nothing into the user's own caches. Every entry is named by what it
was made from (bgc's code, the model's text, the package's text, numba's
version), so checkouts of other commits share the folder safely. The one
test of a cold cache gives its process a new folder (tests/test_backend.py).
"""

import importlib.util
import os
from pathlib import Path

import pytest

#: The OpenBLAS kernels the regression corpus is recorded with (tests/regression/record.py).
RECORDED_CORETYPE = "Haswell"
#: What the Haswell kernels need of the CPU.
_HASWELL_FLAGS = ("avx2", "fma")


def _runs_haswell() -> bool:
    try:
        with open("/proc/cpuinfo") as f:
            flags = set(f.read().split())
    except OSError:
        return False
    return all(flag in flags for flag in _HASWELL_FLAGS)


if _runs_haswell():
    os.environ.setdefault("OPENBLAS_CORETYPE", RECORDED_CORETYPE)

#: The caches kept between test runs, outside the checkout: a clean clone finds what the last run compiled.
KEPT = Path(os.environ.get("BGC_TEST_CACHE")
            or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bgc-tests")
os.environ.setdefault("NUMBA_CACHE_DIR", str(KEPT / "numba"))
os.environ.setdefault("BGC_CACHE_DIR", str(KEPT / "bgc"))

#: What the suite's cache keeps that no run used for this long is removed when a run starts.
PRUNE_DAYS = 30


def pytest_sessionstart(session) -> None:
    """Prune the suite's own cache (not a folder the caller chose): what bgc
    wrote in its part that no run used for :data:`PRUNE_DAYS` days
    (``bgc cache clear --unused-days``), and numba's cache folders none of
    whose files changed for as long (a checkout that is gone leaves one)."""
    import shutil
    import time

    if hasattr(session.config, "workerinput"):  # a pytest-xdist worker: the controller prunes, once
        return
    from bgc.api import cache

    days = PRUNE_DAYS * 86400.0
    if os.environ.get("BGC_CACHE_DIR") == str(KEPT / "bgc"):
        cache.clear(KEPT / "bgc", unused_for=days)
    if os.environ.get("NUMBA_CACHE_DIR") == str(KEPT / "numba") and (KEPT / "numba").is_dir():
        for folder in (KEPT / "numba").iterdir():
            stamps = [f.stat().st_mtime for f in folder.rglob("*") if f.is_file()] if folder.is_dir() else []
            if stamps and time.time() - max(stamps) > days:
                shutil.rmtree(folder, ignore_errors=True)


collect_ignore = ([] if importlib.util.find_spec("numba") is not None
                  else ["bgc/filters/numba_kernel.py", "bgc/filters/_jit_kernel.py"])


@pytest.hookimpl(trylast=True)  # after -m has deselected by marker: make check keeps the fast ones
def pytest_collection_modifyitems(config, items) -> None:
    """A document's fast transcripts (``test_transcripts_run_as_printed[DOC]``)
    run again inside its slow test (``[DOC, with its slow blocks]``, which
    runs every block in order): when both are selected (``make test``), the
    fast one is left out, deselected; ``make check`` keeps it."""
    slow = {item.nodeid.replace(", with its slow blocks]", "]") for item in items
            if item.nodeid.endswith(", with its slow blocks]")}
    dropped = [item for item in items if item.nodeid in slow]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = [item for item in items if item.nodeid not in slow]
