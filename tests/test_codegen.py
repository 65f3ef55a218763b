"""The generated NumPy packages (bgc.codegen: templates for the model modules, bgc's
plain filters and kernel copied), checked as a reviewed product.

Four ways, as STYLE.md asks: the committed modules parse and import numpy only;
they compute what ``sympy.lambdify`` computes from the compiler's own equations
(``compile_model(...).equations``) at random points; the RK4 step agrees with the
exact matrix-exponential discretisation of a linear model within a derived
bound; and the stability rule gives the number of substeps the eigenvalues of
an independently computed linearisation ask for. Same seed, same numbers.
"""

import ast
import importlib.util
import math
import re
import subprocess
import sys
import textwrap
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import sympy
from hypothesis import given, settings
from hypothesis import strategies as st

from bgc.compiler import codegen
from bgc.errors import BgcError
from bgc.ir import sym
from bgc.kinds import fault_kind
from bgc.pipeline import compile_model

import conftest
from conftest import ROOT

MODELS = ["circuit", "two_tank", "ro"]
LINEAR = ["circuit", "two_tank"]
#: RK4 stability margin of the rule: |lambda|max * h <= 1.5 (bgc.modelspec documents it).
H_LAMBDA = 1.5


# ------------------------------------------------------------------ helpers
def package_dir(model: str) -> Path:
    return ROOT / "generated" / model / "numpy_model"


def load_package(directory: Path, name: str):
    """Import a generated package by path, as a package (its __init__ uses relative imports)."""
    spec = importlib.util.spec_from_file_location(name, directory / "__init__.py",
                                                  submodule_search_locations=[str(directory)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[name] = package
    spec.loader.exec_module(package)
    return package


@lru_cache(maxsize=None)
def package(model: str):
    return load_package(package_dir(model), f"_bgc_generated_{model}")


def compiled(model: str):
    """A shipped model compiled once per test session (conftest.compiled)."""
    return conftest.compiled(model)


def module_files(model: str) -> list[str]:
    return sorted(p.stem for p in package_dir(model).glob("*.py") if p.stem not in ("__init__", "filters", "_kernel"))


def _enters_an_equation(name: str) -> bool:
    """Whether fault module ``name`` (``<subject>_<kind>``, e.g. ``F_back_stuck_stuck``) is of a kind whose
    fault enters an equation (not a stuck reading, not a noise factor)."""
    kind = fault_kind(name.rsplit("_", 1)[1])
    return not (kind.replaces or kind.noise)


MODULES = [(m, name) for m in MODELS for name in module_files(m)]
#: The fault modules whose fault enters an equation: a parameter, a sensor's offset, an input's bias or gain.
#: A stuck reading replaces the sensor's reading at any value of its state, and a noise factor enters no
#: equation (it scales measurement_std): tests/test_sensor_faults.py and tests/test_noise_fault.py test
#: those kinds' modules by hand.
FAULT_MODULES = [(m, name) for m, name in MODULES if name != "nominal" and _enters_an_equation(name)]


class Reference:
    """``sympy.lambdify`` of the compiler's equations, vectorised over particles."""

    def __init__(self, ssm):
        xs = [sym(s) for s in ssm.states]
        us = [sym(s) for s in ssm.inputs]
        ps = [sym(s) for s in ssm.parameters]
        self.ssm = ssm
        self._rhs = sympy.lambdify([xs, us, ps], list(ssm.rhs), modules="numpy")
        self._out = sympy.lambdify([xs, us, ps], list(ssm.output_exprs), modules="numpy")

    @staticmethod
    def _stack(values, n):
        return np.array([np.broadcast_to(np.asarray(v, dtype=float), (n,)) for v in values])

    def rhs(self, x, u, theta):
        return self._stack(self._rhs(list(x), list(u), list(theta)), x.shape[1])

    def out(self, x, u, theta):
        return self._stack(self._out(list(x), list(u), list(theta)), x.shape[1])


@lru_cache(maxsize=None)
def reference(model: str) -> Reference:
    return Reference(compiled(model).equations)


def random_point(mod, ssm, rng, n=50):
    """Physical states, inputs and parameters near the nominal operating point."""
    x0 = np.array(ssm.initial)
    scale = np.where(x0 != 0, np.abs(x0), 1.0)
    x = x0[:, None] + 0.05 * scale[:, None] * rng.standard_normal((len(x0), n))
    u = mod.inputs(0.0) * (1.0 + 0.05 * rng.standard_normal(len(ssm.inputs)))
    theta = np.array(ssm.parameter_values) * (1.0 + 0.05 * rng.standard_normal(len(ssm.parameters)))
    return x, u, theta


def assert_close(got, want, what):
    """Relative 1e-10 per element, plus 1e-12 of the row's largest value: rounding differences are
    relative to the size of the terms, and one particle's result can be small by cancellation."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert got.shape == want.shape, (what, got.shape, want.shape)
    scale = np.max(np.abs(want), axis=1, keepdims=True)
    bad = ~(np.abs(got - want) <= 1e-10 * np.abs(want) + 1e-12 * scale)
    assert not bad.any(), f"{what}: {bad.sum()} values differ, e.g. row {np.argwhere(bad)[0][0]}: " \
                          f"{got[bad][:3]} != {want[bad][:3]}"


def linearisation(ssm, u0, theta):
    """Jacobian d rhs / d x at (X0, u0, theta) and the constant term, by sympy (an independent derivation)."""
    xs = [sym(s) for s in ssm.states]
    sub = {sym(p): v for p, v in zip(ssm.parameters, theta)}
    sub.update({sym(i): float(v) for i, v in zip(ssm.inputs, u0)})
    at_x0 = {**sub, **{x: v for x, v in zip(xs, ssm.initial)}}
    jac = sympy.Matrix(list(ssm.rhs)).jacobian(xs)
    a = np.array([[float(e.xreplace(at_x0)) for e in row] for row in jac.tolist()])
    return jac, a, sub


def expm(m):
    """Matrix exponential: Taylor series to 30 terms after scaling to norm <= 1/2, then squaring."""
    norm = np.linalg.norm(m, 1)
    s = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0 else 0
    a = m / 2.0 ** s
    result = np.eye(len(m))
    term = np.eye(len(m))
    for k in range(1, 30):
        term = term @ a / k
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


def taylor(z, order):
    """sum_{k <= order} z^k / k!: R(z) of an explicit Runge-Kutta method of that order on a linear ODE."""
    result = np.eye(len(z))
    term = np.eye(len(z))
    for k in range(1, order + 1):
        term = term @ z / k
        result = result + term
    return result


# ------------------------------------------------------ static: text and imports
@pytest.mark.parametrize("model,name", MODULES)
def test_model_module_parses_has_header_and_imports_numpy_only(model, name):
    source = (package_dir(model) / f"{name}.py").read_text()
    assert source.splitlines()[0] == f"# generated by bgc from models/{model}.yaml, do not edit"
    tree = ast.parse(source)
    imports = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert imports, "a model module uses numpy"
    for node in imports:
        if isinstance(node, ast.ImportFrom):  # the package's own numerics, nothing else
            assert node.level == 1 and node.module is None, ast.unparse(node)
            assert [a.name for a in node.names] == ["_kernel"], ast.unparse(node)
            continue
        assert [(a.name, a.asname) for a in node.names] == [("numpy", "np")], ast.unparse(node)
    assert "bgc" not in {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    # Dynamic imports would dodge the walk above.
    assert not re.search(r"__import__|importlib|\bexec\(|\beval\(", source)


@pytest.mark.parametrize("model", MODELS)
def test_filters_and_init_import_numpy_and_siblings_only(model):
    d = package_dir(model)
    for helper in ("filters.py", "_kernel.py"):
        text = (d / helper).read_text()
        assert text.splitlines()[0] == f"# generated by bgc from models/{model}.yaml, do not edit"
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                # numpy, and the standard library's threading (per-thread scratch arrays)
                assert isinstance(node, ast.Import) and [a.name for a in node.names] in (["numpy"], ["threading"]), \
                    ast.unparse(node)
    init = (d / "__init__.py").read_text()
    assert init.splitlines()[0] == f"# generated by bgc from models/{model}.yaml, do not edit"
    for node in ast.walk(ast.parse(init)):
        if isinstance(node, ast.Import):
            pytest.fail(ast.unparse(node))
        if isinstance(node, ast.ImportFrom):
            assert node.level == 1 and node.module is None, ast.unparse(node)
            assert {a.name for a in node.names} <= set(module_files(model)) | {"filters", "_kernel"}


@pytest.mark.parametrize("model", MODELS)
def test_filters_and_kernel_are_bgcs_plain_files_behind_the_header(model):
    """filters.py and _kernel.py are bgc/filters/particle.py and
    kernel.py as they are, behind the header line: fixed Python is a plain
    module of bgc (importable and linted on its own), not a template."""
    plain = ROOT / "bgc" / "filters"
    header = f"# generated by bgc from models/{model}.yaml, do not edit\n"
    for generated, source in (("filters.py", "particle.py"), ("_kernel.py", "kernel.py")):
        assert (package_dir(model) / generated).read_text(encoding="utf-8") == (
            header + (plain / source).read_text(encoding="utf-8")), generated
    assert not list((ROOT / "bgc" / "templates").glob("filters*")) + list((ROOT / "bgc" / "templates").glob("kernel*"))


def test_the_plain_files_import_as_bgc_modules_and_meet_the_filter_protocol():
    from bgc.filters import Filter, kernel, particle

    model = package("circuit").nominal
    assert model._kernel.__doc__ == kernel.__doc__
    for cls in (particle.GenericParticleFilter, particle.AuxiliaryParticleFilter,
                particle.OptimalProposalParticleFilter):
        assert isinstance(cls(model, 10, np.random.default_rng(0)), Filter), cls.__name__


@pytest.mark.parametrize("model", MODELS)
def test_package_lists_one_module_per_dbn_of_the_compiler(model):
    c = compiled(model)
    expected = {"nominal"} | {codegen.module_name(d.name) for d in c.dbn.faulty}
    assert set(module_files(model)) == expected
    pkg = package(model)
    assert set(pkg.MODELS) == expected
    for name, mod in pkg.MODELS.items():
        assert mod.NAME == name and mod.MODEL == model
        assert mod.__file__ == str(package_dir(model) / f"{name}.py")


@pytest.mark.process  # a fresh interpreter: this one has imported bgc and sympy
def test_importing_the_packages_loads_neither_bgc_nor_sympy():
    script = textwrap.dedent(f"""
        import importlib.util, sys
        for model in {MODELS!r}:
            d = {str(ROOT)!r} + "/generated/" + model + "/numpy_model"
            spec = importlib.util.spec_from_file_location("g_" + model, d + "/__init__.py",
                                                          submodule_search_locations=[d])
            m = importlib.util.module_from_spec(spec); sys.modules["g_" + model] = m; spec.loader.exec_module(m)
            assert len(m.MODELS) > 1
        bad = sorted(k for k in sys.modules if k.split(".")[0] in ("bgc", "sympy", "jinja2", "networkx"))
        print(bad)
    """)
    r = subprocess.run([sys.executable, "-c", script], cwd="/", capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


# -------------------------------------------------- numbers: lambdify agreement
@pytest.mark.parametrize("model", MODELS)
def test_nominal_derivative_and_observe_equal_lambdify(model):
    mod, ssm, ref = package(model).nominal, compiled(model).equations, reference(model)
    assert mod.STATES == ssm.states and mod.OUTPUTS == ssm.outputs and mod.PARAMETERS == ssm.parameters
    assert mod.THETA == ssm.parameter_values
    rng = np.random.default_rng(101)
    for _ in range(4):
        x, u, theta = random_point(mod, ssm, rng)
        assert_close(mod.derivative(x, u, tuple(theta)), ref.rhs(x, u, theta), "derivative")
        assert_close(mod.observe(x, u, tuple(theta)), ref.out(x, u, theta), "observe")


def _fault_layout(mod, ssm):
    p, kind = mod.FAULT["parameter"], mod.FAULT["kind"]
    n = len(ssm.states)
    assert mod.STATES[:n] == ssm.states
    if not fault_kind(kind).drifts:
        assert mod.STATES[n:] == (f"delta_{p}",) and mod.STATE_KINDS[n:] == ("bias",)
    else:
        assert mod.STATES[n:] == (p, f"delta_{p}") and mod.STATE_KINDS[n:] == ("parameter", "slope")
    return p, kind, n, ssm.parameters.index(p)


@pytest.mark.parametrize("model,name", FAULT_MODULES)
def test_fault_module_at_its_neutral_value_is_the_nominal_model(model, name):
    mod, ssm, ref = package(model).MODELS[name], compiled(model).equations, reference(model)
    p, kind, n, j = _fault_layout(mod, ssm)
    rng = np.random.default_rng(202)
    for _ in range(3):
        xp, u, theta = random_point(mod, ssm, rng)
        N = xp.shape[1]
        if not fault_kind(kind).drifts:
            x = np.vstack([xp, np.zeros((1, N))])
        else:  # parameter state = the parameter's value, any slope
            x = np.vstack([xp, np.full((1, N), theta[j]), rng.uniform(-1.0, 1.0, (1, N)) * (abs(theta[j]) or 1.0)])
        dx = mod.derivative(x, u, tuple(theta))
        assert_close(dx[:n], ref.rhs(xp, u, theta), "physical part of the derivative")
        assert_close(mod.observe(x, u, tuple(theta)), ref.out(xp, u, theta), "observe")
        if not fault_kind(kind).drifts:
            np.testing.assert_array_equal(dx[n], 0.0)
        else:
            np.testing.assert_array_equal(dx[n], x[n + 1])  # d theta / dt = slope
            np.testing.assert_array_equal(dx[n + 1], 0.0)
        np.testing.assert_allclose(mod.parameter_value(x, theta), theta[j], rtol=1e-15)


@pytest.mark.parametrize("model,name", FAULT_MODULES)
def test_fault_module_with_a_fault_replaces_the_parameter(model, name):
    mod, ssm, ref = package(model).MODELS[name], compiled(model).equations, reference(model)
    p, kind, n, j = _fault_layout(mod, ssm)
    rng = np.random.default_rng(303)
    for _ in range(3):
        xp, u, theta = random_point(mod, ssm, rng)
        N = xp.shape[1]
        change = rng.uniform(-0.4, 0.4, N) * (abs(theta[j]) or 1.0)  # per particle, both signs (an offset's is 0)
        faulty = [np.full(N, v) for v in theta]
        faulty[j] = theta[j] + change
        if not fault_kind(kind).drifts:
            x = np.vstack([xp, change[None]])
        else:
            x = np.vstack([xp, faulty[j][None], rng.uniform(-1.0, 1.0, (1, N))])
        assert_close(mod.derivative(x, u, tuple(theta))[:n], ref.rhs(xp, u, faulty), "derivative with the fault")
        assert_close(mod.observe(x, u, tuple(theta)), ref.out(xp, u, faulty), "observe with the fault")
        np.testing.assert_allclose(mod.parameter_value(x, theta), faulty[j], rtol=1e-15)
        # And it really differs from the nominal wherever the parameter acts (a
        # sensor's offset acts on its reading only).
        nominal = ref.rhs(xp, u, theta)
        acts = [i for i, e in enumerate(ssm.rhs) if sym(p) in e.free_symbols]
        seen = [i for i, e in enumerate(ssm.output_exprs) if sym(p) in e.free_symbols]
        assert acts or seen, f"{p} appears in no equation"
        if acts:
            assert not np.allclose(mod.derivative(x, u, tuple(theta))[acts], nominal[acts], rtol=1e-6, atol=0)
        if seen:
            reading = ref.out(xp, u, theta)[seen]
            assert not np.allclose(mod.observe(x, u, tuple(theta))[seen], reading, rtol=1e-6, atol=0)


@pytest.mark.parametrize("model,name", FAULT_MODULES)
def test_augment_lifts_nominal_particles_to_the_neutral_fault_state(model, name):
    mod, ssm = package(model).MODELS[name], compiled(model).equations
    p, kind, n, j = _fault_layout(mod, ssm)
    xp = package(model).nominal.initial_particles(np.random.default_rng(1), 400)
    x = mod.augment(xp, np.random.default_rng(2))
    np.testing.assert_array_equal(x[:n], xp)
    magnitude = x[-1]
    lo, hi = mod.FAULT_PRIOR
    assert lo < hi and np.all((magnitude >= lo) & (magnitude <= hi)) and np.ptp(magnitude) > 0.5 * (hi - lo)
    if fault_kind(kind).drifts:
        np.testing.assert_array_equal(x[n], ssm.parameter_values[j])


# ------------------------------------------------- RK4 against the exact step
@pytest.mark.parametrize("model", LINEAR)
def test_predict_agrees_with_the_exact_discretisation_within_the_rk4_bound(model):
    """dx/dt = A x + c with a constant input. RK4 maps the equilibrium x* = -A^-1 c to itself, and the
    deviation d = x - x* to R(hA)^n d with n substeps of h = dt/n and R(Z) = I + Z + Z^2/2 + Z^3/6 + Z^4/24;
    the exact step maps d to exp(dt A) d. With E = exp(hA) and a = ||hA||_2: ||R - E|| <= sum_{k>=5} a^k/k!
    = e^a - R(a), so ||R^n - E^n|| = ||sum_j R^j (R - E) E^(n-1-j)|| <= n (e^a - R(a)) e^((n-1) a), and
    the error of predict is at most that times ||d||."""
    mod, ssm = package(model).nominal, compiled(model).equations
    u0 = mod.inputs(0.0)
    jac, a_mat, sub = linearisation(ssm, u0, ssm.parameter_values)
    xs = [sym(s) for s in ssm.states]
    assert all(not (e.free_symbols & set(xs)) for e in jac), f"{model} is not linear"
    c = np.array([float(e.xreplace({**sub, **{x: 0 for x in xs}})) for e in ssm.rhs])
    equilibrium = np.linalg.solve(a_mat, -c)
    dt, n = mod.DT, mod.SUBSTEPS
    exact = expm(dt * a_mat)
    # The oracle itself: the Taylor expm agrees with the eigen-decomposition.
    lam, v = np.linalg.eig(a_mat)
    np.testing.assert_allclose(exact, (v @ np.diag(np.exp(dt * lam)) @ np.linalg.inv(v)).real,
                               rtol=1e-12, atol=1e-14)
    a = np.linalg.norm((dt / n) * a_mat, 2)
    tail = math.exp(a) - (1 + a + a ** 2 / 2 + a ** 3 / 6 + a ** 4 / 24)
    bound_factor = n * tail * math.exp((n - 1) * a)
    rng = np.random.default_rng(404)
    x, _, _ = random_point(mod, ssm, rng, n=64)
    x[:, :8] *= rng.uniform(0.0, 2.0, (len(xs), 8))  # some far from the operating point too
    d = x - equilibrium[:, None]
    want = equilibrium[:, None] + exact @ d
    got = mod.predict(x, u0, mod.THETA, dt)
    # Rounding: x is O(|x|), its error O(1e-16 |x|) per operation.
    rounding = 1e-13 * np.linalg.norm(x, axis=0)
    err = np.linalg.norm(got - want, axis=0)
    bound = bound_factor * np.linalg.norm(d, axis=0)
    assert np.all(err <= bound + rounding), ((err - rounding) / bound).max()
    # It is RK4 with SUBSTEPS substeps exactly: R(hA)^n, to rounding.
    rk4 = np.linalg.matrix_power(taylor((dt / n) * a_mat, 4), n)
    assert np.all(np.linalg.norm(got - (equilibrium[:, None] + rk4 @ d), axis=0) <= rounding)
    # The bound discriminates: a third-order method breaks it at most of the points.
    rk3 = np.linalg.matrix_power(taylor((dt / n) * a_mat, 3), n)
    err3 = np.linalg.norm(rk3 @ d - exact @ d, axis=0)
    assert np.mean(err3 > bound) > 0.5
    print(f"\n{model}: RK4 error / bound: max {(err / bound).max():.3g}; third-order error / bound: median "
          f"{np.median(err3 / bound):.3g}")


# ------------------------------------------------------------- stability rule
def expected_substeps(ssm, mod):
    _, a_mat, _ = linearisation(ssm, mod.inputs(0.0), ssm.parameter_values)
    eig = np.linalg.eigvals(a_mat)
    ratio = np.max(np.abs(eig)) * mod.DT / H_LAMBDA
    assert abs(ratio - round(ratio)) > 1e-9 or ratio < 1, "on a rounding boundary: the test cannot decide"
    return max(1, math.ceil(ratio)), eig


@pytest.mark.parametrize("model", MODELS)
def test_substeps_follow_the_stability_rule(model):
    pkg, ssm = package(model), compiled(model).equations
    substeps, eig = expected_substeps(ssm, pkg.nominal)
    assert pkg.nominal.SUBSTEPS == substeps
    table = np.array([complex(re_, im) for re_, im in pkg.nominal.EIGENVALUES])
    key = lambda z: (round(z.real, 6), round(z.imag, 6))  # noqa: E731
    np.testing.assert_allclose(sorted(table, key=key), sorted(eig, key=key), atol=1e-8)
    for mod in pkg.MODELS.values():  # fault models integrate like the nominal one
        assert mod.SUBSTEPS == substeps and mod.DT == pkg.nominal.DT


def _stiff_circuit(tmp_path):
    text = (ROOT / "models" / "circuit.yaml").read_text()
    stiff = text.replace("C1: {value: 0.5,", "C1: {value: 1.0e-3,")
    assert stiff != text
    (tmp_path / "models").mkdir()
    path = tmp_path / "models" / "circuit.yaml"
    path.write_text(stiff)
    c = compile_model(path)
    out = tmp_path / "numpy_model"
    out.mkdir()
    for rel, content in c.package.files:
        (out / rel).write_text(content)
    return c, load_package(out, f"_bgc_stiff_{abs(hash(str(tmp_path)))}")


@pytest.mark.slow
def test_stiff_circuit_gets_more_substeps_and_stays_bounded(tmp_path, monkeypatch):
    c, pkg = _stiff_circuit(tmp_path)
    mod = pkg.nominal
    substeps, eig = expected_substeps(c.equations, mod)
    assert mod.SUBSTEPS == substeps
    assert substeps > package("circuit").nominal.SUBSTEPS
    # DC steady state of the circuit does not depend on C1: i = V / (R1 + R2 + R3).
    i = 10.0 / (1.0 + 2.0 + 1.0)
    steady = np.array([10.0 - 1.0 * i, 10.0 - 3.0 * i, i])
    rng = np.random.default_rng(5)
    x0 = steady[:, None] * (1.0 + 0.2 * rng.standard_normal((3, 8)))
    x = x0
    u, theta = mod.inputs(0.0), mod.THETA
    peak = 0.0
    for _ in range(1000):
        x = mod.predict(x, u, theta, mod.DT)
        peak = max(peak, float(np.abs(x).max()))
    assert np.all(np.isfinite(x)) and peak < 2 * np.abs(x0).max()
    np.testing.assert_allclose(x, np.broadcast_to(steady[:, None], x.shape), atol=1e-6)
    # Control: with the nominal circuit's substep count the same plant blows up, so the rule matters.
    monkeypatch.setattr(mod, "SUBSTEPS", package("circuit").nominal.SUBSTEPS)
    x = x0
    with np.errstate(all="ignore"):
        for _ in range(50):
            x = mod.predict(x, u, theta, mod.DT)
    assert not np.all(np.isfinite(x) & (np.abs(x) < 1e6))


# ---------------------------------------------------------------- same seed
def _data(mod, steps, seed):
    rng = np.random.default_rng(seed)
    x = mod.initial_particles(rng, 1)
    ys = []
    u = mod.inputs(0.0)
    for _ in range(steps):
        x = mod.transition(x, u, mod.THETA, mod.DT, rng)
        ys.append(mod.observe(x, u, mod.THETA)[:, 0] + mod.MEASUREMENT_STD * rng.standard_normal(len(mod.OUTPUTS)))
    return np.array(ys), np.tile(u, (steps, 1))


@pytest.mark.parametrize("name", ["nominal", "R2_abrupt", "C1_incipient"])
def test_same_seed_gives_identical_particles_and_filter_outputs(name):
    pkg = package("circuit")
    mod = pkg.MODELS[name]
    a = mod.initial_particles(np.random.default_rng(11), 300)
    b = mod.initial_particles(np.random.default_rng(11), 300)
    c = mod.initial_particles(np.random.default_rng(12), 300)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    ys, us = _data(pkg.nominal, 40, 99)
    for cls in (pkg.filters.GenericParticleFilter, pkg.filters.AuxiliaryParticleFilter):
        runs = [cls(mod, 300, np.random.default_rng(seed)).run(ys, us) for seed in (11, 11, 12)]
        for key in pkg.filters.FilterRun.__slots__:
            if getattr(runs[0], key) is None:  # the modes' probabilities: a model with modes only
                assert getattr(runs[1], key) is None and not hasattr(mod, "MODES"), key
                continue
            assert getattr(runs[0], key).tobytes() == getattr(runs[1], key).tobytes(), (cls.__name__, key)
        assert not np.array_equal(runs[0].mean, runs[2].mean), cls.__name__


# ----------------------------------------------- names the generated code uses
CIRCUIT_TEXT = (ROOT / "models" / "circuit.yaml").read_text()


def _renamed_model(tmp_path, old, new):
    text = re.sub(rf"\b{old}\b", new, CIRCUIT_TEXT)
    assert text != CIRCUIT_TEXT
    (tmp_path / "models").mkdir()
    path = tmp_path / "models" / "circuit.yaml"
    path.write_text(text)
    return path


def _renamed_package(tmp_path, old, new):
    c = compile_model(_renamed_model(tmp_path, old, new))
    out = tmp_path / "numpy_model"
    out.mkdir()
    for rel, content in c.package.files:
        (out / rel).write_text(content)
    return c, load_package(out, f"_bgc_renamed_{new}_{abs(hash(str(tmp_path)))}")


@pytest.mark.parametrize("old,new", [("R2", "R_mid"), ("C1", "dx"), ("V", "dx"), ("R3", "OUTPUTS"), ("L", "r"),
                                     ("R1", "seen"), ("C2", "SUBSTEPS")])
def test_model_names_do_not_collide_with_names_the_generated_code_uses(tmp_path, old, new):
    c, pkg = _renamed_package(tmp_path, old, new)
    ssm, ref = c.equations, Reference(c.equations)
    rng = np.random.default_rng(606)
    for name, mod in pkg.MODELS.items():
        xp, u, theta = random_point(mod, ssm, rng)
        N = xp.shape[1]
        if mod.FAULT is None:
            x, faulty = xp, theta
        else:
            p, kind, n, j = _fault_layout(mod, ssm)
            faulty = [np.full(N, v) for v in theta]
            faulty[j] = theta[j] + (abs(theta[j]) or 1.0) * rng.uniform(-0.3, 0.3, N)
            extra = [faulty[j] - theta[j]] if not fault_kind(kind).drifts else [faulty[j], rng.uniform(-1.0, 1.0, N)]
            x = np.vstack([xp, *extra])
        assert_close(mod.observe(x, u, tuple(theta)), ref.out(xp, u, faulty), f"{name}: observe")
        dx = mod.derivative(x, u, tuple(theta))
        assert_close(dx[:len(ssm.states)], ref.rhs(xp, u, faulty), f"{name}: derivative")
        if mod.FAULT is not None and fault_kind(mod.FAULT["kind"]).drifts:
            np.testing.assert_array_equal(dx[-2], x[-1], err_msg=f"{name}: d{mod.FAULT['parameter']}/dt = slope")


@pytest.mark.parametrize("name", ["delta_R2", "_dx", "np", "theta"])
def test_names_of_generated_code_are_refused_in_the_model(tmp_path, name):
    """A parameter named like a fault state (delta_<p>) or a name the modules use is a model error."""
    with pytest.raises(BgcError) as info:
        compile_model(_renamed_model(tmp_path, "R1", name))
    assert "reserved" in info.value.line() and name in info.value.line()


# ------------------------------------------------------- APF first stage
@pytest.mark.parametrize("model", MODELS)
def test_predictive_std_is_measurement_noise_plus_process_noise_seen_through_the_outputs(model):
    """PREDICTIVE_STD = sqrt(R + diag(H Q H')), H = d observe / d x at X0 (sympy Jacobian, derived here)."""
    mod, ssm = package(model).nominal, compiled(model).equations
    xs = [sym(s) for s in ssm.states]
    sub = {sym(p): v for p, v in zip(ssm.parameters, ssm.parameter_values)}
    sub.update({sym(i): float(v) for i, v in zip(ssm.inputs, mod.inputs(0.0))})
    sub.update({x: v for x, v in zip(xs, ssm.initial)})
    h = np.array([[float(e.xreplace(sub)) for e in row]
                  for row in sympy.Matrix(list(ssm.output_exprs)).jacobian(xs).tolist()])
    want = np.sqrt(mod.MEASUREMENT_STD ** 2 + np.diag(h @ np.diag(mod.PROCESS_STD ** 2) @ h.T))
    np.testing.assert_allclose(mod.PREDICTIVE_STD, want, rtol=1e-12)
    assert np.all(mod.PREDICTIVE_STD > mod.MEASUREMENT_STD)
    for fault in package(model).MODELS.values():
        assert len(fault.PREDICTIVE_STD) == len(ssm.outputs)


def test_predictive_std_where_the_plant_runs_passes_on_the_process_noise_of_a_product_of_states():
    """The DC motor's P_mech = e5 f5 = k i w (gyrator: e5 = k f4, f4 = i, f5 =
    w) vanishes with its slope at X0 (the motor at rest), so PREDICTIVE_STD
    (H at X0) is the measurement noise alone. At a state (i, w) the one-step
    predictive std is, by hand, sqrt(r^2 + k^2 (q_i^2 w^2 + q_w^2 i^2)): a
    central difference of a bilinear output along one coordinate is its slope.
    The other outputs (f2 = i, f7 = w, e4 = k w) are linear: their values are
    PREDICTIVE_STD at any state. Before: the APF used PREDICTIVE_STD, its
    normalised P_mech residuals had std 1.35 and 8 of 40 fault-free runs
    alarmed."""
    from bgc.model.package import load_package as load

    folder = conftest.session("dc_motor").folder  # compiled once per test session
    mod = load(folder, "dc_motor").nominal
    k = dict(zip(mod.PARAMETERS, mod.THETA))["k"]
    out = list(mod.OUTPUTS)
    assert mod.STATES == ("f3", "f6")  # i (L_a), w (J)
    np.testing.assert_array_equal(mod.X0, [0.0, 0.0])
    p = out.index("P_mech")
    r, q = mod.MEASUREMENT_STD, mod.PROCESS_STD
    assert mod.PREDICTIVE_STD[p] == pytest.approx(r[p], rel=1e-12)
    states = np.array([[10.9, 3.0, 0.0], [10.9, 7.0, 0.0]])  # (i, w) per column
    got = mod.predictive_std(states, mod.inputs(0.0), mod.THETA)
    assert got.shape == (3, len(out))
    i, w = states
    want = np.sqrt(r[p] ** 2 + k * k * (q[0] ** 2 * w ** 2 + q[1] ** 2 * i ** 2))
    np.testing.assert_allclose(got[:, p], want, rtol=1e-12)
    assert got[0, p] > 1.3 * r[p]  # at the running point the process noise is most of it
    for j, name in enumerate(out):
        if name != "P_mech":
            np.testing.assert_allclose(got[:, j], mod.PREDICTIVE_STD[j], rtol=1e-12)
    bad = mod.predictive_std(np.array([[np.nan], [1.0]]), mod.inputs(0.0), mod.THETA)
    np.testing.assert_array_equal(bad[0], mod.PREDICTIVE_STD)  # not a number: the value at X0


@pytest.mark.parametrize("model", LINEAR)
def test_predictive_std_of_a_linear_plant_is_the_same_at_every_state(model):
    """With affine outputs sqrt(R + diag(H Q H')) does not depend on the state."""
    mod = package(model).nominal
    rng = np.random.default_rng(5)
    states = mod.X0[:, None] * (1.0 + rng.uniform(-0.5, 0.5, (len(mod.STATES), 4)))
    got = mod.predictive_std(states, mod.inputs(0.0), mod.THETA)
    np.testing.assert_allclose(got, np.broadcast_to(mod.PREDICTIVE_STD, got.shape), rtol=1e-9)


def test_blocked_transition_matches_unblocked_for_a_partial_last_block():
    """predict/perturb work on blocks of BLOCK particles: with N = 2 BLOCK + 5
    (a partial last block) the noise-free prediction equals a single-particle one
    (to rounding), in place or not, and perturb adds noise of the model's std to
    every particle."""
    import numpy as np

    from bgc.model.package import load_package

    pkg = load_package(ROOT / "generated", "ro")
    m = pkg.MODELS["nominal"]
    block = pkg._kernel.BLOCK
    n = 2 * block + 5
    rng = np.random.default_rng(3)
    x = m.X0[:, None] + m.X0_STD[:, None] * rng.standard_normal((len(m.STATES), n))
    u = m.inputs(0.0)
    whole = m.predict(x, u, m.THETA, m.DT)
    one_by_one = np.column_stack([m.predict(x[:, i:i + 1], u, m.THETA, m.DT) for i in (0, block, n - 1)])
    # equal up to the summation order of the matrix product (BLAS kernels differ with N)
    np.testing.assert_allclose(whole[:, [0, block, n - 1]], one_by_one, rtol=1e-13, atol=0)
    inplace = x.copy()
    m.predict(inplace, u, m.THETA, m.DT, out=inplace)
    assert np.array_equal(inplace, whole)
    noisy = m.perturb(whole.copy(), np.random.default_rng(4))
    z = (noisy - whole) / m.PROCESS_STD[:, None]
    assert np.all(np.isfinite(z)) and abs(z.std() - 1.0) < 0.02 and abs(z.mean()) < 0.02


def test_predict_in_threads_equals_serial():
    """The kernel's scratch arrays are per thread: filters running in several
    threads at once (a thread-pool campaign) do not write into each other's."""
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    from bgc.model.package import load_package

    pkg = load_package(ROOT / "generated", "ro")
    m = pkg.MODELS["nominal"]
    u = m.inputs(0.0)
    starts = [m.X0[:, None] + m.X0_STD[:, None] * np.random.default_rng(s).standard_normal((len(m.STATES), n))
              for s, n in enumerate((3000, 5000, 3000, 9000))]

    def run(x):
        x = x.copy()
        for _ in range(20):
            m.predict(x, u, m.THETA, m.DT, out=x)
        return x

    serial = [run(x) for x in starts]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(run, starts))
    for a, b in zip(serial, threaded):
        assert np.array_equal(a, b)


@settings(max_examples=200)
@given(n=st.integers(1, 200_000))
def test_kernel_spans_split_particles_evenly_into_blocks_of_one_to_two_block_lengths(n):
    from bgc.model.package import load_package

    kernel = load_package(ROOT / "generated", "ro")._kernel
    parts, width = kernel.spans(n)
    assert parts[0][0] == 0 and parts[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(parts, parts[1:]))            # contiguous, no overlap
    sizes = [stop - start for start, stop in parts]
    assert max(sizes) == width and max(sizes) - min(sizes) <= 1    # as even as integers allow
    assert len(parts) == max(1, n // kernel.BLOCK)
    if n >= kernel.BLOCK:
        assert kernel.BLOCK <= min(sizes) and width < 2 * kernel.BLOCK


# ------------------------------ every test plant, through a freshly generated package
@lru_cache(maxsize=None)
def fresh_package(name: str):
    """The package bgc generates for one of conftest.ALL_MODELS, written to a
    temporary directory, removed when the test session ends, and imported
    (the test plants have no generated/ copy)."""
    from bgc.api.folders import private_folder
    from conftest import compiled as compiled_any

    root = Path(private_folder(f"bgc-{name}-")) / "numpy_model"
    root.mkdir()
    for rel, text in compiled_any(name).package.files:
        (root / rel).write_text(text)
    return load_package(root, f"_bgc_fresh_{name}")


@pytest.mark.parametrize("name", sorted(__import__("conftest").ALL_MODELS))
def test_every_plant_derivative_and_observe_equal_lambdify_also_into_strided_out(name):
    """Nominal and fault modules of every test plant (gyrator, algebraic loop,
    nonlinear orifice with a linear block that starts at row 1) against lambdify
    of the compiler's equations; derivative and observe also write into ``out``
    given as a strided view of a larger array (what the kernel hands them)."""
    from conftest import compiled as compiled_any

    pkg, ssm = fresh_package(name), compiled_any(name).equations
    ref = Reference(ssm)
    rng = np.random.default_rng(404)
    for mod_name, mod in pkg.MODELS.items():
        if mod.FAULT and not _enters_an_equation(mod_name):  # no neutral value, or no equation: FAULT_MODULES
            continue
        n_phys = len(ssm.states)
        for _ in range(2):
            xp, u, theta = random_point(mod, ssm, rng, n=37)
            x = np.zeros((len(mod.STATES), xp.shape[1]))  # fault states at their neutral value
            x[:n_phys] = xp
            if mod.FAULT and fault_kind(mod.FAULT["kind"]).drifts:
                x[n_phys] = theta[ssm.parameters.index(mod.FAULT["parameter"])]  # parameter state = its value
            want_dx, want_y = ref.rhs(xp, u, theta), ref.out(xp, u, theta)
            assert_close(mod.derivative(x, u, tuple(theta))[:n_phys], want_dx, f"{mod_name} derivative")
            assert_close(mod.observe(x, u, tuple(theta)), want_y, f"{mod_name} observe")
            big = np.full((len(mod.STATES) + 2, 60), np.nan)
            out = big[1:-1, 5:5 + x.shape[1]]                      # strided, not contiguous
            assert mod.derivative(x, u, tuple(theta), out) is out
            assert_close(out[:n_phys], want_dx, f"{mod_name} derivative into out")
            ybig = np.full((len(mod.OUTPUTS), 50), np.nan)
            yout = ybig[:, 3:3 + x.shape[1]]
            assert mod.observe(x, u, tuple(theta), out=yout) is yout
            assert_close(yout, want_y, f"{mod_name} observe into out")


def test_noise_of_a_signal_that_starts_at_zero_scales_with_its_size_over_the_run(tmp_path):
    """An RC charging from 0 towards V = 1e-3 (tau = R C = 2, dt = 1): noise is a
    fraction of the signal, so the capacitor voltage's scale is its size over
    the nominal run, V (not an arbitrary 1): process std 0.03 * V * sqrt(min(1,
    2 dt / tau)) = 3e-5, sensor std 0.02 * V = 2e-5 (derived by hand)."""
    model = tmp_path / "rc0.yaml"
    model.write_text("""name: rc0
description: RC charging from rest (test model)
parameters: {R: 1.0, C: 2.0}
inputs: {V: 1.0e-3}
elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, C: {kind: C}}
bonds: {1: [V, j], 2: [j, R], 3: [j, C]}
measurements: {e3: {}}
""")
    noise = compile_model(model).numerics.noise
    assert noise.process[0] == pytest.approx(0.03 * 1e-3, rel=1e-6)
    assert noise.measurement[0] == pytest.approx(0.02 * 1e-3, rel=1e-6)


# ------------------------------------- model text cannot change generated statements
#: Descriptions that would break out of a module docstring, or make a package
#: that does not parse, if they reached the code unescaped.
HOSTILE_DESCRIPTIONS = [
    'end """\nimport os\nos.system("touch bgc_injection_sentinel")\n"""',
    'ends with a quote"',
    'trailing """',
    "C:\\Users\\new and \\N{BULLET} and \\x4 and \\u12",
    "a NUL \x00 here",
    "ends with a backslash \\",
    "line\u2028separator and \r carriage return and \x1b[31m ANSI",
    "tab\tand form\x0cfeed",
]


def _rc_model(path: Path, description: str) -> Path:
    """A small RC plant with an abrupt and an incipient fault; ``description``
    written as a YAML double-quoted scalar (JSON's escapes are YAML's)."""
    import json

    path.write_text(f"""name: rc_text
description: {json.dumps(description)}
parameters: {{R: 1.0, C: 2.0}}
inputs: {{V: 1.0}}
elements: {{V: {{kind: Se}}, j: {{kind: "1"}}, R: {{kind: R}}, C: {{kind: C, initial: 0.5}}}}
bonds: {{1: [V, j], 2: [j, R], 3: [j, C]}}
measurements: {{e3: {{}}, f2: {{}}}}
faults: {{R: [abrupt, incipient]}}
""", encoding="utf-8")
    return path


def _trees(c) -> dict[str, ast.Module]:
    return {rel: ast.parse(text) for rel, text in c.package.files}


@pytest.fixture(scope="module")
def plain_rc(tmp_path_factory):
    """The RC plant with a plain description, compiled once for every hostile
    one (its package's statements and docstrings are what each is compared
    with; read it, do not change it)."""
    return compile_model(_rc_model(tmp_path_factory.mktemp("rc") / "plain.yaml", "plain"))


@pytest.mark.process
@pytest.mark.parametrize("description", HOSTILE_DESCRIPTIONS)
def test_a_description_cannot_add_statements_to_the_generated_package(tmp_path, plain_rc, description):
    """Every module of the package made from a hostile description has exactly
    the statements of the package made from a plain one (its AST, docstrings
    aside, is identical), its docstrings hold the description as written, and
    importing it runs nothing of the description (in a fresh interpreter in
    an empty folder, which it must leave empty)."""
    plain = plain_rc
    hostile = compile_model(_rc_model(tmp_path / "hostile.yaml", description))
    assert hostile.model.description == description
    want, got = _trees(plain), _trees(hostile)
    assert set(want) == set(got)
    for rel in want:
        w, g = want[rel], got[rel]
        assert ast.dump(ast.Module(w.body[1:], [])) == ast.dump(ast.Module(g.body[1:], [])), rel
        doc_w, doc_g = ast.get_docstring(w, clean=False), ast.get_docstring(g, clean=False)
        assert doc_g == doc_w.replace("plain", description), rel
    out = tmp_path / "gen" / "numpy_model"
    out.mkdir(parents=True)
    for rel, text in hostile.package.files:
        (out / rel).write_text(text, encoding="utf-8")
    monkey = tmp_path / "cwd"
    monkey.mkdir()
    subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(out.parent)!r}); import numpy_model"],
                   cwd=monkey, check=True, capture_output=True)
    assert not any(monkey.iterdir()), "importing the package ran a command"


def test_a_model_file_name_cannot_add_statements_to_the_generated_package(tmp_path):
    """A file name holding a newline would break out of the first line's
    ``# generated by bgc from ...`` comment: it is escaped, so the header is one
    comment line and the package is the one a plain name gives."""
    evil_dir = tmp_path / "models"
    evil_dir.mkdir()
    evil = _rc_model(evil_dir / "x\nimport os\nos.system('touch bgc_injection_sentinel')\n#.yaml", "plain")
    plain = compile_model(_rc_model(evil_dir / "rc.yaml", "plain"))
    hostile = compile_model(evil)
    for (rel, text), (_, plain_text) in zip(hostile.package.files, plain.package.files):
        assert ast.dump(ast.parse(text)) == ast.dump(ast.parse(plain_text)), rel
        first, rest = text.split("\n", 1)
        assert first == "# generated by bgc from models/x\\nimport os\\nos.system('touch bgc_injection_sentinel')" \
                        "\\n#.yaml, do not edit", first
        assert rest == plain_text.split("\n", 1)[1], rel


@pytest.mark.parametrize("old,new", [("R1", "out"), ("R2", "linear"), ("C1", "A"), ("L", "b"), ("R3", "key"),
                                     ("V", "hit"), ("C2", "n")])
def test_names_the_generated_functions_use_for_themselves_are_free_for_models(tmp_path, old, new):
    """A parameter or input named ``out``, ``linear``, ``A``, ``b``, ``key``,
    ``hit`` or ``n`` (locals and arguments of the generated functions) compiles
    and computes the same numbers as lambdify (before, ``out`` shadowed the
    output array and ``A`` the linear block)."""
    test_model_names_do_not_collide_with_names_the_generated_code_uses(tmp_path, old, new)


def test_a_lightly_damped_plant_pushed_from_rest_gets_the_substeps_its_accuracy_needs(tmp_path, monkeypatch):
    """The mass-spring-damper test plant: det A = k_s / m = 4, so |lambda| = 2
    on both (complex) eigenvalues, and with dt = 1 the stability rule gives
    ceil(2 / 1.5) = 2 substeps. Its damping ratio is c / (2 sqrt(k_s m)) =
    0.0625 and it starts at rest under a step of force: with 2 substeps the
    generated RK4 drifts from the exact run by more than a measurement std
    (the detector alarmed on 9 of 20 fault-free runs at 0.5 % / 1 % noise).
    The compiled SUBSTEPS keep the generated model's noise-free run within
    0.2 measurement std of the same code with 64 times as many substeps."""
    from bgc import pipeline
    from bgc.model import package as track

    c = conftest.compiled("mass_spring_damper")
    for rel, text in pipeline.generated_files(c).items():
        (tmp_path / "mass_spring_damper" / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "mass_spring_damper" / rel).write_text(text)
    mod = track.load_package(tmp_path, "mass_spring_damper").nominal
    chosen = mod.SUBSTEPS

    def run(substeps: int) -> np.ndarray:
        monkeypatch.setattr(mod, "SUBSTEPS", substeps)
        x = np.asarray(mod.X0, dtype=float)[:, None].copy()
        ys = []
        for k in range(120):
            u = mod.inputs(k * mod.DT)
            x = mod.predict(x, u, mod.THETA, mod.DT)
            ys.append(mod.observe(x, u, mod.THETA)[:, 0])
        return np.array(ys)

    exact = run(64 * chosen)
    error = lambda n: float(np.max(np.abs(run(n) - exact) / mod.MEASUREMENT_STD))  # noqa: E731
    assert chosen > 2
    assert error(2) > 1.0  # the stability rule alone
    assert error(chosen) <= 0.2
