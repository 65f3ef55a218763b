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
packages (``BGC_CACHE_DIR``) are folders of .pytest_cache, kept from run to
run (``make clean`` removes them), unless the caller chose others: the
kernels compiled by one run are loaded by the next, and the suite writes
nothing into the user's own caches. The one test of a cold cache gives its
process a new folder (tests/test_backend.py).
"""

import importlib.util
import os
from pathlib import Path

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

#: The caches kept between test runs.
KEPT = Path(__file__).resolve().parent / ".pytest_cache"
os.environ.setdefault("NUMBA_CACHE_DIR", str(KEPT / "numba"))
os.environ.setdefault("BGC_CACHE_DIR", str(KEPT / "bgc"))

collect_ignore = ([] if importlib.util.find_spec("numba") is not None
                  else ["bgc/filters/numba_kernel.py", "bgc/filters/_jit_kernel.py"])
