"""Stage 8 for a model with modes: each mode's generated models, and one
model per fault hypothesis across the modes (:func:`generate`).

Every mode is an ordinary bond graph (:func:`bgc.compiler.modes.mode_graph`),
so stage 8 generates its modules as it does a model of one mode's, named
``_m<I>_<model>`` (``I`` the mode's number, 1 for the first listed). Over
them, one module per model (``nominal`` and each fault model) meets the
runtime's protocol (:mod:`bgc.model.protocol`) with a mode axis:

* **The state vector** is every variable that is a state in some mode
  (:func:`bgc.compiler.modes.states`), then the mode (kind ``mode``: its
  number, an integer the model keeps exact; the filters carry it like a
  physical state with no noise), then the fault model's fault states.
* **The mode is an input** too, the last (``mode``: its number, from the run
  file's ``mode`` column, the mode at the sample's time). ``predict``
  integrates each particle with its mode's equations over the sample
  period, then moves it into the input's mode (the resets of the transition
  it takes, then the idle states of the mode entered): a switch the data
  show at a sample happened by its time, as a run's row holds the state
  after the changes due at its time. An input that is NaN (the data do not
  say) leaves each particle in its mode.
* **A state idle in a mode** (an inertia behind an open switch: no state
  there) takes the value that mode's equations give it after every step
  and every draw of process noise, as in the truth simulator
  (:mod:`bgc.analysis.hybrid`).
* **A particle switches where within a step** its guard is crossed (linear
  interpolation between the step's two ends, to 1/8 of a step) or its time
  in the mode runs out: it is integrated to there in its mode and on in the
  mode entered.
* **A guard with a tolerance** (its threshold drawn per visit from
  N(threshold, tolerance^2), as the truth simulator draws it): a particle
  that has not switched yet has its threshold beyond the margin its guard
  had at the step's start; it crosses it within the step with the
  conditional probability of a threshold between the margin it had at the
  last step's end (state ``margin<k>``) and the margin at this step's end,
  decided by its state ``threshold<k>``, a uniform draw made afresh by every
  ``perturb`` (a draw kept from visit to visit would collapse onto a few
  values as the filters resample): at the step's start when the process
  noise carried it across, else where that probability reaches the draw.
  Each step proposes the switch to at least 2 % of the particles a guard
  could move (a threshold in its tail is still tried), their importance
  weight in the state ``proposal``, which the particle filters add to the
  particles' log-weights.
* **A stuck switch** the model lists (``faults: K: {kinds: [stuck_off]}``)
  has a model of its own, ``K_stuck_off``: the nominal model's states and
  one more, its flag ``K_stuck`` (kind ``switch``: 0 before the onset, 1
  from it, a magnitude with no size); a particle whose flag is set runs
  each mode in the configuration the stuck switch makes there
  (:func:`bgc.compiler.modes.compile_stuck`): a declared mode's module, or
  one generated for a configuration no mode has, ``_c<k>_nominal``. Its
  guards, resets and transitions are the modes' (the data still say the
  mode the controller asked for). A configuration with a state no mode has
  is refused in one line.
* **An uncommanded change of a switch** (``uncommanded_on``,
  ``uncommanded_off``) is a stuck switch's model whose flag,
  ``K_uncommanded``, clears where a particle's mode asks for the switch
  where the fault put it (``_RELEASE``, per mode): the controller's next
  command of the switch takes it back, and the particle follows its modes
  again. Cleared on entering such a mode and at the start of every step
  (a flag set where the mode already asks for the switch so, as at an
  onset: the filters set it after the transition into the onset sample,
  whose mode then decides).
* **Noise levels** are those the simulator uses: a state's process noise is
  that of the first mode it is a state of, the measurement noise the first
  mode's.
"""

from __future__ import annotations

import sympy

from ..errors import CodegenError
from ..ir import GeneratedPackage, sym
from ..kinds import fault_kind
from . import codegen
from . import numerics
from .modes import ModeModel, compile_stuck, states as every_state
from .printing import escape, print_expr, print_number

#: The name of the mode among a hybrid model's states and inputs.
MODE = "mode"
#: The state of the time spent in the current mode (a model with a timed transition).
DWELL = "dwell"
#: The states of the guards with a tolerance (k the transition's number, 1 for the first):
#: ``threshold<k>`` a uniform draw for the next step, made by ``perturb``; ``margin<k>`` the guard's
#: margin at the end of the last step, before its process noise; ``proposal`` the log importance
#: weight of the last step's switches (a particle filter adds it to the particle's log-weight).
THRESHOLD, MARGIN, PROPOSAL = "threshold", "margin", "proposal"
#: A switch's fault state, ``<junction>_stuck`` or ``<junction>_uncommanded`` (the kind's suffix; its
#: state kind ``switch``): its flag, 0 before the onset and 1 from it (:attr:`bgc.kinds.FaultKind.discrete`),
#: an uncommanded change's cleared where a mode asks for the switch where the fault put it.
FLAG_KIND = "switch"


def generate(model, modes: tuple[ModeModel, ...], nums: tuple) -> GeneratedPackage:
    """The generated packages of a model with modes: each mode's modules
    (``_m<I>_<name>``, NumPy and compiled), and a module per model across the
    modes (module docstring); ``nums`` each mode's :class:`~bgc.ir.Numerics`.

    Raises
    ------
    CodegenError
        The modes disagree on the inputs, sensors, parameters or fault
        models (a model file cannot make them), or an expression or a number
        that NumPy code cannot hold.
    """
    first = modes[0]
    ssm0 = first.equations
    names = [codegen.module_name(d.name) for d in (first.dbn.nominal, *first.dbn.faulty)]
    for m in modes[1:]:
        s = m.equations
        if (s.inputs, s.outputs, s.parameters) != (ssm0.inputs, ssm0.outputs, ssm0.parameters) or \
                [codegen.module_name(d.name) for d in (m.dbn.nominal, *m.dbn.faulty)] != names:
            raise CodegenError(f"modes {first.name} and {m.name} of {model.name} differ in their inputs, sensors, "
                               "parameters or faults", model.source, "report this: every mode has the model's")
    env = codegen._env()
    common = {"source": escape(model.display_source), "model": escape(model.name),
              "description": escape(model.description, newlines=True)}
    kernel_sha256 = codegen.kernel_digest()
    files: dict[str, str] = {}
    compiled: dict[str, str] = {}
    for i, (m, num) in enumerate(zip(modes, nums), start=1):
        for d in (m.dbn.nominal, *m.dbn.faulty):
            ctx = codegen._model_context(m.dbn, num, d)
            ctx["name"] = own = f"_m{i}_{codegen.module_name(d.name)}"
            ctx["title"] = escape(f"{ctx['title'][:-1]} in mode {m.name} (mode {i}).")
            files[f"{own}.py"] = env.get_template("model.py.j2").render(**common, **ctx, numba=False)
            compiled[f"{own}.py"] = env.get_template("model.py.j2").render(**common, **ctx, numba=True)
            compiled[f"_jit_{own}.py"] = env.get_template("model_jit.py.j2").render(**common, **ctx,
                                                                                      kernel_sha256=kernel_sha256)
    every = every_state(modes)
    for j, name in enumerate(names):
        ctx = _context(model, modes, nums, every, j, name)
        text = env.get_template("hybrid_model.py.j2").render(**common, **ctx)
        files[f"{name}.py"] = compiled[f"{name}.py"] = text
    number = 0  # the configurations no mode has, numbered over the stuck switches
    for fault in model.modes.stuck:
        stuck = compile_stuck(model, modes, fault)
        extra, indices = [], []
        for config, same in zip(stuck.configs, stuck.same):
            if same is not None:
                indices.append(model.modes.names.index(same))
                continue
            known = next((k for k, (m, _) in enumerate(extra) if m is config), None)
            if known is None:
                number += 1
                known = len(extra)
                extra.append((config, number))
                num = numerics.derive(config.dbn)
                ctx = codegen._model_context(config.dbn, num, config.dbn.nominal)
                ctx["name"] = own = f"_c{number}_{codegen.module_name(config.dbn.nominal.name)}"
                ctx["title"] = escape(f"{ctx['title'][:-1]} in configuration {config.name}.")
                files[f"{own}.py"] = env.get_template("model.py.j2").render(**common, **ctx, numba=False)
                compiled[f"{own}.py"] = env.get_template("model.py.j2").render(**common, **ctx, numba=True)
                compiled[f"_jit_{own}.py"] = env.get_template("model_jit.py.j2").render(
                    **common, **ctx, kernel_sha256=kernel_sha256)
            indices.append(len(modes) + known)
        name = codegen.module_name(f"{fault.junction}_{fault.kind}")
        names.append(name)
        ctx = _context(model, modes, nums, every, 0, name, (fault, indices, extra))
        files[f"{name}.py"] = compiled[f"{name}.py"] = env.get_template("hybrid_model.py.j2").render(**common, **ctx)
    for package, fixed in ((files, codegen.FIXED_FILES), (compiled, codegen.NUMBA_FIXED_FILES)):
        for name, source in fixed.items():
            package[name] = codegen._header(common["source"]) + codegen._fixed_text(source)
        package["__init__.py"] = env.get_template("package_init.py.j2").render(**common, modules=names)
    return GeneratedPackage(nums[0], tuple(sorted(files.items())), tuple(names), tuple(sorted(compiled.items())))


def _context(model, modes: tuple[ModeModel, ...], nums: tuple, every: tuple[str, ...], j: int, name: str,
             stuck: tuple | None = None) -> dict:
    """What hybrid_model.py.j2 lays out for the ``j``-th model (0: nominal) across the modes; ``stuck``:
    (the stuck switch, each mode's configuration's index, the configurations no mode has, each with its
    number) for the model of a stuck switch (``j`` 0: the nominal's modules, and the fault's flag)."""
    where = model.source
    first, num0 = modes[0], nums[0]
    d0 = (first.dbn.nominal, *first.dbn.faulty)[j]
    ssm0 = first.equations
    n = len(every)
    fault = codegen.fault_rows(num0, d0) if d0.parameter is not None else None
    fault_states = fault.states if fault else []
    flag = [] if stuck is None else [f"{stuck[0].junction}_{fault_kind(stuck[0].kind).suffix}"]
    timed = any(t.after is not None for t in model.modes.transitions)
    carried = [MODE] + ([DWELL] if timed else [])  # the mode, and the time in it when a transition is timed
    # a guard with a tolerance: each particle's uniform draw for the step, with which it crosses the threshold
    spread = [k for k, t in enumerate(model.modes.transitions) if t.tolerance > 0]
    thresholds = [f"{THRESHOLD}{k + 1}" for k in spread] + [f"{MARGIN}{k + 1}" for k in spread] + \
        ([PROPOSAL] if spread else [])
    states = list(every) + carried + thresholds + fault_states + flag
    at = {x: i for i, x in enumerate(states)}  # each state's row
    kinds = ["physical"] * n + carried + ["threshold"] * len(thresholds) + (fault.kinds if fault else []) + \
        [FLAG_KIND] * len(flag)
    carried = carried + thresholds
    # a state's noise and initial value: the first mode it is a state of (the simulator's rule)
    process, x0 = [], []
    for x in every:
        owner, num = next((m, nm) for m, nm in zip(modes, nums) if x in m.equations.states)
        k = owner.equations.states.index(x)
        process.append(num.noise.process[k])
        x0.append(owner.equations.initial[k])
    x0_std = [2.0 * s for s in process] + [0.0] * len(carried) + (fault.x0_std if fault else []) + [0.0] * len(flag)
    process += [0.0] * len(carried) + (fault.process if fault else []) + [0.0] * len(flag)
    initial = _settled(first, every, x0, ssm0)
    # the draws of the guards with a tolerance: the median where no perturb draws them (a Kalman filter's points)
    x0 = initial + [1.0] + [0.0] * timed + [0.5] * len(spread) + [0.0] * (len(thresholds) - len(spread)) + \
        (fault.x0 if fault else []) + [1.0] * len(flag)
    row = {x: i for i, x in enumerate(every)}
    n_nominal = n + len(carried)
    fault_row = {s: n_nominal + i for i, s in enumerate(fault_states)}
    mode_ctx = [_configuration(i, m, f"Mode {m.name}", f"_m{i}_{codegen.module_name(d0.name) if stuck else name}",
                               every, row, d0, fault_row, fault_states, where, f"mode {m.name}'s idle states")
                for i, m in enumerate(modes, start=1)]
    configs, stuck_ctx = list(mode_ctx), None
    if stuck is not None:
        more, stuck_ctx = _stuck(model, stuck, every, row, at[flag[0]], len(mode_ctx))
        stuck_ctx["releases"] = [stuck[0].released(m.on) for m in model.modes.modes] if stuck[0].releases else None
        configs += more
    transitions = _transitions(model, modes, row, d0, fault_row, at, spread)
    n_inputs = len(ssm0.inputs)
    return {
        "name": name, "title": escape(f"{'Nominal model' if fault is None and stuck is None else 'Model'} of "
                                      f"{model.name} across its modes"
                                      f"{'' if fault is None else f', with an {d0.kind} fault of {d0.parameter}'}"
                                      f"{'' if stuck is None else f', with {stuck[0].title}'}."),
        "modes": mode_ctx, "configs": configs, "stuck": stuck_ctx, "mode_names_tuple": codegen._tuple(repr(m.name) for m in modes),
        "states_tuple": codegen._tuple(repr(x) for x in states),
        "state_kinds_tuple": codegen._tuple(repr(k) for k in kinds),
        "inputs_tuple": codegen._tuple(repr(u) for u in (*ssm0.inputs, MODE)), "n_inputs": n_inputs,
        "mode_row": at[MODE], "dwell_row": at.get(DWELL), "n_nominal": n_nominal, "n_states": len(states),
        "threshold_rows": [at[f"{THRESHOLD}{k + 1}"] for k in spread],
        "margins": [{"index": k, "row": at[f"{MARGIN}{k + 1}"]} for k in spread],
        "proposal_row": at.get(PROPOSAL),
        "n_first": len(first.equations.states),
        "x0": codegen._floats(x0, "an initial value", where), "x0_std": codegen._floats(x0_std, "an initial std", where),
        "process_std": codegen._floats(process, "a process-noise std", where),
        "fault": fault is not None or stuck is not None,
        "noise_fault": fault is not None and fault_kind(d0.kind).noise,
        "transitions": transitions,
        "dt": print_number(model.settings.dt, "simulation.dt", where),
        "substeps": max(num.substeps for num in nums),
    }


def _configuration(number: int, m: ModeModel, title: str, module: str, every: tuple[str, ...], row: dict[str, int],
                   d, fault_row: dict[str, int], fault_states: list[str], where, what: str) -> dict:
    """What hybrid_model.py.j2 lays out of a configuration of the switches
    (a mode's, or one a stuck switch makes: ``m``) for fault model ``d``:
    its number, name, title, module, its states' rows (then the fault
    states'), the rows of the states idle in it and the lines that settle them."""
    s = m.equations
    idle = [x for x in every if x not in s.states]
    variables = dict(s.variables)
    return {"number": number, "name": m.name, "title": title, "module": module,
            "rows": [row[x] for x in s.states] + [fault_row[x] for x in fault_states],
            "idle": [row[x] for x in idle],
            "settle": _assignments([(row[x], variables[x]) for x in idle], _sources(s, row, d, fault_row), where,
                                   what)}


def _stuck(model, stuck: tuple, every: tuple[str, ...], row: dict[str, int], flag_row: int,
           first: int) -> tuple[list[dict], dict]:
    """The configurations a stuck switch makes that no mode has (numbered
    from ``first`` + 1, after the modes), and what hybrid_model.py.j2 lays
    out of the switch (each mode's configuration, its flag's row, its
    ``FAULT``); ``stuck``: (the switch, each mode's configuration's index,
    those configurations with their modules' numbers). A configuration with
    a state no mode has is refused."""
    switch, indices, extra = stuck
    out = []
    for m, number in extra:
        missing = [x for x in m.equations.states if x not in row]
        if missing:
            raise CodegenError(f"with {switch.title} in {m.name.split(' with ')[0]}, {', '.join(missing)} "
                               f"{'is a state' if len(missing) == 1 else 'are states'} in no mode of "
                               f"{model.name}; bgc cannot follow that stuck switch yet", switch.loc,
                               "declare a mode with that configuration of the switches, or leave out the fault")
        out.append(_configuration(first + len(out) + 1, m, f"Configuration {m.name}",
                                  f"_c{number}_{codegen.module_name(m.dbn.nominal.name)}", every, row,
                                  m.dbn.nominal, {}, [], model.source, f"{m.name}'s idle states"))
    return out, {"configs": list(indices), "row": flag_row, "title": escape(switch.title),
                 "fault": repr({"parameter": switch.junction, "kind": switch.kind, "magnitude": FLAG_KIND,
                                "target": "switch", "subject": switch.junction, "unit": ""})}


def _transitions(model, modes: tuple[ModeModel, ...], row: dict[str, int], d0, fault_row: dict[str, int],
                 at: dict[str, int], spread: list[int]) -> list[dict]:
    """What hybrid_model.py.j2 lays out of each transition: its modes' numbers, its guard (each side's
    NumPy text; a tolerance's std and the rows of its draw and last margin), its time, its resets."""
    where = model.source
    transitions = []
    by_name = {m.name: (i, m) for i, m in enumerate(modes, start=1)}
    for k, t in enumerate(model.modes.transitions):
        i, source = by_name[t.source]
        s = source.equations
        resolve = {sym(v): e for v, e in s.variables}
        sources = _sources(s, row, d0, fault_row)
        what = f"transition {t.source} -> {t.target}"
        body = [(row[state], expr.xreplace(resolve)) for state, expr in t.resets]
        guard = None
        if t.guard is not None:
            sides = [sympy.sympify(t.guard.lhs).xreplace(resolve), sympy.sympify(t.guard.rhs).xreplace(resolve)]
            unpack, (lhs, rhs) = _expressions(sides, sources, where, f"the guard of {what}")
            guard = {"unpack": unpack, "lhs": lhs, "op": t.guard.op, "rhs": rhs, "text": escape(t.guard.text),
                     "rising": t.guard.op in (">", ">="), "strict": t.guard.op in (">", "<"),
                     "tolerance": print_number(t.tolerance, "a transition's tolerance", where) if k in spread
                     else None, "row": at.get(f"{THRESHOLD}{k + 1}"), "margin_row": at.get(f"{MARGIN}{k + 1}")}
        transitions.append({"index": k, "source": i, "target": by_name[t.target][0], "kind": t.kind,
                            "text": escape(f"{t.source} -> {t.target}"), "guard": guard,
                            "after": print_number(t.after, "a transition's after", where) if t.after is not None
                            else None, "reset": _assignments(body, sources, where, f"the resets of {what}")})
    return transitions


def _settled(first: ModeModel, every: tuple[str, ...], x0: list[float], ssm) -> list[float]:
    """The initial states with those idle in the first mode at what its
    equations give them (the inputs at time 0, the parameters nominal)."""
    values = {sym(x): v for x, v in zip(every, x0)}
    values.update({sym(p): v for p, v in zip(ssm.parameters, ssm.parameter_values)})
    signals = {i.name: i.signal for i in first.graph.inputs}
    values.update({sym(u): signals[u].at(0.0) for u in ssm.inputs})
    variables = dict(ssm.variables)
    out = []
    for x, v in zip(every, x0):
        if x in ssm.states:
            out.append(float(v))
        else:
            out.append(float(sympy.sympify(variables[x]).xreplace(values)))
    return out


def _sources(ssm, row: dict[str, int], d, fault_row: dict[str, int]) -> dict[str, str]:
    """Where each name an expression of mode ``ssm`` uses comes from in the
    model across the modes: states and inputs by index, parameters from
    theta, a fault model's parameter from its fault states."""
    sources = {x: f"x[{row[x]}]" for x in ssm.states}
    sources.update({u: f"u[{i}]" for i, u in enumerate(ssm.inputs)})
    sources.update({p: f"theta[{i}]" for i, p in enumerate(ssm.parameters)})
    if d.parameter is not None:
        p = d.parameter
        if fault_kind(d.kind).drifts:
            sources[p] = f"x[{fault_row[p]}]"
        else:
            sources[p] = f"theta[{ssm.parameters.index(p)}] + x[{fault_row[f'delta_{p}']}]"
    return sources


def _assignments(pairs: list[tuple[int, object]], sources: dict[str, str], where, what: str) -> list[str]:
    """The lines that set rows of x to expressions (all computed first, then
    written): the names they use unpacked, then ``_v<k> = ...``, then ``x[row] = _v<k>``."""
    if not pairs:
        return []
    unpack, texts = _expressions([e for _, e in pairs], sources, where, what)
    return (unpack + [f"_v{k} = {text}" for k, text in enumerate(texts)]
            + [f"x[{r}] = _v{k}" for k, (r, _) in enumerate(pairs)])


def _expressions(exprs: list, sources: dict[str, str], where, what: str) -> tuple[list[str], list[str]]:
    """(the lines that unpack the names ``exprs`` use from ``sources``, each expression's NumPy text)."""
    exprs = [sympy.sympify(e) for e in exprs]
    used = {s.name for e in exprs for s in e.free_symbols}
    unknown = sorted(used - set(sources))
    if unknown:
        raise CodegenError(f"{what} name {', '.join(unknown)}, which the mode's equations do not give", where,
                           "report this: a guard, a reset or an idle state reads states, inputs and parameters only")
    return [f"{name} = {sources[name]}" for name in sources if name in used], [print_expr(e) for e in exprs]
