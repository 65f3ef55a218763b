"""``bgc distinguish`` of a stuck switch (bgc/analysis/distinguish.py, "Stuck
switches"), against the exact Gaussian divergences of a relay's measurements
derived by hand.

The plant: a voltage source V through a coil (L, its resistance R_s) into a
capacitor C loaded by R_load, and a second load R_aux across C behind a relay
K an operator switches (controlled transitions). States x = (i, v), the
coil's current and the capacitor's voltage, both measured (v_C, i_L):

    L di/dt = V - R_s i - v
    C dv/dt = i - v / R_load - [K closed] v / R_aux

Between two samples the plant is linear in each configuration, so its step
is exactly x_k = Phi x_(k-1) + Gamma, Phi = expm(A dt), Gamma = A^-1 (Phi -
I) b (bgc's generated model integrates the same equations by RK4: equal to
about 1e-8 at dt = 0.01). With the process noise w_k ~ N(0, Q) added at
each step and x at t = 0 ~ N(X0, P0), the measurements of the whole run are
one Gaussian vector: its mean from the recursion, its covariance from the
stacked transition matrices. The Kullback-Leibler divergence between two such
runs (the relay stuck, and not) is then the closed form for two Gaussians,
with no Kalman filter in it: what ``Distinction.divergence`` (the common
covariance: the nominal run's) and a refined rival's ``expected`` (each
run's own covariance) must equal.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

import bgc
from bgc.analysis import distinguish as distinction
from pathlib import Path
from bgc.model import linear
from bgc.model.protocol import nominal_model
from bgc.output import render

ROOT = Path(__file__).resolve().parent.parent
R_S, L, C, R_LOAD, R_AUX, V = 0.5, 0.2, 2.0, 10.0, 0.5, 8.0
DT = 0.01
STEPS = 300

MODEL = f"""
name: relay_stuck
description: a load behind a relay an operator switches, the relay able to weld or fail (a test plant)
domain: electrical
parameters:
  R_s: {{value: {R_S}, unit: ohm}}
  L: {{value: {L}, unit: H}}
  C: {{value: {C}, unit: F}}
  R_load: {{value: {R_LOAD}, unit: ohm}}
  R_aux: {{value: {R_AUX}, unit: ohm}}
inputs:
  V: {{signal: constant, value: {V}, unit: V}}
elements:
  V: {{kind: Se}}
  S: {{kind: "1"}}
  R_s: {{kind: R}}
  L: {{kind: I}}
  J_c: {{kind: "0"}}
  C: {{kind: C}}
  J_load: {{kind: "1"}}
  R_load: {{kind: R}}
  K: {{kind: "1", switch: true}}
  R_aux: {{kind: R}}
bonds:
  1: [V, S]
  2: [S, R_s]
  3: [S, L]
  4: [S, J_c]
  6: [J_c, C]
  7: [J_c, J_load]
  8: [J_load, R_load]
  9: [J_c, K]
  10: [K, R_aux]
measurements:
  v_C: {{expr: e6, noise: 0.01}}
  i_L: {{expr: f3, noise: 0.01}}
faults:
  R_load: {{kinds: [abrupt], direction: increase}}
  K: {{kinds: [stuck_on, stuck_off], prior: 0.02}}
modes:
  open: {{on: [], description: relay open}}
  closed: {{on: [K], description: relay closed}}
transitions:
  - {{from: open, to: closed}}
  - {{from: closed, to: open}}
simulation:
  dt: {DT}
  steps: {STEPS}
  time_unit: s
"""


def _step(k_closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Phi and Gamma of one sample's step, the relay closed or open."""
    g = 1.0 / R_LOAD + (1.0 / R_AUX if k_closed else 0.0)
    A = np.array([[-R_S / L, -1.0 / L], [1.0 / C, -g / C]])
    b = np.array([V / L, 0.0])
    phi = expm(A * DT)
    return phi, np.linalg.solve(A, (phi - np.eye(2)) @ b)


def means(closed, x0) -> np.ndarray:
    """The mean (2T,) of the measurements (i_L, v_C) of samples 0..T-1, the
    relay closed over the steps into the samples ``closed``."""
    steps = {True: _step(True), False: _step(False)}
    x, out = np.array(x0, dtype=float), []
    for k_closed in closed:
        phi, gamma = steps[bool(k_closed)]
        x = phi @ x + gamma
        out.append(x)
    return np.concatenate(out)


def measurements(closed, x0, P0, Q, R) -> tuple[np.ndarray, np.ndarray]:
    """The mean (2T,) and covariance (2T, 2T) of the measurements (i_L, v_C)
    of samples 0..T-1, the relay closed over the steps into the samples
    ``closed`` (T booleans: :func:`configuration`)."""
    T = len(closed)
    steps = {True: _step(True), False: _step(False)}
    mean = np.empty((T, 2))
    M = np.zeros((2 * T, 2))  # d x_k / d x(t = 0)
    N = np.zeros((2 * T, 2 * T))  # d x_k / d w_j
    x, product = np.array(x0, dtype=float), np.eye(2)
    for k in range(T):
        phi, gamma = steps[bool(closed[k])]
        x = phi @ x + gamma
        mean[k] = x
        product = phi @ product
        M[2 * k:2 * k + 2] = product
        if k:
            N[2 * k:2 * k + 2, :2 * k] = phi @ N[2 * k - 2:2 * k, :2 * k]
        N[2 * k:2 * k + 2, 2 * k:2 * k + 2] = np.eye(2)
    cov_x = M @ P0 @ M.T + N @ np.kron(np.eye(T), Q) @ N.T
    return mean.ravel(), cov_x + np.kron(np.eye(T), R)  # the sensors read (i_L, v_C) = (i, v)


def configuration(column, kind: str | None = None, onset: int | None = None) -> np.ndarray:
    """Whether the relay is closed over the step into each sample, for a mode
    column ``column`` (True: closed) and the relay ``kind`` (stuck_on,
    stuck_off; None: as commanded) from sample ``onset``. A row's mode holds
    from its time on, as the truth simulator writes it (the row holds the
    state after the changes due at its time): the step into sample k runs in
    row k-1's mode, the first step in the first mode (open). The step into
    the onset sample is nominal, the sample sees the fault (bgc's onset rule):
    stuck over the steps into the samples after it."""
    before = np.concatenate([[False], np.asarray(column, dtype=bool)[:-1]])
    if kind is None:
        return before
    return np.where(np.arange(len(before)) > onset, kind == "stuck_on", before)


def gaussian_kl(ma, Sa, mb, Sb) -> float:
    """KL(N(ma, Sa) || N(mb, Sb))."""
    La, Lb = np.linalg.cholesky(Sa), np.linalg.cholesky(Sb)
    d = np.linalg.solve(Lb, mb - ma)
    W = np.linalg.solve(Lb, La)
    return 0.5 * (float(np.sum(W * W)) + float(d @ d) - len(ma)
                  + 2.0 * float(np.log(np.diag(Lb)).sum() - np.log(np.diag(La)).sum()))


@pytest.fixture(scope="module")
def relay(tmp_path_factory):
    path = tmp_path_factory.mktemp("stuck") / "relay_stuck.yaml"
    path.write_text(MODEL)
    return bgc.open(path, backend="numpy")


def _families(relay, closed):
    """The families of the relay's package over a run with the mode column
    ``closed`` (the mode's number per sample: 1 open, 2 closed)."""
    package = relay.package
    us = linear.scenario_inputs(package, len(closed), (), np.where(closed, 2.0, 1.0))
    return package, distinction.prepare(package, us)


def _noise(package):
    nominal = nominal_model(package)
    P0 = np.diag(np.asarray(nominal.X0_STD, dtype=float)[:2] ** 2)
    Q = np.diag(np.asarray(nominal.PROCESS_STD, dtype=float)[:2] ** 2)
    R = np.diag(np.asarray(nominal.MEASUREMENT_STD, dtype=float) ** 2)
    assert nominal.STATES[:2] == ("f3", "e6") and nominal.OUTPUTS == ("i_L", "v_C")
    return np.asarray(nominal.X0, dtype=float)[:2], P0, Q, R


#: The operator's schedule: open, closed from sample 80 to 159, open again, closed from 240.
SCHEDULE = np.array([80 <= k < 160 or k >= 240 for k in range(STEPS)])


@pytest.mark.slow
def test_a_stuck_relays_divergence_from_no_fault_is_the_exact_gaussian_ones(relay):
    """The relay welded shut (K stuck ON) from sample 100 (the step into
    sample 100 still nominal: the onset rule) and failing to close (K stuck
    OFF) from 100: their divergence from no fault under the nominal run's
    covariance is 1/2 dmu' Sigma^-1 dmu of the hand-derived Gaussians, to
    1e-5; so is the ideal detector's reach at the end of the run; a relay
    stuck where the operator never moves it from (ON over a closed stretch
    it leaves only after the run) changes nothing: divergence 0."""
    package, families = _families(relay, SCHEDULE)
    x0, P0, Q, R = _noise(package)
    mean, cov = measurements(configuration(SCHEDULE), x0, P0, Q, R)
    assert np.abs(families.y.ravel() - mean).max() < 1e-4  # the nominal run: RK4 against the exact step
    chol = np.linalg.cholesky(cov)
    for kind, stuck in (("stuck_on", True), ("stuck_off", False)):
        faulty, _ = measurements(configuration(SCHEDULE, kind, 100), x0, P0, Q, R)
        z = np.linalg.solve(chol, faulty - mean)
        exact = 0.5 * float(z @ z)
        d = distinction.distinguish(families, f"K_{kind}", 1.0, 100, {"K": 0.02, "R_load": 0.01})
        assert exact > 50 and abs(d.divergence - exact) <= 1e-5 * exact, (kind, d.divergence, exact)
        assert abs(d.reach[-1] - 2 * exact) <= 1e-5 * exact and d.misfit == 0.0 and d.magnitude == 1.0
        assert d.label == f"K stuck {'ON' if stuck else 'OFF'}"
    late = np.array([k >= 240 for k in range(STEPS)])  # closed from 240 to the end
    package, families = _families(relay, late)
    d = distinction.distinguish(families, "K_stuck_on", 1.0, 250, {"K": 0.02, "R_load": 0.01})
    assert d.divergence < 1e-12 and d.detectability == pytest.approx(0.5, abs=1e-6)


@pytest.mark.slow
def test_a_stuck_rival_is_fitted_over_its_onsets_and_judged_with_its_own_covariance(relay):
    """The relay welded shut at the end of a short open stretch (closed
    until sample 60, open from 60 to 90, closed again; K stuck ON from 85):
    its own run is the truth, and K stuck OFF, the rival, fits it best
    where it comes nearest: by hand nowhere, since the truth moves the
    plant over the open samples 86 to 89 only and a relay stuck OFF from any
    onset only over closed ones (no fault: magnitude 0). A truth this weak (a
    divergence of about 9) leaves the rival's linearised P under ``SURE``,
    so its expected log Bayes factor is refined with both runs' own
    covariances (a relay stuck closed changes the plant's time constants,
    and so the colour of its noise): the exact KL divergence between the truth's Gaussian and
    the rival's at the onset bgc chose (or no fault: the nominal Gaussian),
    to 1e-5. The rival's fit over the onsets is the least common-covariance
    divergence over them (checked on the grid). Before, the stuck switch's
    run was linearised with its flag set (its X0) before its onset too: 9.71
    where the exact divergence is 9.24."""
    schedule = np.array([not (60 <= k < 90) for k in range(STEPS)])
    package, families = _families(relay, schedule)
    x0, P0, Q, R = _noise(package)
    onset = 85
    mean_t, cov_t = measurements(configuration(schedule, "stuck_on", onset), x0, P0, Q, R)
    d = distinction.distinguish(families, "K_stuck_on", 1.0, onset, {"K": 0.02, "R_load": 0.01})
    rival = next(x for x in d.rivals if x.name == "K_stuck_off")
    assert rival.stuck and rival.magnitude == 0.0
    # the common-covariance fit over the onsets, by hand: the least of 1/2 |L^-1 (mu_r(tau) - mu_t)|^2
    mean_n, cov_n = measurements(configuration(schedule), x0, P0, Q, R)
    chol = np.linalg.cholesky(cov_n)

    def rival_closed(tau):
        return configuration(schedule, "stuck_off", tau)

    fits = [0.5 * float(np.sum(np.linalg.solve(chol, means(rival_closed(t), x0) - mean_t) ** 2))
            for t in families.onsets]
    no_fault = 0.5 * float(np.sum(np.linalg.solve(chol, mean_n - mean_t) ** 2))
    assert min(fits) >= no_fault * (1.0 - 1e-9)  # no onset nearer than no fault (a late one as near, to rounding)
    # the refined expected log Bayes factor: the exact KL from the truth to the rival's Gaussian
    closed_r = rival_closed(rival.onset) if rival.magnitude == 1.0 else configuration(schedule)
    mean_r, cov_r = measurements(closed_r, x0, P0, Q, R)
    exact = gaussian_kl(mean_t, cov_t, mean_r, cov_r)
    assert abs(rival.expected - exact) <= 1e-5 * exact, (rival, exact)
    assert abs(rival.expected - d.divergence) > 1e-4 * exact  # refined: not the common covariance's divergence
    assert rival.std == pytest.approx(math.sqrt(2.0 * rival.expected))


def test_bgc_distinguish_names_a_stuck_switch_and_its_rivals(relay, tmp_path):
    """The report of a stuck switch's scenario: its label, a stuck rival's fit
    as "stuck from t" (not a magnitude), and no refusal; a stuck switch the
    model does not list is refused in one line naming the candidates."""
    r = bgc.distinguishability(relay, "K:stuck_off@0.9", modes="closed@0.5,open@1.5,closed@2.2", steps=STEPS)
    (d,) = r.distinctions
    assert d.truth == "K_stuck_off" and d.divergence > 10 and not d.group
    text = render.distinguishability_text(r)
    assert "truth: K:stuck_off@0.9 (K_stuck_off, from sample 89)" in text
    line = next(row for row in text.splitlines() if row.startswith("K_stuck_on"))
    assert line.endswith("no fault"), line  # stuck ON acts over the open stretch, the truth over the closed ones
    every = bgc.distinguishability(relay, change=0.3, at=0.5, modes="closed@0.5,open@1.5,closed@2.2", steps=STEPS)
    assert {x.label for x in every.distinctions} >= {"K stuck ON", "K stuck OFF"}
    from bgc.errors import SimulationError

    other = tmp_path / "one_kind.yaml"
    other.write_text(MODEL.replace("kinds: [stuck_on, stuck_off]", "kinds: [stuck_on]"))
    with pytest.raises((SimulationError, bgc.Error), match="not a fault candidate") as info:
        bgc.distinguishability(other, "K:stuck_off@0.9", modes="closed@0.5", steps=STEPS)
    assert "K:stuck_on" in str(info.value) and "\n" not in str(info.value)


def test_a_stuck_switchs_own_prior_weighs_it_as_a_rival(relay):
    """Through the API, a stuck switch's prior is the model file's (K: 0.02),
    not the default 0.01: a rival's P is Phi((E - log(prior_rival /
    prior_truth)) / sd) with E and sd as reported (docs/diagnosis.md section 7)."""
    from statistics import NormalDist

    r = bgc.distinguishability(relay, "R_load:abrupt:0.3@0.9", modes="closed@0.5,open@1.5,closed@2.2", steps=STEPS)
    (d,) = r.distinctions
    rival = next(x for x in d.rivals if x.name == "K_stuck_on")
    threshold = math.log(0.02 / 0.01)  # K's prior against R_load's (the default 0.01: the file gives none)
    assert rival.probability == pytest.approx(NormalDist().cdf((rival.expected - threshold) / rival.std), abs=1e-9)


@pytest.mark.slow
def test_a_stuck_truth_on_a_guard_switched_plant_runs_through_the_faulty_plants_own_modes():
    """docs/examples/relay.yaml (the relay K by its voltage guards, the
    contactor S an operator trips and closes again after 5 s): S stuck OFF
    from t = 2 cuts the supply, the voltage falls under the guard that
    opens K, and K stays open, where the nominal plant keeps cycling. The
    truth's run (the package's own model through the mode column of the
    faulty plant's noise-free run) follows the truth simulator's noise-free
    run of the faulty plant to within what the nominal run does (RK4 on the
    sample against the simulator's finer grid); through the nominal plant's
    modes it would be several volts off. As a rival (no inputs given: the
    families' own), its run takes its own modes by the generated model's
    guards and timers, the commands where the nominal run has them, and
    follows the faulty plant as closely."""
    from bgc.analysis.simulate import parse_scenario
    from bgc.api.distinguish import _stuck_inputs

    path = ROOT / "docs" / "examples" / "relay.yaml"
    session = bgc.open(path, backend="numpy")
    T = 800
    quiet = dict(steps=T, process_noise=0.0, measurement_noise=1e-12)
    healthy = bgc.simulate(path, "none", **quiet)
    faulty = bgc.simulate(path, "S:stuck_off@2", **quiet)
    package = session.package
    families = distinction.prepare(package, linear.scenario_inputs(package, T, (), healthy.modes))
    outputs = nominal_model(package).OUTPUTS
    seen = lambda sim: np.column_stack([sim.measurements[name] for name in outputs])  # noqa: E731
    nominal_gap = float(np.abs(families.y - seen(healthy)).max())
    injection = parse_scenario("S:stuck_off@2", session.view.numerics, "scenario")
    own = _stuck_inputs("test", session.view, families, T, (), (), injection)
    assert (own[:, -1] != families.us[:, -1]).any()  # the faulty plant's modes are not the nominal one's
    onset = int(round(2 / 0.01)) - 1
    for us, close in ((own, True), (families.us, False), (None, True)):
        y = families.y + distinction.deviations(families, "S_stuck_off", [1.0], [onset], us)[:, :, 0]
        gap = float(np.abs(y - seen(faulty)).max())
        assert (gap <= 2 * nominal_gap + 1e-3) if close else gap > 1.0, (gap, nominal_gap)
