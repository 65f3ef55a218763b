"""pytest's collection of bgc's doctests (``testpaths``): the compiled
backend's kernels import numba, the ``fast`` extra; without it they are not
collected (the NumPy package never imports them)."""

import importlib.util

collect_ignore = ([] if importlib.util.find_spec("numba") is not None
                  else ["bgc/runtime/filters/numba_kernel.py", "bgc/runtime/filters/_jit_kernel.py"])
