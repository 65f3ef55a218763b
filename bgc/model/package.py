"""A generated package loaded (``generated/<model>/numpy_model``, or the
compiled ``numba_model``: the backend), and the choice of backend.

The NumPy package imports only numpy, the compiled one numpy and numba; a
package is loaded by path under a private module name, so several models'
packages can be loaded side by side. The
runtime knows fault kinds from :mod:`bgc.kinds` and the package's ``FAULT``
table, never from the compiler.
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path

import numpy as np

from ..arguments import spelled
from ..errors import TrackingError, printable
from ..ir import PACKAGES, NoiseLevels
from .protocol import Package


#: The backends, in the order ``--backend`` lists them.
BACKENDS = tuple(PACKAGES)


def numba_installed() -> bool:
    """Whether numba can be imported (the ``fast`` extra)."""
    return importlib.util.find_spec("numba") is not None


def resolve_backend(backend: str | None) -> str:
    """The backend to run on: ``backend`` ('numpy' or 'numba'), or for None or
    'auto' the environment's ``BGC_BACKEND`` when set, else numba when it is
    installed, else numpy.

    Raises
    ------
    TrackingError
        An unknown backend, or numba asked for and not installed.
    """
    chosen = backend if backend not in (None, "auto") else _environment_backend() or (
        "numba" if numba_installed() else "numpy")
    if chosen not in PACKAGES:
        raise TrackingError(f"unknown backend {printable(str(chosen))}", None,
                            "use one of: " + ", ".join(BACKENDS) + " (or auto)")
    if chosen == "numba" and not numba_installed():
        raise TrackingError("the numba backend needs numba, which is not installed", None,
                            "pip install 'bgc[fast]', or use "
                            + spelled("backend='numpy'", "--backend numpy"))
    return chosen


#: ``auto``'s rule (:func:`auto_backend`), in particle-steps (particles x
#: steps of a diagnosis): from this much work, loading numba and a model's
#: kernels from numba's disk cache (about 1 s) is repaid. Measured (CPU
#: seconds, one process; docs/backend.md, "What auto chooses"): a diagnosis
#: that finds a fault saves 1.6 to 1.8 s on the two tanks and 5.5 to 7.5 s
#: on RO from 200 particles over 300 steps; a fault-free run saves 0.05 to
#: 0.2 s, less than the loading.
LOAD_WORK = 100_000

#: From this much work, compiling a model's kernels first (20 to 35 s on a
#: quiet 2-core machine, 44 kernels for the two tanks, 54 for RO) is repaid
#: within the one run: the saving grows with the steps, far less with the
#: particles (the static posterior's Kalman filters do not have any).
COMPILE_WORK = 20_000_000


def auto_backend(work: int | None, cached: bool) -> tuple[str, str]:
    """The backend ``auto`` runs a diagnosis of ``work`` particle-steps on
    (None: not known), with the model's numba kernels in numba's disk cache
    (``cached``) or not, and why, in words: numba when it is installed and
    either its kernels are cached and the work repays loading them (at least
    :data:`LOAD_WORK`, or not known), or the work repays compiling them (at
    least :data:`COMPILE_WORK`); else numpy. The result does not depend on
    the backend, only the time does.

    >>> auto_backend(None, False)[0], auto_backend(LOAD_WORK - 1, True)[0]
    ('numpy', 'numpy')
    """
    if not numba_installed():
        return "numpy", "auto: numba is not installed"
    size = "work not known" if work is None else f"{work:,} particle-steps"
    if cached and (work is None or work >= LOAD_WORK):
        return "numba", f"auto: the model's kernels are in numba's disk cache ({size})"
    if work is not None and work >= COMPILE_WORK:
        return "numba", f"auto: {size} repay compiling the model's kernels"
    if cached:
        return "numpy", f"auto: {size}, too little to repay loading numba's kernels"
    return "numpy", (f"auto: the model's kernels are not compiled yet, and {size} would not repay compiling them; "
                     "--backend numba compiles them, and auto uses them from then on")


def _environment_backend() -> str | None:
    """``BGC_BACKEND`` when it names a backend (empty or 'auto': None)."""
    import os

    chosen = os.environ.get("BGC_BACKEND", "").strip()
    return None if chosen in ("", "auto") else chosen


def chosen_by_name(backend: str | None) -> bool:
    """Whether ``backend`` (or, for None / 'auto', ``BGC_BACKEND``) names a backend: a
    backend asked for by name is used or refused; one chosen by what is installed
    falls back to NumPy when the compiled package cannot be had."""
    return backend not in (None, "auto") or _environment_backend() is not None


def load_package(generated_dir: str | Path, model: str, source: str | None = None,
                 noise: NoiseLevels | None = None, backend: str = "numpy") -> Package:
    """Import ``<generated_dir>/<model>/numpy_model`` (``backend`` 'numba':
    ``numba_model``) as ``bgc_generated_<model>_<folder hash>``
    (``source``: the model file, for the hint when the package is missing).

    With ``noise`` (absolute stds, e.g. :meth:`bgc.ir.Numerics.noise_at` of
    other relative levels), a separate instance of the package is loaded
    whose models use those process, measurement and predictive stds (their
    fault states keep theirs, and the initial spread ``X0_STD`` stays the
    compiled one): the filters then match data simulated at other noise levels.
    """
    root = Path(generated_dir) / model / PACKAGES[backend]
    init = root / "__init__.py"
    if not init.exists():
        if (Path(generated_dir) / PACKAGES[backend] / "__init__.py").exists():  # the model's own folder, not the root
            raise TrackingError(
                f"{printable(str(generated_dir))} is the folder of one model's package", None,
                f"point --generated at the folder bgc compile -o wrote: {printable(str(Path(generated_dir).parent))}")
        out = "" if Path(generated_dir) == Path("generated") else f" -o {printable(str(generated_dir))}"
        raise TrackingError(
            f"no generated package at {printable(str(root))}", None,
            f"run: bgc compile {printable(source or 'MODEL.yaml')}{out} (it writes both backends' packages), or "
            "point --generated at the folder bgc compile -o wrote")
    # one name per folder: two sessions of a model (another folder, another text) never share a module
    name = f"bgc_generated_{model}_{hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:12]}"
    if noise is not None:
        key = hashlib.sha256(repr((noise.process, noise.measurement, noise.predictive)).encode()).hexdigest()[:16]
        name = f"{name}_noise_{key}"
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(init):
        return sys.modules[name]
    for old in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
        del sys.modules[old]  # another folder's package of that name: none of its modules may be reused
    spec = importlib.util.spec_from_file_location(name, init, submodule_search_locations=[str(root)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    if noise is not None:
        for m in module.MODELS.values():
            n = len(noise.process)
            if len(m.MEASUREMENT_STD) != len(noise.measurement) or len(m.PROCESS_STD) < n:
                raise TrackingError(f"the package at {printable(str(root))} does not have this model's states and "
                                    "sensors", None, f"run: bgc compile {printable(source or 'MODEL.yaml')}")
            m.PROCESS_STD[:n] = noise.process
            m.MEASUREMENT_STD[:] = noise.measurement
            m.PREDICTIVE_STD[:] = noise.predictive
    return module




#: The attribute a started package (:func:`started_package`) names the package it was made from with.
STARTED_FROM = "BGC_STARTED_FROM"
#: The attributes a started package keeps its start (mean, std; None: X0) and its parameters changed ({name: value}) in.
STARTED_AT, STARTED_THETA = "BGC_STARTED_AT", "BGC_STARTED_THETA"


def base_package(package: Package) -> Package:
    """The generated package a started package (:func:`started_package`)
    was started from: the model file's; ``package`` itself when it is one."""
    return sys.modules.get(getattr(package, STARTED_FROM, package.__name__), package)


def started_package(package: Package, mean=None, std=None, theta: dict | None = None) -> Package:
    """Generated ``package`` with its record starting elsewhere than the
    model's ``X0``, or some of its parameters at other values: another
    instance of its files (imported again under a name of its own,
    ``<name>_from_<digest>``, registered in ``sys.modules`` as every package
    is, so forked workers find it by name), every array (the noise) copied
    from ``package``, and

    - with ``mean`` and ``std`` (one per nominal state): its models' carried
      states start at ``mean`` with spread ``std`` (a mode or a dwell time
      exactly: std 0; a fault model's fault states keep theirs), so that the
      filters and the static posteriors that start "from the model's prior"
      start there: a diagnoser that forgot the first part of its record
      (:meth:`bgc.diagnosis.diagnoser.Diagnoser.step`) starts its record's
      models from the nominal observer's estimate at the step it kept first;
    - with ``theta`` ({parameter: value}): those parameters (``THETA``) at
      those values in every model: a fault accommodated by the monitor
      (:mod:`bgc.service.episodes`), its fault models sized from there.

    What ``package`` was started with is kept where an argument is None (a
    started package started again keeps its parameters); a package of the
    same start and parameters is the same module."""
    from .protocol import CARRIED, nominal_model

    base = base_package(package)
    if mean is None:
        mean, std = getattr(package, STARTED_AT, None) or (None, None)
    if theta is None:
        theta = getattr(package, STARTED_THETA, None) or {}
    if mean is None and not theta:
        return base
    key = repr(sorted(theta.items())).encode()
    if mean is not None:
        mean, std = np.array(mean, dtype=float), np.array(std, dtype=float)
        key += mean.tobytes() + std.tobytes()
    name = f"{base.__name__}_from_{hashlib.sha256(key).hexdigest()[:16]}"
    if name in sys.modules:
        return sys.modules[name]
    init = Path(base.__file__)
    spec = importlib.util.spec_from_file_location(name, init, submodule_search_locations=[str(init.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    setattr(module, STARTED_FROM, base.__name__)
    setattr(module, STARTED_AT, None if mean is None else (mean, std))
    setattr(module, STARTED_THETA, dict(theta))
    nominal = nominal_model(base)
    kinds = getattr(nominal, "STATE_KINDS", ("physical",) * len(nominal.STATES))
    rows = [i for i, k in enumerate(kinds) if k in CARRIED and k != "threshold"]
    for key_, m in module.MODELS.items():
        source = base.MODELS[key_]
        for array in ("PROCESS_STD", "MEASUREMENT_STD", "PREDICTIVE_STD", "X0", "X0_STD"):
            getattr(m, array)[:] = getattr(source, array)
        if mean is not None:
            m.X0[rows] = mean[rows]
            m.X0_STD[rows] = [std[i] if kinds[i] == "physical" else 0.0 for i in rows]
        if theta:
            m.THETA = tuple(float(theta.get(p, v)) for p, v in zip(m.PARAMETERS, source.THETA))
            if hasattr(source, "FAULT_PRIOR"):  # a fault model
                m.FAULT_PRIOR = _with_return(source, m.THETA)
    return module


#: How far past its way back to the model file's value the prior of an accommodated fault's step
#: reaches, as a fraction of that way: room for the estimate's spread around it.
RETURN_MARGIN = 0.5


def _with_return(source, theta: tuple) -> tuple:
    """The prior (``FAULT_PRIOR``) of fault model ``source`` on a package
    whose parameters are ``theta``: its own, and where its fault's parameter
    is held at a faulty value (accommodated) and its kind is a step, widened
    to the step back to the value in the model file (the fault going away)
    with ``RETURN_MARGIN`` of it beyond; a parameter's never below ``LOWEST``
    of its value."""
    from ..kinds import LOWEST, fault_kind

    low, high = (float(v) for v in source.FAULT_PRIOR)
    fault = getattr(source, "FAULT", None)
    if not fault or fault.get("parameter") not in source.PARAMETERS or fault_kind(fault["kind"]).drifts:
        return (low, high)
    i = source.PARAMETERS.index(fault["parameter"])
    back = float(source.THETA[i]) - float(theta[i])
    if back == 0.0 or fault_kind(fault["kind"]).discrete:
        return (low, high)
    low, high = min(low, back - RETURN_MARGIN * abs(back)), max(high, back + RETURN_MARGIN * abs(back))
    if fault.get("target") == "parameter":
        low = max(low, LOWEST * abs(float(theta[i])))
    return (low, high)


def accommodated(package: Package) -> tuple[str, ...]:
    """The parameters a started package (:func:`started_package`) holds at
    other values than the model file's (faults accommodated), in its order."""
    theta = getattr(package, STARTED_THETA, None) or {}
    base = base_package(package)
    from .protocol import nominal_model

    nominal = nominal_model(base)
    return tuple(p for p, v in zip(nominal.PARAMETERS, nominal.THETA) if p in theta and float(theta[p]) != float(v))


def forget_started(package: Package) -> None:
    """Take a started package (:func:`started_package`) out of
    ``sys.modules`` (its diagnoser made another start, or finished); any
    other package is left alone."""
    if getattr(package, STARTED_FROM, None) is not None:
        for name in [m for m in sys.modules if m == package.__name__ or m.startswith(package.__name__ + ".")]:
            del sys.modules[name]
