"""The compile cache (bgc/api/cache.py) and the compiled model's plain-data
view it keeps (bgc/view.py): hits and misses, processes writing at once,
what clearing removes, a hit without sympy, the same numbers with and without
it, and --backend auto's note of numba's cached kernels."""

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from bgc.analysis import simulate
from bgc.api import cache
from bgc.model import package as packages
from bgc.view import from_json, to_json
from bgc.pipeline import view

from conftest import ALL_MODELS, ROOT, compiled


@pytest.fixture()
def root(tmp_path, monkeypatch):
    """An empty cache folder of this test."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("BGC_CACHE_DIR", str(folder))
    return folder


@pytest.fixture()
def tanks(tmp_path):
    """A copy of the two tanks' model file, to change."""
    path = tmp_path / "tanks.yaml"
    path.write_text((ROOT / "models" / "two_tank.yaml").read_text(encoding="utf-8"), encoding="utf-8")
    return path


def entries(root):
    return sorted(p.name for p in (root / cache.MODELS).iterdir())


@pytest.mark.parametrize("name", sorted(ALL_MODELS))
def test_a_view_read_back_is_the_view_written(name):
    """Every field of the view survives its JSON to the bit (floats by their
    shortest repr, complex eigenvalues, places in the file), and its methods
    are the IRs': the same noise levels and fault numbers as the compilation's."""
    c = compiled(name)
    v = view(c)
    back = from_json(to_json(v), v.model.source)
    assert back == v
    assert back.numerics.noise_at(0.05, 0.01) == c.numerics.noise_at(0.05, 0.01)
    assert back.numerics.noise == c.numerics.noise
    assert [back.numerics.fault(f.name) for f in c.numerics.faults] == list(c.numerics.faults)
    assert back.model.display_source == c.model.display_source
    assert back.model.settings.loc("dt") == c.model.settings.loc("dt")
    assert [back.dbn.get(d.name).name for d in (c.dbn.nominal, *c.dbn.faulty)] == \
        [d.name for d in (c.dbn.nominal, *c.dbn.faulty)]
    other = from_json(to_json(v), "elsewhere/model.yaml")  # a view is read with the path the model is opened by
    assert other.model.source == other.equations.model.source == other.numerics.equations.model.source \
        == "elsewhere/model.yaml"
    assert other.model.settings.loc("dt") is None or other.model.settings.loc("dt").file == "elsewhere/model.yaml"


@pytest.mark.parametrize("name", ["two_tank", "ro", "orifice_tanks"])
def test_the_truth_from_the_view_is_the_truth_from_sympy(name):
    """The truth simulator on the view runs the code lambdify printed, made
    again without sympy: the same run to the bit as on the compilation."""
    c = compiled(name)
    v = from_json(to_json(view(c)), c.model.source)
    assert v.equations.truth is not None
    fault = c.numerics.faults[0]
    magnitude = simulate.change_magnitude(c.numerics, fault.name, 0.3, 20 * c.model.settings.dt)
    options = simulate.SimulationOptions(steps=60, seed=4, fault=simulate.FaultInjection(
        fault.parameter, fault.name.split(":")[1], magnitude, 20 * c.model.settings.dt))
    a, b = simulate.simulate(c.numerics, options), simulate.simulate(v.numerics, options)
    for field in ("time", "inputs", "measurements", "clean_measurements", "states", "parameter"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.header == b.header


def test_a_model_is_compiled_once_then_read_while_text_options_and_bgc_stay(root, tanks, monkeypatch):
    first = cache.open_model(tanks)
    assert first.compiled is not None and first.entry is not None
    again = cache.open_model(tanks)
    assert again.compiled is None and again.entry == first.entry and again.view == first.view
    assert entries(root) == [first.entry.name]
    # another prior scale, another text (a comment), another bgc: each its own entry, compiled
    assert cache.open_model(tanks, prior_scale=2.0).compiled is not None
    tanks.write_text(tanks.read_text(encoding="utf-8") + "# a comment\n", encoding="utf-8")
    assert cache.open_model(tanks).compiled is not None
    monkeypatch.setattr(cache, "__version__", "0.0.0-other")
    assert cache.open_model(tanks).compiled is not None
    monkeypatch.setattr(cache, "code_digest", lambda: "edited")
    assert cache.open_model(tanks).compiled is not None
    assert len(entries(root)) == 5
    assert cache.open_model(tanks).compiled is None  # and that one is kept too


def test_the_same_text_at_another_path_is_read_with_its_own_path(root, tanks, tmp_path):
    cache.open_model(tanks)
    moved = tmp_path / "elsewhere" / "tanks.yaml"
    moved.parent.mkdir()
    moved.write_bytes(tanks.read_bytes())
    o = cache.open_model(moved)
    assert o.compiled is None and o.view.model.source == str(moved)
    assert o.view.model.display_source == "elsewhere/tanks.yaml"


@pytest.mark.slow
def test_two_processes_writing_one_entry_at_once_leave_one_whole_entry(root, tanks):
    """Both compile the model (nothing cached yet) and write its entry at
    the same time: one rename wins, the other copy is dropped, neither
    fails, and no temporary folder is left."""
    probe = textwrap.dedent(f"""\
        import json, sys
        from bgc.api import cache
        o = cache.open_model({str(tanks)!r})
        print(json.dumps([o.entry.name, o.compiled is not None, o.view.model.name]))
        """)
    procs = [subprocess.Popen([sys.executable, "-c", probe], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err
        assert err == ""
    results = [json.loads(out) for out, _ in outs]
    assert results[0][0] == results[1][0] and {r[2] for r in results} == {"two_tank"}
    assert entries(root) == [results[0][0]]  # no temporary folder beside it
    o = cache.open_model(tanks)
    assert o.compiled is None and (o.entry / "two_tank" / "numpy_model" / "__init__.py").is_file()


def test_a_half_written_entry_is_never_read(root, tanks):
    """A writer killed before its rename leaves a temporary folder: it is
    not the entry, and the model is compiled and its entry written."""
    key = cache.key_of(tanks.read_bytes())
    half = root / cache.MODELS / f".{key}-killed"
    half.mkdir(parents=True)
    (half / "view.json").write_text("{", encoding="utf-8")
    o = cache.open_model(tanks)
    assert o.compiled is not None and o.entry.name == key
    assert cache.open_model(tanks).compiled is None


def test_an_entry_that_cannot_be_read_is_compiled_afresh_with_a_warning(root, tanks):
    o = cache.open_model(tanks)
    (o.entry / "view.json").write_text('{"format": 1, "view": {"@": "os.system"}}', encoding="utf-8")
    with pytest.warns(cache.CacheWarning, match="bgc cache clear"):
        again = cache.open_model(tanks)
    assert again.compiled is not None and again.entry is None and again.view == o.view


def test_a_cache_that_cannot_be_written_leaves_every_call_compiling(tmp_path, tanks, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder\n", encoding="utf-8")
    monkeypatch.setenv("BGC_CACHE_DIR", str(blocker))
    with pytest.warns(cache.CacheWarning, match="BGC_CACHE_DIR"):
        o = cache.open_model(tanks)
    assert o.compiled is not None and o.entry is None
    assert (tmp_path / "a-file").read_text(encoding="utf-8") == "not a folder\n"


def test_clear_removes_what_bgc_wrote_and_nothing_else(root, tanks, capsys):
    from bgc.cli import main

    o = cache.open_model(tanks)
    cache.mark_warm(cache.numba_folder(o) + "/two_tank/numba_model", 3)
    foreign = [root / "notes.txt", root / cache.MODELS / "mine", root / cache.MODELS / ("0" * 64),
               root / cache.PACKAGES / "two_tank-0123456789abcdef0123"]
    foreign[0].write_text("keep\n", encoding="utf-8")
    for folder in foreign[1:]:
        folder.mkdir(parents=True)
        (folder / "keep.txt").write_text("keep\n", encoding="utf-8")
    assert main(["cache"]) == 0
    listed = capsys.readouterr().out
    assert str(root) in listed and "two_tank" in listed and "bgc cache clear" in listed
    kinds = sorted(i.kind for i in cache.items(root))
    assert kinds == ["model", "note", "package"]
    assert main(["cache", "clear"]) == 0
    out = capsys.readouterr().out
    assert "removed" in out and "1 compiled model" in out and "1 compiled (numba) package" in out
    assert cache.items(root) == []
    for path in foreign:
        assert path.exists(), path
    assert not (root / cache.WARM).exists()
    assert cache.open_model(tanks).compiled is not None  # compiled again after a clear


def test_clear_unused_days_keeps_what_was_used_since(root, tanks, capsys):
    """``bgc cache clear --unused-days 30`` removes the entries and packages
    last used over 30 days ago and keeps the others; using a package again
    (a session opening it) marks it used."""
    from bgc.cli import main

    old, new = cache.open_model(tanks), None
    package = Path(cache.numba_folder(old))
    month = time.time() - 31 * 86400
    os.utime(old.entry / "entry.json", (month, month))
    os.utime(package, (month, month))
    tanks.write_text(tanks.read_text(encoding="utf-8") + "# another text\n", encoding="utf-8")
    new = cache.open_model(tanks)
    assert sorted(i.kind for i in cache.items(root)) == ["model", "model", "package"]
    assert main(["cache", "clear", "--unused-days", "30"]) == 0
    assert "1 compiled model, 1 compiled (numba) package" in capsys.readouterr().out
    assert [i.path for i in cache.items(root)] == [new.entry]
    package = Path(cache.numba_folder(new))  # made again; used now
    os.utime(package, (month, month))
    cache.numba_folder(new)  # a later use marks it used
    assert main(["cache", "clear", "--unused-days", "30"]) == 0
    assert sorted(i.kind for i in cache.items(root)) == ["model", "package"]
    assert main(["cache", "list", "--unused-days", "3"]) == 1
    assert "--unused-days is for clear" in capsys.readouterr().err


@pytest.mark.slow
def test_a_hit_imports_neither_sympy_nor_the_compiler(root):
    """A diagnosis of a scenario (the truth simulated, then diagnosed) and
    its report, served by the cache: sympy, networkx and the compiler's
    stages are never imported; the first call, which compiles, does. (60
    steps, the fault from sample 30: it is still found and sized, which is
    what imports the most.)"""
    probe = textwrap.dedent("""\
        import sys
        from bgc.cli import main
        status = main(["diagnose", "models/two_tank.yaml", "--scenario", "R12:abrupt:1.0@15", "--particles", "100",
                       "--steps", "60", "--backend", "numpy", "-o", sys.argv[1]])
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("sympy", "networkx")
                       or m.startswith(("bgc.compiler.", "bgc.pipeline")) and m != "bgc.compiler.rk4")
        print(status, len(heavy), heavy[:5])
        """)
    outs = [subprocess.run([sys.executable, "-c", probe, str(root.parent / f"d{i}")], cwd=ROOT, capture_output=True,
                           text=True, timeout=600) for i in range(2)]
    for out in outs:
        assert out.returncode == 0, out.stderr
    first, again = (o.stdout.splitlines()[-1].split()[:2] for o in outs)
    assert first[0] == again[0] == "0"
    assert int(first[1]) > 0
    assert again[1] == "0", outs[1].stdout
    reports = [json.loads((root.parent / f"d{i}" / "report.json").read_text(encoding="utf-8")) for i in range(2)]
    for r in reports:
        r.pop("seconds")
    assert reports[0] == reports[1]


@pytest.mark.slow
def test_a_diagnosis_is_the_same_with_and_without_the_cache(root):
    """The same diagnosis, to the bit, from a fresh compilation (a miss),
    from the cache (a hit) and from the committed generated package and a
    compilation that never met the cache. (80 of the circuit's 300 steps:
    the fault at t = 1.5 is sample 30, found, isolated and sized by the 50
    samples after it.)"""
    import bgc
    from bgc.api import folders
    from bgc.diagnosis.diagnose import diagnose as run_diagnosis
    from bgc.model.package import load_package

    kwargs = dict(scenario="R2:abrupt:0.6@1.5", seed=3, particles=200, steps=80, backend="numpy")
    miss = bgc.diagnose("models/circuit.yaml", **kwargs)
    assert miss.diagnosis.verdict == "isolated" and miss.diagnosis.estimate is not None  # a diagnosis with all its parts
    hit = bgc.diagnose("models/circuit.yaml", **kwargs)
    c, folder = folders._compiled("models/circuit.yaml")
    package = load_package(folder, "circuit")
    plain = run_diagnosis(miss.run, package, c.signatures, {f.parameter: f.prior for f in c.model.faults},
                          miss.diagnosis.options)
    for d in (hit.diagnosis, plain):
        assert d.verdict == miss.diagnosis.verdict and d.candidates == miss.diagnosis.candidates
        assert d.estimate == miss.diagnosis.estimate
        assert d.events == miss.diagnosis.events
        assert [h.posterior for h in d.hypotheses] == [h.posterior for h in miss.diagnosis.hypotheses]
    np.testing.assert_array_equal(miss.run.measurements["e11"], hit.run.measurements["e11"])


def test_a_session_served_by_the_cache_compiles_its_irs_on_first_use(root, tanks):
    import bgc

    bgc.open(tanks)
    s = bgc.open(tanks)
    assert s._compiled is None
    assert s.compiled.model.name == "two_tank" and s.compiled.model.source_sha256 == s.view.model.source_sha256
    tanks.write_text(tanks.read_text(encoding="utf-8") + "# changed\n", encoding="utf-8")
    t = bgc.open(tanks)
    bgc.open(tanks)
    t._compiled = None
    tanks.write_text(tanks.read_text(encoding="utf-8") + "# changed again\n", encoding="utf-8")
    with pytest.raises(bgc.errors.ArgumentValueError, match="changed since it was opened"):
        t.compiled


# ---------------------------------------------------------------- --backend auto
def test_auto_chooses_numba_only_for_cached_kernels_or_work_that_repays_compiling(monkeypatch):
    monkeypatch.setattr(packages, "numba_installed", lambda: True)
    assert packages.auto_backend(300_000, False)[0] == "numpy"
    assert packages.auto_backend(None, False)[0] == "numpy"
    assert packages.auto_backend(packages.COMPILE_WORK, False)[0] == "numba"
    assert packages.auto_backend(300_000, True)[0] == "numba"
    assert packages.auto_backend(None, True)[0] == "numba"
    assert packages.auto_backend(packages.LOAD_WORK - 1, True)[0] == "numpy"
    monkeypatch.setattr(packages, "numba_installed", lambda: False)
    assert packages.auto_backend(10 * packages.COMPILE_WORK, True) == ("numpy", "auto: numba is not installed")


def test_numbas_cached_kernels_are_noted_until_the_package_changes(root, tanks, monkeypatch):
    pytest.importorskip("numba")
    from bgc.api.session import choose_backend

    monkeypatch.delenv("BGC_BACKEND", raising=False)
    o = cache.open_model(tanks)
    package = cache.numba_path(o)
    assert not cache.kernels_cached(package)
    assert choose_backend(None, package, 300_000)[0] == "numpy"
    assert cache.numba_folder(o) == str(package.parent.parent)  # where numba_path said
    cache.mark_warm(package, 44)
    assert cache.kernels_cached(package)
    assert choose_backend("auto", package, 300_000)[0] == "numba"
    assert choose_backend("numpy", package, 300_000) == ("numpy", "asked for")
    monkeypatch.setenv("BGC_BACKEND", "numpy")
    assert choose_backend(None, package, 300_000) == ("numpy", "BGC_BACKEND")
    init = package / "__init__.py"
    os.utime(init, ns=(init.stat().st_atime_ns, init.stat().st_mtime_ns + 10**9))
    assert not cache.kernels_cached(package)


def test_auto_for_a_campaign_counts_the_particle_steps_of_all_its_runs(root, tmp_path, monkeypatch):
    """A local campaign's auto backend: numpy for a small campaign whose
    kernels are not cached, numba once they are noted in numba's cache, and
    numba for a campaign whose runs add up to work that repays compiling
    (the rule ``bgc experiment`` and ``run_campaign`` share)."""
    from bgc.experiment import campaign_file, dispatch
    from bgc.experiment.one_run import model_file

    def _auto_backend(c):
        return dispatch.campaign_backend(c.specs)

    monkeypatch.setattr(packages, "numba_installed", lambda: True)
    monkeypatch.delenv("BGC_BACKEND", raising=False)  # the suite's numpy: auto decides here
    config = tmp_path / "c.yaml"

    def campaign(particles: int, seeds: int):
        config.write_text(textwrap.dedent(f"""\
            campaign: auto
            seed: 1
            defaults: {{steps: 300, filters: [gpf], particles: [{particles}], seeds: {seeds}}}
            groups:
              - name: g
                model: {ROOT / "models" / "two_tank.yaml"}
                scenarios: [none, "R12:abrupt:1.0@60"]
            """), encoding="utf-8")
        return campaign_file.load_campaign(config)

    small = campaign(100, 1)  # 2 runs of 100 particles over 300 steps
    assert _auto_backend(small) == packages.auto_backend(60_000, False)
    assert _auto_backend(small)[0] == "numpy"
    large = campaign(20_000, 2)  # 4 runs: 24 000 000 particle-steps
    assert _auto_backend(large)[0] == "numba"
    cache.mark_warm(cache.numba_folder(cache.open_model(model_file(small.specs[0]))) + "/two_tank/numba_model", 44)
    assert _auto_backend(campaign(1000, 1))[0] == "numba"  # cached, 600 000 particle-steps
    assert dispatch.campaign_backend(small.specs, "numpy") == ("numpy", None)  # asked for by name
    assert dispatch.campaign_backend(small.specs, "auto", "tcp://h:8786") == ("auto", None)  # each Dask worker
