"""bgc: a bond-graph model compiler for model-based fault diagnosis.

A plant described as a bond graph in YAML is compiled, stage by stage, into a
probabilistic fault diagnoser (see :mod:`bgc.pipeline`): validated model ->
causality (SCAP) -> temporal causal graph -> state equations -> dynamic Bayesian
networks -> generated NumPy particle filters.

The public API (docs/api.md; each name's ``help()`` says more)
--------------------------------------------------------------
open(model) -> Session
    A compiled model and its generated package: ``equations(format)``,
    ``tcg()``, ``dbn(name)``, ``signatures()``, ``diagnoser()`` (online, one
    sample at a time), ``calibrate(data)``.
simulate(model, scenario, seed=...) -> Simulation
    A run of the plant with its truth (arrays by name, ``to_frame()``).
diagnose(model, data=... | scenario=..., filter=..., identify=...) -> DiagnosisReport
    Detection, isolation and the fault's size (``to_dict()``, ``table()``,
    ``to_frame()``, ``write(folder)``, ``figures()``); DiagnosisOptions for every option.
distinguishability(model, scenario=...) -> DistinguishabilityReport
    Which faults the data of a scenario can tell apart, before any run.
analyse(model) -> AnalysisReport
    Which faults the sensors can detect and tell apart, structurally, by
    their signatures and at the data's noise, before the plant runs.
run_campaign(campaign_file, out) -> CampaignResult
    A campaign of runs (``to_frame()``; its ``runs.csv`` reads with pandas).
Table
    Rows of one kind of result (``to_frame()``).
Error, ModelError, DataError, ArgumentError, ArgumentTypeError, ArgumentValueError, SimulationError, ...
    What bgc raises for a user's mistake; ScenarioWarning for a fault outside the model's prior.

Glossary
--------
e, f
    Effort and flow of a bond (voltage/current, pressure/volume flow,
    force/velocity); ``e4`` and ``f4`` are those of bond 4.
p, q
    Momentum (integral of effort) and displacement (integral of flow).
Se, Sf
    Effort and flow sources; MSe, MSf their modulated forms.
R, C, I
    Resistor, capacitor and inertia; MR a modulated resistor.
TF, GY
    Transformer (``e_in = m e_out``, ``f_out = m f_in``) and gyrator
    (``e_in = r f_out``, ``e_out = r f_in``); MTF, MGY modulated.
0, 1
    Junctions: common effort (flows sum to zero) and common flow (efforts sum).
SCAP
    Sequential causality assignment procedure.
TCG
    Temporal causal graph (Mosterman and Biswas, 1999).
DBN, 2TBN
    Dynamic Bayesian network, given by its two-slice template.
x, u, y, theta
    States, inputs, measurements and parameters of the state-space model.
logw, ancestors, ess
    Log-weights, resampling indices and effective sample size of a particle filter.
"""

__version__ = "0.1.0"


from .errors import (ArgumentError, ArgumentTypeError, ArgumentValueError, DataError, Error, ExperimentError,
                     ModelError, OutputError, SimulationError, TrackingError)

#: The names of :mod:`bgc.api` that ``bgc`` gives (imported on first use).
API = ("open", "Session", "diagnose", "DiagnosisReport", "distinguishability", "DistinguishabilityReport",
       "analyse", "AnalysisReport", "CalibrationReport", "simulate", "Simulation", "DiagnosisOptions", "Table", "ScenarioWarning")
#: The campaign wing's public names (:mod:`bgc.experiment.public`; imported on first use).
CAMPAIGN = ("run_campaign", "CampaignResult")
#: The service wing's public names (:mod:`bgc.service.public`; imported on first use).
SERVICE = ("monitor", "Monitor")

__all__ = [*API, *CAMPAIGN, *SERVICE, "Error", "ModelError", "DataError", "ArgumentError", "ArgumentTypeError",
           "ArgumentValueError",
           "SimulationError", "TrackingError", "OutputError", "ExperimentError", "__version__"]


def __getattr__(name: str):
    """``bgc.open`` (a :class:`~bgc.api.Session`: a compiled model and its
    online diagnosers), ``bgc.diagnose``, ``bgc.distinguishability`` and their reports
    (:mod:`bgc.api`), imported on first use so that ``import bgc`` stays
    light. Each checks its arguments (:class:`bgc.errors.ArgumentTypeError`,
    :class:`bgc.errors.ArgumentValueError`)."""
    if name in API:
        from . import api

        return getattr(api, name)
    if name in CAMPAIGN:
        from .experiment import public

        return getattr(public, name)
    if name in SERVICE:
        from .service import public as service

        return getattr(service, name)
    raise AttributeError(f"module 'bgc' has no attribute {name!r}")
