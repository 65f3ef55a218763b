"""Shared test set-up: hypothesis profiles (``ci`` is derandomized), the
models compiled once per session, and ``bgc ...`` run in this process.

The tiers (markers registered in pyproject.toml): ``make check`` runs every
test but those marked ``slow`` (end-to-end scenarios, seeded statistics, any test of more than a second or two),
``process`` (starts a real process: a CLI through a pipe, Ctrl-C, --follow,
a fresh interpreter, a Dask cluster, a notebook kernel; or forks the worker
pool it tests), ``numba`` (compiles kernels), ``install``, ``browser`` and
``long``; ``make test``, which CI runs, runs them all but ``long``: the long
runs (a test of 4 s or more, measured: seeded statistics, memory peaks, long
streams, campaigns, the slower end-to-end scenarios), which ``make long``
runs, as a benchmark is run. A diagnosis runs its filters in
this process (``BGC_WORKERS=1``, below) unless workers are what the
test is about; a command runs in this process (:func:`bgc_cli`) unless it
needs a real one; a shipped model is compiled once (:func:`compiled`,
:func:`session`, and :func:`compiled_once` for what bgc compiles itself).
"""

import contextlib
import importlib.util
import io
import os
import subprocess
import sys
import tracemalloc
import warnings
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))
# The suite runs on the NumPy backend (a model the tests write afresh would be compiled by numba
# each time); tests/test_backend.py asks for numba by name, so does the seeded interval-coverage test
# of tests/test_diagnose.py when numba is installed (shipped models only), and a run may choose:
# BGC_BACKEND=numba make test.
os.environ.setdefault("BGC_BACKEND", "numpy")
os.environ.setdefault("MPLBACKEND", "Agg")  # no display: as make test sets it
# A diagnosis (bgc diagnose, bgc monitor, bgc.diagnose, a Diagnoser) weighs its hypotheses in its own
# process: the suite's two processes already fill the two cores, and a forked pool beside them only adds
# work (docs/commands.md, --workers; the API's default reads the variable too). The tests of the forked
# pool ask for it by name (DiagnosisOptions(workers=2)).
os.environ.setdefault("BGC_WORKERS", "1")

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
TEST_MODELS = ROOT / "tests" / "data" / "models"
#: Every model the stage tests run on: the shipped three and the test plants.
ALL_MODELS = {
    "circuit": MODELS / "circuit.yaml",
    "two_tank": MODELS / "two_tank.yaml",
    "ro": MODELS / "ro.yaml",
    "dc_motor": TEST_MODELS / "dc_motor.yaml",
    "resistor_loop": TEST_MODELS / "resistor_loop.yaml",
    "mass_spring_damper": TEST_MODELS / "mass_spring_damper.yaml",
    "orifice_tanks": TEST_MODELS / "orifice_tanks.yaml",
}


@lru_cache(maxsize=None)
def compiled(name: str):
    """Every IR of one of ALL_MODELS, compiled once per test session (for a
    test that is not about compiling: read it, do not change it)."""
    from bgc.pipeline import compile_model

    return compile_model(ALL_MODELS[name])


@lru_cache(maxsize=None)
def _session(model: str, text: bytes, options: tuple):
    import bgc

    return bgc.open(model, **dict(options))


def session(model, **options):
    """``bgc.open(model, **options)`` once per test session and model text
    (``model``: a name of ALL_MODELS or a path), for the many diagnoses of
    tests that are not about opening a model: ``bgc.diagnose(session(...),
    ...)`` gives what ``bgc.diagnose(model, ..., **options)`` would, without
    compiling again. Read it, do not change it."""
    path = ALL_MODELS.get(model, model)
    return _session(str(path), Path(path).read_bytes(), tuple(sorted(options.items())))


@lru_cache(maxsize=None)
def numba_package(name: str):
    """The compiled (numba) package of a shipped model, every kernel of
    every model's whole step compiled into numba's disk cache, or loaded from
    it, once per test process. The package is the one bgc.open runs: the text
    of generated/NAME/numba_model (tests/test_generated.py), in its folder of
    bgc's cache that lasts (:func:`bgc.api.cache.numba_folder`), where numba's
    disk cache stays valid from run to run and from checkout to checkout
    (the root conftest.py keeps both caches outside the checkout); a
    package's folder in a checkout is new in every clone. The first test
    process to ask compiles (on forked workers) while holding a lock on a
    file of the suite's cache; the other waits for it, then loads: two test
    processes never compile the same kernels at once. The tests that run a
    shipped model on numba ask for it first."""
    import fcntl

    from bgc.api import cache
    from bgc.model import package as loading
    from bgc.model import warmup

    folder = cache.numba_folder(cache.open_model(MODELS / f"{name}.yaml"))
    package = loading.load_package(folder, name, backend="numba")
    lock = Path(os.environ["BGC_CACHE_DIR"]) / "numba-warm.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        try:
            warmup.warm_up(package, steps=tuple(package.MODELS))
        finally:
            fcntl.flock(held, fcntl.LOCK_UN)
    return package


def numba_folder(name: str) -> Path:
    """The folder of :func:`numba_package` (``<folder>/NAME/numba_model``),
    its kernels in numba's disk cache: ``generated=`` for a shipped model's
    compiled package."""
    return Path(numba_package(name).__file__).parents[2]


#: The backend of the slow tests of the shipped models (many seeded diagnoses): the compiled one when
#: numba is installed (the same diagnoses, tests/test_backend.py checks it, about 3x faster), else NumPy;
#: also of the docs' slow transcripts (tests/test_docs.py), so of the slow tests of the docs/examples
#: models those transcripts diagnose (switched_rc.yaml, level.yaml): their kernels are compiled once into
#: the suite's lasting cache either way.
FAST = "numba" if importlib.util.find_spec("numba") else "numpy"


def fast_session(model: str, **options):
    """:func:`session` of a shipped model on the FAST backend, its kernels
    compiled once per test run, or loaded from the last run's (:func:`numba_package`);
    for the slow tier (make check compiles no kernel)."""
    if FAST == "numba":
        numba_package(model)
    return session(MODELS / f"{model}.yaml", backend=FAST, **options)


def fast_backend(model: str) -> tuple[str, str]:
    """A command's ``--backend`` option for the FAST backend, a shipped
    model's kernels compiled first once per test run, or loaded from the last
    run's (:func:`numba_package`): :func:`fast_session` for the commands
    (``bgc_cli("monitor", ..., *fast_backend("circuit"))``); for the slow
    tier only (make check compiles no kernel)."""
    if FAST == "numba":
        numba_package(model)
    return ("--backend", FAST)


#: Folders of model files no test writes to: their compilations may be shared.
_READ_ONLY = (MODELS, TEST_MODELS, ROOT / "tests" / "regression" / "models", ROOT / "docs" / "examples")
_COMPILED: dict = {}


@contextlib.contextmanager
def compiled_once():
    """Within it, ``bgc.pipeline.compile_model`` of a model file of
    ``models/``, ``tests/data/models/`` or the regression corpus's models
    (files no test writes to) compiles once per test session and per path
    as given (a message names the path as the user wrote it), text and
    prior scale; any other file, and a model that fails, compile as usual.
    What bgc compiles on its way (bgc.open, the commands, a campaign) goes
    through ``pipeline.compile_model``; a test of the compiler imports
    ``compile_model`` itself and compiles afresh. The compilations are
    frozen values (bgc.ir): sharing them is safe."""
    from bgc import pipeline

    fresh = pipeline.compile_model

    def compile_model(path, prior_scale: float = 1.0, *, text: str | None = None):
        where = Path(path).resolve()
        if where.parent not in _READ_ONLY:
            return fresh(path, prior_scale, text=text)
        key = (str(path), str(where), where.read_bytes() if text is None else text, prior_scale)
        if key not in _COMPILED:
            _COMPILED[key] = fresh(path, prior_scale, text=text)
        return _COMPILED[key]

    pipeline.compile_model = compile_model
    try:
        yield
    finally:
        pipeline.compile_model = fresh


@pytest.fixture(autouse=True, scope="session")
def _shipped_models_compiled_once():
    """Every test runs within :func:`compiled_once`."""
    with compiled_once():
        yield


#: The warning filters of a fresh interpreter (``python -m bgc`` has no others).
_FRESH_FILTERS = [("default", None, DeprecationWarning, "__main__", 0),
                  ("ignore", None, DeprecationWarning, None, 0),
                  ("ignore", None, PendingDeprecationWarning, None, 0),
                  ("ignore", None, ImportWarning, None, 0),
                  ("ignore", None, ResourceWarning, None, 0)]


def bgc_cli(*args, cwd=ROOT, input: str | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    """``bgc ARGS`` run in this process, as ``python -m bgc ARGS`` would run:
    :func:`bgc.cli.main` from folder ``cwd`` with ``input`` on standard input
    and ``env`` added to the environment (a value None: removed); its exit
    status (argparse's ``SystemExit`` included) and what it printed on stdout
    and stderr (a warning as a fresh interpreter shows it, on stderr), as
    ``subprocess.run(..., capture_output=True, text=True)`` returns them. An
    exception that would be a traceback is raised here. A test that needs a
    real process (a pipe, a signal, a fresh interpreter) starts one instead.
    ``bgc diagnose`` and ``bgc monitor`` weigh their hypotheses on
    ``--workers`` processes (the suite's ``BGC_WORKERS``: 1, this one), and
    ``bgc experiment`` runs its campaign on its workers."""
    from bgc.cli import main

    argv = [str(a) for a in args]
    out, err = io.BytesIO(), io.BytesIO()
    stdout = io.TextIOWrapper(out, encoding="utf-8", errors="strict", newline="", write_through=True)
    stderr = io.TextIOWrapper(err, encoding="utf-8", errors="backslashreplace", newline="", write_through=True)
    stdin = io.TextIOWrapper(io.BytesIO((input or "").encode("utf-8")), encoding="utf-8")
    old = {k: os.environ.get(k) for k in (env or {})}
    here = os.getcwd()
    try:
        for k, v in (env or {}).items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        os.chdir(cwd)
        with contextlib.ExitStack() as stack:
            stack.enter_context(warnings.catch_warnings())
            warnings.filters[:] = list(_FRESH_FILTERS)
            warnings._filters_mutated()  # noqa: SLF001 - as warnings.filterwarnings does
            warnings.showwarning = _show_on_stderr  # not to pytest's record
            stack.enter_context(contextlib.redirect_stdout(stdout))
            stack.enter_context(contextlib.redirect_stderr(stderr))
            stack.enter_context(_stdin(stdin))
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors, --help, --version
                code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
                if not isinstance(exc.code, (int, type(None))):
                    print(exc.code, file=sys.stderr)
            stdout.flush()
            stderr.flush()
    finally:
        os.chdir(here)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    text = lambda b: io.TextIOWrapper(io.BytesIO(b.getvalue()), encoding="utf-8", errors="replace").read()
    return subprocess.CompletedProcess(["bgc", *argv], code, text(out), text(err))


def _show_on_stderr(message, category, filename, lineno, file=None, line=None) -> None:
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


@contextlib.contextmanager
def _stdin(stream):
    old, sys.stdin = sys.stdin, stream
    try:
        yield
    finally:
        sys.stdin = old


def tank_map(R12: float, dt: float = 0.5, R10: float = 4.0, R20: float = 3.0):
    """The two tanks' RK4 step (one substep of dt, as generated: SUBSTEPS = 1)
    derived by hand: C1 dP1/dt = f_in - P1/R10 - (P1 - P2)/R12, C2 dP2/dt =
    (P1 - P2)/R12 - P2/R20, i.e. dx/dt = A x + b, whose RK4 step is x' = M x + c
    with M = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24 and c = h (I + hA/2 +
    (hA)^2/6 + (hA)^3/24) b. Measurements F10 = P1/R10, F12 = (P1 - P2)/R12,
    F20 = P2/R20."""
    C1, C2, f_in = 2.0, 1.5, 1.0
    A = np.array([[-1 / (C1 * R10) - 1 / (C1 * R12), 1 / (C1 * R12)],
                  [1 / (C2 * R12), -1 / (C2 * R12) - 1 / (C2 * R20)]])
    b = np.array([f_in / C1, 0.0])
    hA = dt * A
    I2 = np.eye(2)
    M = I2 + hA + hA @ hA / 2 + hA @ hA @ hA / 6 + hA @ hA @ hA @ hA / 24
    c = dt * (I2 + hA / 2 + hA @ hA / 6 + hA @ hA @ hA / 24) @ b
    H = np.array([[1 / R10, 0.0], [1 / R12, -1 / R12], [0.0, 1 / R20]])
    return M, c, H


def peak_memory(fn):
    """(fn(), the peak of the memory tracemalloc saw allocated while it ran)."""
    tracemalloc.start()
    try:
        return fn(), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
