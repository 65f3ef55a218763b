"""The compiled (numba) backend: the same numbers as the NumPy package on
every shipped model and filter, the choice of backend, and a NumPy-only
installation that never needs numba.

The tests that compile kernels are marked ``numba`` (make check leaves them
out). On NumPy they load the committed packages of generated/; on numba the
same package text from its folder of bgc's cache that lasts (what bgc.open
runs; tests/conftest.py's ``numba_package``): each kernel is compiled once,
into numba's disk cache, which the root conftest.py keeps outside the
checkout from run to run, and every later test, in this process or another,
in this run or the next, loads it. Only the test of a cold cache starts from
nothing.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from bgc.diagnosis.options import DiagnosisOptions
from bgc.errors import TrackingError
from bgc.filters import cubature as kalman
from bgc.filters import quadrature
from bgc.analysis import simulate
from bgc.model import package as loading
from bgc.model import warmup

from conftest import ROOT, bgc_cli, compiled, numba_folder, numba_package

numba = pytest.importorskip("numba", reason="the fast extra (numba) is not installed: pip install '.[fast]'")

MODELS = ["circuit", "two_tank", "ro"]
#: Relative difference allowed between the backends (each series scaled by its largest magnitude).
TOLERANCE = 1e-10


def record(name: str, steps: int = 120):
    """A faulty run of a shipped model (its first fault candidate, from a third
    of the run) with a few sensor readings missing: (ys, us)."""
    c = compiled(name)
    fault = c.numerics.faults[0]
    kind = fault.name.split(":")[1]
    magnitude = simulate.change_magnitude(c.numerics, fault.name, 0.2, steps * c.model.settings.dt / 2)
    injection = simulate.FaultInjection(fault.parameter, kind, magnitude, steps // 3 * c.model.settings.dt)
    r = simulate.simulate(c.numerics, simulate.SimulationOptions(steps=steps, seed=3, fault=injection))
    ys = np.array(r.measurements, dtype=float)
    ys[10, 0] = np.nan  # one sensor not read
    ys[20, :] = np.nan  # a sample without any reading
    return ys, np.array(r.inputs, dtype=float)


def difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| over the series, each column scaled by its largest |a| (NaN where both are)."""
    a, b = np.asarray(a, float).reshape(len(a), -1), np.asarray(b, float).reshape(len(b), -1)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    scale = np.nanmax(np.abs(a), axis=0, initial=0.0)
    scale[scale == 0] = 1.0
    return float(np.nanmax(np.abs(a - b) / scale, initial=0.0))


def packages(name: str):
    """A shipped model's package on NumPy (generated/) and on numba (every kernel compiled once, :func:`numba_package`)."""
    return loading.load_package(ROOT / "generated", name, backend="numpy"), numba_package(name)


def representatives(package) -> list[str]:
    """The nominal module and, of each kind of fault module (what the fault
    acts on, a parameter, a sensor or an input, and how: a step, a drift, a
    bias), the first by name: every module of a kind is generated from the
    same template with its own parameter made a state, so one of each runs
    every kind of step the printer writes (the nominal module holds all the
    model's equations)."""
    kinds = {}
    for module in sorted(package.MODELS):
        if module != "nominal":
            fault = package.MODELS[module].FAULT
            kinds.setdefault((fault["target"], fault["kind"]), module)
    return ["nominal", *kinds.values()]


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.numba
def test_backends_give_the_same_filter_outputs_on_every_model_and_filter(name):
    """The nominal module and one fault module of each kind
    (:func:`representatives`: 5 or 6 of the package's 16 to 21; every module:
    bench/full_cases.py backend-modules), every particle filter
    (same seed) and the cubature Kalman filter: the compiled package's
    outputs equal the NumPy package's to 1e-10 (they draw the same random
    numbers; only the order in which a compiled loop adds terms differs),
    over a faulty run of 60 steps. Every module's compiled step is loaded
    (warmed up) all the same."""
    ys, us = record(name, steps=60)
    numpy_pkg, numba_pkg = packages(name)
    assert warmup.warm_up(numpy_pkg) == (0.0, 0, 0)
    _, compiled_now, _ = warmup.warm_up(numba_pkg, steps=tuple(numba_pkg.MODELS))
    assert compiled_now == 0  # numba_package compiled every model's whole step
    assert numba_pkg.MODELS.keys() == numpy_pkg.MODELS.keys()
    modules = representatives(numpy_pkg)
    assert len(modules) >= 5 and {numpy_pkg.MODELS[m].FAULT["kind"] for m in modules[1:]} >= {"abrupt", "bias"}
    worst = filter_differences(numpy_pkg, numba_pkg, modules, ys, us)
    bad = {k: v for k, v in worst.items() if not v <= TOLERANCE}
    assert not bad, bad


def filter_differences(numpy_pkg, numba_pkg, modules, ys, us) -> dict:
    """The largest difference (:func:`difference`) between the backends' outputs of
    each particle filter and the cubature Kalman filter on each of ``modules``
    (bench/full_cases.py runs it on every module)."""
    worst = {}
    for module in modules:
        for cls in ("GenericParticleFilter", "AuxiliaryParticleFilter", "OptimalProposalParticleFilter"):
            runs = [getattr(p.filters, cls)(p.MODELS[module], 64, np.random.default_rng(7)).run(ys, us)
                    for p in (numpy_pkg, numba_pkg)]
            worst[module, cls] = max(difference(getattr(runs[0], k), getattr(runs[1], k))
                                     for k in ("mean", "std", "y_mean", "y_std", "ess"))
            assert np.array_equal(runs[0].resampled, runs[1].resampled)
        runs = [kalman.CubatureKalmanFilter(p.MODELS[module]) for p in (numpy_pkg, numba_pkg)]
        steps = [[f.step(ys[k], us[k]) for k in range(len(ys))] for f in runs]
        worst[module, "ckf"] = max(difference(np.array([getattr(s, k) for s in steps[0]]),
                                              np.array([getattr(s, k) for s in steps[1]]))
                                   for k in ("mean", "std", "y_mean", "y_std", "loglik"))
    return worst


@pytest.mark.parametrize("name", ["ro"])
@pytest.mark.numba
def test_a_bank_of_filters_is_the_same_on_both_backends(name):
    """Several generic filters of one fault model stepped together (the
    hypothesis filters' bank) give the same on both backends."""
    ys, us = record(name)
    outs = []
    for p in packages(name):
        model = p.MODELS[sorted(p.MODELS)[1]]
        bank = p.filters.FilterBank(model)
        filters = [p.filters.GenericParticleFilter(model, 64, np.random.default_rng(s)) for s in range(3)]
        outs.append(np.array([[r.mean for r in bank.step(filters, ys[k], us[k])] for k in range(len(ys))]))
    assert difference(outs[0].reshape(len(ys), -1), outs[1].reshape(len(ys), -1)) <= TOLERANCE


@pytest.mark.parametrize("fault", ["R12_abrupt", "F12_offset_bias"])
@pytest.mark.numba
def test_a_fault_that_comes_and_goes_is_weighed_alike_on_both_backends(fault):
    """The bank of a fault that comes and goes (bgc.diagnosis.intermittent:
    each cell's magnitude over a transition its own, and the update's that
    of the sample: ``moved``) on the compiled kernel's cubature step and on
    the NumPy arithmetic: the same log likelihoods and state weights, for a
    part of the two tanks that the transition sees and a sensor's offset
    that the update sees (the record: the first fault model's, from a third
    of the run)."""
    from bgc.diagnosis import intermittent
    from bgc.model.protocol import state_rows

    ys, us = record("two_tank")
    out = []
    for i, p in enumerate(packages("two_tank")):
        nominal, model = p.MODELS["nominal"], p.MODELS[fault]
        assert kalman._Filter(model).compiled == (i == 1)  # NumPy's arithmetic, then the kernel's step
        track = kalman.nominal_track(nominal, ys, us, len(ys))
        _, extra = state_rows(model)
        fixed = model.augment(track.mean[0][:, None], np.random.default_rng(0))[extra, 0]
        bank = intermittent._bank(model, ys, us, track, 30, [0.5, 1.0, 2.0], [4.0, 40.0], [8.0, 80.0], fixed,
                                  keep=True)
        finite = lambda a: np.where(np.isfinite(a), a, np.nan)  # noqa: E731  (a state not reached: -inf)
        out.append((finite(bank.loglik), finite(bank.alpha[30:])))
    assert difference(out[0][0][:, None], out[1][0][:, None]) <= TOLERANCE
    assert difference(out[0][1].reshape(len(out[0][1]), -1), out[1][1].reshape(len(out[1][1]), -1)) <= TOLERANCE


@pytest.mark.numba
def test_a_diagnosis_does_not_depend_on_the_backend():
    import bgc

    numba_package("circuit")  # the kernels bgc.open loads, compiled once
    reports = [bgc.diagnose("models/circuit.yaml", scenario="R2:abrupt:0.6@5", seed=2, steps=150,  # fault: sample 100
                            options=DiagnosisOptions(particles=200, seed=2, workers=1), backend=b)
               for b in ("numpy", "numba")]
    a, b = (r.diagnosis for r in reports)
    assert (a.verdict, a.candidates, a.onset) == (b.verdict, b.candidates, b.onset)
    assert a.estimate is not None and b.estimate is not None
    assert abs(a.estimate.value - b.estimate.value) <= 1e-8 * abs(a.estimate.value)


@pytest.fixture(scope="module")
def new_cache(tmp_path_factory):
    """The environment of a process with a bgc cache of its own, new for this
    run of the tests, and numba's disk cache where it is by default (beside
    the package), not the suite's: (the environment, the cache folder)."""
    cache = tmp_path_factory.mktemp("new-cache")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    return {**env, "BGC_CACHE_DIR": str(cache)}, cache


@pytest.mark.numba
@pytest.mark.process
@pytest.mark.long
def test_a_second_process_loads_the_compiled_kernels_from_the_disk_cache(new_cache):
    """The first session of a model text compiles its kernels, a later
    process loads them from numba's disk cache (the package lives in a
    folder of bgc's cache that lasts, named by the package's digest). The
    one test of a cold cache: two fresh interpreters, a new bgc cache, and
    numba's cache where it is by default (beside the package), not the
    suite's; a small test plant (two fault models: the kernel's loops are
    most of what it compiles)."""
    env, cache = new_cache
    assert not any(cache.iterdir()), "the test of a cold cache runs first on its cache"
    probe = ("import bgc; s = bgc.open('tests/data/models/resistor_loop.yaml', backend='numba'); "
             "print(s.package.__file__); print(*s.warm[1:]); print(s.backend_note())")
    outs = [subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True,
                           timeout=600) for _ in range(2)]
    for out in outs:
        assert out.returncode == 0, out.stderr
    (first_file, first, first_note), (again_file, again, again_note) = (o.stdout.splitlines() for o in outs)
    assert first_file == again_file and first_file.startswith(str(cache))
    compiled_first, _ = map(int, first.split())
    compiled_again, loaded_again = map(int, again.split())
    assert compiled_first > 0 and "compiled" in first_note
    assert compiled_again == 0 and loaded_again == compiled_first and "disk cache" in again_note


def test_the_backend_is_chosen_by_name_by_the_environment_or_by_what_is_installed(monkeypatch):
    assert loading.resolve_backend("numpy") == "numpy"
    assert loading.resolve_backend("numba") == "numba"
    monkeypatch.delenv("BGC_BACKEND", raising=False)
    assert loading.resolve_backend(None) == "numba"
    monkeypatch.setenv("BGC_BACKEND", "numpy")
    assert loading.resolve_backend("auto") == "numpy"
    monkeypatch.delenv("BGC_BACKEND")
    monkeypatch.setattr(loading, "numba_installed", lambda: False)
    assert loading.resolve_backend(None) == "numpy"
    with pytest.raises(TrackingError, match="pip install 'bgc\\[fast\\]'"):
        loading.resolve_backend("numba")
    with pytest.raises(TrackingError, match="unknown backend"):
        loading.resolve_backend("cuda")


@pytest.mark.process
def test_without_numba_the_numpy_package_runs_and_numba_is_refused_in_one_line(tmp_path):
    """An installation without the fast extra: numba cannot be imported (blocked
    here); ``bgc diagnose`` runs on the NumPy package, ``--backend numba`` is a
    one-line error naming the extra. (A fresh interpreter: this one has
    imported numba.)"""
    block = "import sys; sys.modules['numba'] = None; from bgc.cli import main; sys.exit(main())"
    env = {**os.environ, "BGC_BACKEND": ""}
    ok = subprocess.run([sys.executable, "-c", block, "diagnose", "models/circuit.yaml", "--scenario",
                         "R2:abrupt:0.6@5", "--particles", "100", "--steps", "150", "-o", str(tmp_path / "d")],
                        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert ok.returncode == 0, ok.stderr
    assert "numba" not in ok.stderr
    refused = subprocess.run([sys.executable, "-c", block, "diagnose", "models/circuit.yaml", "--scenario",
                              "R2:abrupt:0.6@5", "--backend", "numba", "-o", str(tmp_path / "e")],
                             cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert refused.returncode != 0
    assert "Traceback" not in refused.stderr
    assert "pip install 'bgc[fast]'" in refused.stderr
    for path in (ROOT / "generated").glob("*/numpy_model/*.py"):
        assert "numba" not in path.read_text(encoding="utf-8"), path


@pytest.mark.numba
def test_a_package_instance_at_other_noise_levels_uses_its_own_noise_on_both_backends():
    """``load_package(noise=...)`` loads a second instance of a package (its
    own module names) whose stds differ: the compiled kernels, shared by both
    instances, take the stds as arguments, so each instance filters with its
    own, and the backends agree."""
    c = compiled("two_tank")
    levels = c.numerics.noise_at(0.05, 0.04)
    ys, us = record("two_tank")
    runs = {}
    for backend in ("numpy", "numba"):
        folder = ROOT / "generated" if backend == "numpy" else numba_folder("two_tank")
        base = loading.load_package(folder, "two_tank", backend=backend)
        other = loading.load_package(folder, "two_tank", noise=levels, backend=backend)
        assert other.__name__ != base.__name__
        assert not np.allclose(other.MODELS["nominal"].PROCESS_STD, base.MODELS["nominal"].PROCESS_STD)
        for name, p in (("base", base), ("other", other)):
            runs[backend, name] = p.filters.GenericParticleFilter(p.MODELS["nominal"], 64,
                                                                  np.random.default_rng(1)).run(ys, us)
    for name in ("base", "other"):
        assert difference(runs["numpy", name].y_std, runs["numba", name].y_std) <= TOLERANCE
    assert difference(runs["numba", "base"].y_std, runs["numba", "other"].y_std) > 1e-3


@pytest.mark.numba
@pytest.mark.long
def test_the_static_posterior_and_its_verdict_do_not_depend_on_the_backend():
    """The cubature Kalman filters' banks (onset cells, held magnitudes, a
    drifting parameter) on the RO plant, through a whole ckf diagnosis: the
    same verdict, hypotheses' weights and estimate on both backends."""
    import bgc

    numba_package("ro")
    reports = [bgc.diagnose("models/ro.yaml", scenario="R_pipe:incipient:0.5@165", seed=1,
                            options=DiagnosisOptions(filter="ckf", seed=1, workers=1), backend=b)
               for b in ("numpy", "numba")]
    a, b = (r.diagnosis for r in reports)
    assert (a.verdict, a.candidates, a.onset) == (b.verdict, b.candidates, b.onset)
    weights = [{h.name: (h.posterior, h.static_log_evidence) for h in d.hypotheses} for d in (a, b)]
    assert weights[0].keys() == weights[1].keys()
    for k, (p, e) in weights[0].items():
        q, f = weights[1][k]
        assert abs(p - q) <= 1e-8 and (e == f or abs(e - f) <= 1e-8 * abs(e)), k
    assert abs(a.estimate.value - b.estimate.value) <= 1e-8 * abs(a.estimate.value)
    assert abs(a.estimate.high - b.estimate.high) <= 1e-8 * abs(a.estimate.high)


@pytest.mark.numba
@pytest.mark.process
@pytest.mark.long
def test_the_cli_runs_a_diagnosis_and_a_campaign_on_the_compiled_backend(tmp_path, new_cache):
    """``bgc diagnose --backend numba -v`` says in one line how its kernels were
    had (compiled or loaded) and writes the same verdict as on NumPy; a
    campaign's rows are the same on both backends but for the run time. The
    campaigns use the cold-cache test's bgc cache, the compiled one in a
    process of that test's environment (numba reads where its disk cache is
    when it is imported): the resistor loop's kernels that test compiled
    into its bgc cache are loaded, not compiled again (a campaign compiles
    its models into bgc's cache, not from generated/); the NumPy one runs in
    this process."""
    import csv
    import textwrap

    lines = {}
    numba_package("circuit")
    for backend in ("numpy", "numba"):
        out = bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--particles", "200",
                      "--steps", "150", "--backend", backend, "-v", "-o", tmp_path / f"d-{backend}")
        assert out.returncode == 0, out.stderr
        lines[backend] = out.stdout.splitlines()[0]
        assert ("numba backend: " in out.stderr) == (backend == "numba")
    assert lines["numpy"] == lines["numba"]
    config = tmp_path / "c.yaml"
    config.write_text(textwrap.dedent(f"""\
        campaign: b
        seed: 1
        defaults: {{steps: 60, filters: [gpf], particles: [100], seeds: 1}}
        groups:
          - name: g
            model: {ROOT / "tests" / "data" / "models" / "resistor_loop.yaml"}
            scenarios: [none, "R2:abrupt:1.5@30"]
        """), encoding="utf-8")
    rows = {}
    for backend in ("numpy", "numba"):
        args = ["experiment", str(config), "--workers", "1", "--no-progress", "--backend", backend,
                "-o", str(tmp_path / f"e-{backend}")]
        if backend == "numpy":
            out = bgc_cli(*args, env={"BGC_CACHE_DIR": new_cache[0]["BGC_CACHE_DIR"]})
        else:
            out = subprocess.run([sys.executable, "-m", "bgc", *args], cwd=ROOT, env=new_cache[0], capture_output=True,
                                 text=True, timeout=900)
        assert out.returncode == 0, out.stderr
        with open(tmp_path / f"e-{backend}" / "runs.csv", encoding="utf-8") as f:
            table = csv.DictReader(line for line in f if not line.startswith("#"))
            rows[backend] = [{k: v for k, v in r.items() if k != "rt"} for r in table]
        assert "rt" in table.fieldnames and "verdict" in table.fieldnames
    assert len(rows["numpy"]) == len(rows["numba"]) == 2
    def same(x: str, y: str) -> bool:  # numbers to rounding (the backends add in their own order)
        try:
            return x == y or abs(float(x) - float(y)) <= 1e-9 * max(abs(float(x)), 1e-300)
        except ValueError:
            return False
    for a, b in zip(rows["numpy"], rows["numba"]):
        differ = {k: (a[k], b[k]) for k in a if not same(a[k], b[k])}
        assert not differ, differ


@pytest.mark.parametrize("name", ["orifice_tanks"])
@pytest.mark.numba
def test_plants_nobody_here_wrote_compile_to_the_same_numbers(name, tmp_path):
    """A test plant whose laws the shipped ones lack (tanks with orifices:
    sqrt, abs and sign; the resistor loop's algebraic loop is compared on
    both backends by the campaign of the CLI test above; every package
    compiles its own copy of the kernel's loops, so each plant costs),
    written into a fresh folder (the compiled package: into the folder of bgc's cache that bgc.open gives it, where numba's disk cache
    stays valid from run to run): the nominal model and a fault model on
    both backends, the generic particle filter and the cubature Kalman
    filter, agree to 1e-10 (only these two modules are compiled)."""
    from bgc.api.folders import _lasting_folder
    from bgc.output import artifacts
    from bgc.pipeline import generated_files

    c = compiled(name)
    artifacts.write_folder(tmp_path / c.model.name, generated_files(c))
    ys, us = record(name, steps=60)
    numpy_pkg = loading.load_package(tmp_path, c.model.name, backend="numpy")
    numba_pkg = loading.load_package(_lasting_folder(c), c.model.name, backend="numba")
    for module in ("nominal", sorted(numpy_pkg.MODELS)[1]):
        runs = [p.filters.GenericParticleFilter(p.MODELS[module], 64, np.random.default_rng(2)).run(ys, us)
                for p in (numpy_pkg, numba_pkg)]
        assert max(difference(getattr(runs[0], k), getattr(runs[1], k)) for k in ("mean", "y_std")) <= TOLERANCE
        kf = [kalman.CubatureKalmanFilter(p.MODELS[module]) for p in (numpy_pkg, numba_pkg)]
        steps = [[f.step(ys[k], us[k]) for k in range(len(ys))] for f in kf]
        assert difference(np.array([s.mean for s in steps[0]]), np.array([s.mean for s in steps[1]])) <= TOLERANCE


@pytest.mark.numba
def test_a_diverged_particle_is_recovered_alike_on_both_backends():
    """A particle whose prediction is +inf: the NumPy filter's weighing makes
    its log-weight NaN (shift - y < 0 against +inf), and the step recovers;
    the compiled weighing does the same arithmetic, so it recovers too. And
    quietly: no NumPy warning reaches the caller (the step handles the
    particle; a user stepping a filter saw "invalid value encountered in add")."""
    import warnings

    outs = []
    for p in packages("two_tank"):
        model = p.MODELS["nominal"]
        f = p.filters.GenericParticleFilter(model, 8, np.random.default_rng(0))
        f.x[0, 3] = np.inf
        y = np.array(model.observe(np.array(model.X0, dtype=float)[:, None].copy(), model.inputs(0.0),
                                   model.THETA))[:, 0] + 5.0 * np.asarray(model.MEASUREMENT_STD)
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            outs.append((f.step(y, model.inputs(0.0)), f.recoveries))
    (a, ra), (b, rb) = outs
    assert ra == rb == 1 and a.recovered and b.recovered
    assert difference(a.mean[None, :], b.mean[None, :]) <= TOLERANCE


@pytest.mark.numba
def test_above_two_blocks_of_particles_the_backends_agree_too():
    """From 2 * BLOCK particles the filters take the block-wise steps (the
    compiled prediction and measurements still): the same numbers."""
    ys, us = record("two_tank", steps=24)
    runs = []
    for p in packages("two_tank"):
        n = 2 * p.MODELS["nominal"]._kernel.BLOCK + 5
        runs.append(p.filters.GenericParticleFilter(p.MODELS["nominal"], n, np.random.default_rng(4)).run(ys, us))
    assert max(difference(getattr(runs[0], k), getattr(runs[1], k)) for k in ("mean", "std", "y_std")) <= TOLERANCE


def test_integers_beyond_64_bits_reach_the_compiled_kernels_as_the_float_numpy_makes():
    from bgc.compiler.codegen import _machine_ints

    assert _machine_ints("_c0 = 1180591620717411303424*x + 3*y - 2.5e10") == \
        f"_c0 = {float(2 ** 70)!r}*x + 3*y - 2.5e10"
    assert _machine_ints("_y[0] = 9223372036854775807*e6") == "_y[0] = 9223372036854775807*e6"  # int64 holds it


def test_auto_falls_back_to_numpy_when_the_compiled_package_is_missing(tmp_path, monkeypatch):
    """A folder written by an older bgc (no numba_model): ``auto``, for work
    that repays compiling the kernels, runs on NumPy and says why in its one
    line (for less work it does not try numba: no kernels are cached);
    ``numba`` by name is refused in one line."""
    import shutil

    import bgc

    shutil.copytree(ROOT / "generated" / "circuit", tmp_path / "circuit",
                    ignore=shutil.ignore_patterns("numba_model", "__pycache__"))
    monkeypatch.delenv("BGC_BACKEND", raising=False)
    small = bgc.open("models/circuit.yaml", generated=tmp_path, work=(1000, 300))
    assert small.backend == "numpy" and small.fallback is None and "not compiled yet" in small.backend_reason
    session = bgc.open("models/circuit.yaml", generated=tmp_path, work=(100_000, 1000))
    assert session.backend == "numpy" and "numba backend unavailable" in session.backend_note()
    assert "numba_model" in session.backend_note()
    with pytest.raises(TrackingError, match=r"use backend='numpy'\)"):
        bgc.open("models/circuit.yaml", generated=tmp_path, backend="numba")


@pytest.mark.numba
def test_compiled_draws_are_the_generators_own_numbers_and_leave_it_where_numpy_would():
    """The compiled kernel draws from a Generator through its bit generator's
    handle (no conversion of the Generator per call): the numbers of
    ``rng.standard_normal`` of the same shape, and the generator's next draw
    the same after, for two bit generators; a column range fills those
    columns only, row by row."""
    kernel = packages("ro")[1].MODELS["nominal"]._kernel
    for bits in (np.random.PCG64, np.random.Philox):
        ours, theirs = np.random.Generator(bits(11)), np.random.Generator(bits(11))
        out = np.full((3, 7), 9.0)
        kernel.normal_into(ours, out, 2, 6)
        assert np.array_equal(out[:, 2:6], theirs.standard_normal((3, 4)))
        assert (out[:, :2] == 9.0).all() and (out[:, 6:] == 9.0).all()
        assert ours.random() == theirs.random()
    assert kernel.generator_handle(np.random.RandomState(0)) is None


@pytest.mark.numba
def test_a_compiled_generic_filter_step_is_one_call_with_the_numpy_filters_numbers(monkeypatch):
    """Up to two blocks of particles the compiled package's generic filter
    makes a whole step in one compiled call (the model's transition is not
    called), resampling (a uniform drawn only then) as the NumPy filter does:
    the same outputs and the same generator state after every step."""
    ys, us = record("ro", steps=40)
    numpy_pkg, numba_pkg = packages("ro")
    model = numba_pkg.MODELS["R_pipe_abrupt"]
    monkeypatch.setattr(model, "transition", lambda *a, **k: pytest.fail("the step was not one compiled call"))
    filters = [p.filters.GenericParticleFilter(p.MODELS["R_pipe_abrupt"], 200, np.random.default_rng(5))
               for p in (numpy_pkg, numba_pkg)]
    resampled = 0
    for y, u in zip(ys, us):
        a, b = (f.step(y, u) for f in filters)
        assert a.resampled == b.resampled
        resampled += a.resampled
        for k in ("mean", "std", "y_mean", "y_std", "ess"):
            assert difference(np.atleast_1d(getattr(a, k))[None, :], np.atleast_1d(getattr(b, k))[None, :]) <= TOLERANCE
        assert filters[0].rng.bit_generator.state == filters[1].rng.bit_generator.state
    assert 0 < resampled < len(ys)


def test_a_compiled_model_names_the_kernel_its_cached_step_was_compiled_with():
    """numba's disk cache of a model's compiled step holds the kernel's loops
    and is renewed only when the model's file changes: each ``_jit_<model>.py``
    carries the sha256 of the ``_jit_kernel.py`` beside it, so a new kernel
    rewrites every model file."""
    import hashlib

    from bgc.filters import _jit_kernel

    source = open(_jit_kernel.__file__, encoding="utf-8").read()
    for name in MODELS:
        folder = ROOT / "generated" / name / "numba_model"
        shipped = (folder / "_jit_kernel.py").read_text(encoding="utf-8")
        assert shipped.endswith(source)
        digest = hashlib.sha256(source.encode("utf-8")).hexdigest()
        for path in folder.glob("_jit_*.py"):
            if path.name != "_jit_kernel.py":
                assert f'KERNEL_SHA256 = "{digest}"' in path.read_text(encoding="utf-8"), path


@pytest.mark.numba
def test_the_compiled_quadrature_of_the_static_posterior_is_the_numpy_ones():
    """``quadrature.row_quadrature`` on a compiled package's kernel (one call)
    gives the NumPy rule's nodes and log masses: Gaussian and steep rows
    (several panels), rows cut by the prior (-inf), a neighbour far below
    (ignored by the parabola), two points, random rows."""
    kernel = packages("ro")[1].MODELS["nominal"]._kernel
    assert hasattr(kernel, "row_quadrature")
    rng = np.random.default_rng(3)
    v = np.linspace(-2.0, 3.0, 11)
    rows = [-v ** 2 / 2, -40.0 * v ** 2, np.where(v < 0, -np.inf, -v), np.r_[-1e20, -v[1:] ** 2],
            rng.normal(0, 30, 11), np.r_[-np.inf, rng.normal(0, 3, 9), -np.inf]]
    for lg in rows:
        a, b = quadrature.row_quadrature(v, lg), quadrature.row_quadrature(v, lg, kernel)
        assert a[0].shape == b[0].shape and np.array_equal(a[0], b[0])
        assert np.array_equal(np.isfinite(a[1]), np.isfinite(b[1]))
        finite = np.isfinite(a[1])
        assert np.allclose(a[1][finite], b[1][finite], rtol=1e-14, atol=1e-13)
    assert np.array_equal(quadrature.row_quadrature(v[:2], np.zeros(2), kernel)[0],
                          quadrature.row_quadrature(v[:2], np.zeros(2))[0])


@pytest.mark.numba
def test_a_prepared_filter_makes_nothing_on_its_first_step_and_gives_the_same_numbers():
    """``prepare`` (an online diagnoser calls it before its first sample)
    makes the weights, the Gaussian terms of the sensors read and, compiled,
    the generator's handle before the data come: the first step then adds no
    Gaussian terms and finds the handle, and a prepared filter gives the
    numbers of one that is not, on both backends, to the bit."""
    ys, us = record("ro", steps=24)
    for package in packages("ro"):
        model = package.MODELS["nominal"]
        plain, ready = (package.filters.GenericParticleFilter(model, 200, np.random.default_rng(8)) for _ in range(2))
        ready.prepare(np.isfinite(ys[0]))
        terms = dict(ready._gauss)
        assert len(terms) == 1 and ready.w is not None
        compiled = hasattr(model._kernel, "generator_handle")
        if compiled:
            assert model._kernel._HANDLES[id(ready.rng)][0] is ready.rng
        for k, (y, u) in enumerate(zip(ys, us)):
            a, b = plain.step(y, u), ready.step(y, u)
            if k == 0:  # the first step found what prepare made
                assert ready._gauss.keys() == terms.keys()
                assert all(ready._gauss[key] is terms[key] for key in terms)
            for key in ("mean", "std", "y_mean", "y_std", "ess"):
                assert np.array_equal(getattr(a, key), getattr(b, key))
            assert plain.rng.bit_generator.state == ready.rng.bit_generator.state
    import bgc

    d = bgc.open(ROOT / "models" / "circuit.yaml", backend="numpy").diagnoser(filter="gpf", particles=200, seed=3)
    assert len(d.pf._gauss) == 1 and d.pf.w is not None  # the diagnoser prepared its filter
