"""Diagnosis: is the plant faulty, which fault, when, how large, how sure.

The architecture of the thesis (Fig. II.5, sections II.3.3, II.4 and IV.2.1),
with the onset, not the detection time, as the hand-over:

1. **Track** the plant with the nominal observer (a generated particle
   filter), one step at a time, keeping its particle clouds of the last
   ``history`` steps.
2. **Detect** with the sliding-window Z-test on its normalised residuals
   (:mod:`bgc.diagnosis.detect`), and estimate the onset.
3. **Isolate qualitatively**: stop the observer, run its cloud at the onset
   open loop, read each sensor's magnitude and slope symbols (window tests
   against the open-loop particle paths) and keep the faults whose TRANSCEND
   signatures agree (:mod:`bgc.diagnosis.isolate`).
4. **Isolate and identify quantitatively**: for each remaining (parameter,
   kind), the generated fault-model filter starts at the onset from the
   nominal cloud of that time, lifted into the fault model with the fault
   magnitude drawn from its prior, and runs to the end of the data, estimating
   the magnitude jointly with the state. The fault changes the parameter at
   the instant of the onset sample (the thesis's DBN, the simulator): the
   transition into that sample is nominal, the sample sees the fault
   (:func:`~bgc.model.protocol.onset_transition`). One hypothesis's filters run in
   lockstep over its onsets (an onset whose running evidence falls ``PRUNE``
   behind the best one's is pruned); the hypotheses run in parallel
   processes.
5. **Drop** every hypothesis whose filter cannot follow the data: the same
   windowed Z-test runs on each filter's own normalised residuals, with a
   probability ``rejection`` of rejecting a filter of the true hypothesis
   over the run. A filter whose statistic goes beyond ``FAR`` (2) times the
   threshold is far off the data: it stops there and its onset is out, so
   the work on wrong hypotheses and onsets ends early (a filter just over the
   threshold runs on: at low noise the right model is sometimes just off the
   truth). A hypothesis is dropped when the filter of its most probable onset
   is rejected, or when every onset's filter stopped. (A hypothesis whose
   every onset has been rejected runs on to the end all the same: at low
   noise the right one sometimes is, and its estimate over the whole run is
   still the best there is, reported with the verdict ``unexplained``.)
6. **Weigh and identify with the magnitude held static** (``identify =
   "kalman"``, the default): each hypothesis its filters keep gets the
   posterior of its onset and magnitude under the fault model as the thesis
   states it (a constant bias, or a constant slope, from an onset on), from
   cubature Kalman filters run over a grid of onsets and magnitudes
   (:mod:`bgc.filters.cubature`; exact on plants linear in their states once
   the fault is fixed, a close approximation on mildly nonlinear ones). Its
   evidence, the likelihood integrated over the magnitude's prior and the
   onsets, times the candidate's prior, weighs the hypotheses; its
   posterior mean and central interval are the estimate. These jobs start as
   soon as a hypothesis's filters are done. With ``identify = "filter"`` (the
   thesis's method) the weights are the filters' own evidence instead: the
   product of each filter's one-step predictive densities (their Gaussian
   approximation, mean and std of the predicted measurement), over a common
   span (the nominal filter's densities before a later onset), summed over
   the onsets tried, each weighed by the samples it stands for (a stopped
   onset counts zero), times the candidate's prior; and the estimate is the
   filters' magnitude state (below). Either way a survivor less probable
   than the best by a Bayes factor above ``bayes_factor`` is dropped too. The
   survivors are the diagnosis; when several survive, they form an ambiguity
   group, ranked by probability, each with its estimate.
7. **Rank** (``rank``, with ``identify = "filter"`` only, off by default):
   when several survive, weigh them anew by the evidence of their models with
   the magnitude held static from particle filters on a grid, and drop those
   the Bayes factor rules out.
8. **Refine** (``refine``, off by default): each survivor's magnitude by
   the particle filters' marginal likelihood on a grid (:mod:`bgc.diagnosis.identify`).

The onset is a parameter too: each hypothesis is tried from the detector's
change point and, for a drift, from a grid of earlier steps (``spacing``
apart, back to ``search`` steps before the alarm, and coarser further back;
the grid is extended back by ``search`` steps at a time, up to ``history``,
while the drift's onset posterior piles up at its earliest onset; a step
change is tried from the ``near`` samples before the change point to 2 after
it, and no later than the sample after the alarm), and the
onsets are weighed like the hypotheses, each by the span of time it stands
for (its prior: uniform in time); a slow drift is detected long after it
began, and starting its filter late biases the slope.

**The filters' identification.** In the fault-model filters the fault
magnitude (a bias for an abrupt fault, a slope for an incipient one) is a
state of the fault model, with a small random walk
(per step std: a fraction of |theta| for a bias, of the prior's width for a
slope; :mod:`bgc.kinds`). After every step its particles get Liu and West's
(2001) kernel move with shrinkage ``shrinkage`` (a = 0.98, a discount of
about 0.99): the weighted mean and variance are kept, and the particles that
resampling duplicated become distinct again, so the cloud does not collapse
onto a few values while the data narrow the magnitude down. The clouds at the
last step of every onset's filter, weighed by the onset's posterior
probability, form a mixture that gives the estimate (its weighted mean) and a
central interval (weighted quantiles): the onset is averaged over, not fixed at
its most probable value. The band plotted over time is the most probable
onset's weighted mean plus or minus the normal quantile times its weighted std.
"""

from __future__ import annotations

import math

from ..ir import FaultSignatures
from ..data.sampler import grid_steps, samples
from .. import events as ev
from .diagnoser import IDENTIFY, KALMAN_METHOD, Diagnoser
from .finish import dated_misfit, with_misfits_said
from .openloop import PATHS
from ..data.runs import Run, input_columns
from .values import Belief, Diagnosis, Estimate, Hypothesis, Live
from .options import DiagnosisOptions
from ..model.protocol import Package, nominal_model

#: What the batch diagnosis's callers take from here (the values and the method's names).
__all__ = ["diagnose", "horizon_steps", "Belief", "Diagnosis", "DiagnosisOptions", "Estimate", "Hypothesis", "Live",
           "IDENTIFY", "KALMAN_METHOD", "PATHS"]


def diagnose(run: Run, package: Package, signatures: FaultSignatures, priors: dict[str, float],
             options: DiagnosisOptions = DiagnosisOptions(), progress=None, every: bool = False, *,
             time_unit: str | None = None) -> Diagnosis:
    """Diagnose a recorded run with a generated package and the model's
    signatures: the online :class:`~bgc.diagnosis.diagnoser.Diagnoser` over
    its samples (:func:`bgc.data.sampler.samples`: the model's time grid,
    held inputs, missing sensors), then its ``finish``, with the hypotheses'
    filters run over the record on ``options.workers`` processes.

    ``priors``: each fault candidate's prior probability (the model's
    ``faults: ... prior``); ``progress(text)``, when given, is told what is
    being done. ``every``: try every fault model, those the symbols rule out
    too. ``options.horizon`` None here: the detector's horizon is the
    record's length (:func:`bgc.diagnose` fills in the model's run length).
    ``time_unit``: the model's (None: none declared), by which the run's
    times are written (:attr:`bgc.diagnosis.values.Diagnosis.clock`).
    """
    nominal = nominal_model(package)
    steps = grid_steps(run.time, nominal.DT)  # the record's length on the grid, for a horizon of None
    d = Diagnoser(package, signatures, priors, options, horizon_steps(options.horizon, nominal.DT, steps),
                  time_unit=time_unit, inputs=input_columns(run), sensors=run.measurements, source=run.source,
                  lazy=True, every=every, progress=progress)
    said = []  # the misfits said while watching, dated: the record may forget their data after
    for s in samples(run, d.sampler):
        said += [dated_misfit(e, d.time_of) for e in d.take(s).events if isinstance(e, ev.Mismatched)]
    return with_misfits_said(d.finish(run), said)


def horizon_steps(horizon: float | None, dt: float, record: int) -> int:
    """The detector's horizon in steps of ``dt``: ``horizon`` time units
    (None: the ``record``'s steps), at least 1."""
    if horizon is None:
        return max(int(record), 1)
    return max(int(math.floor(horizon / dt + 0.5)), 1)
