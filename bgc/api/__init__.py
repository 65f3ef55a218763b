"""The Python API: what the CLI does, for a notebook or a script.

>>> import bgc
>>> report = bgc.diagnose("models/circuit.yaml", scenario="R2:abrupt:0.6@5", seed=1)
>>> report.diagnosis.verdict, report.diagnosis.candidates
('isolated', ('R2_abrupt',))
>>> e = report.diagnosis.estimate
>>> round(e.value, 1), e.low < 0.6 < e.high
(0.6, True)

:func:`diagnose` compiles the model and generates its NumPy package, or
reads both from bgc's compile cache (:mod:`bgc.api.cache`; or uses the
package ``generated`` points at), reads the run (or
simulates ``scenario`` with the truth simulator), and runs
:func:`bgc.diagnosis.diagnose.diagnose`. :mod:`bgc.output.report` turns the
result into ``report.json``, ``report.md``, ``report.html`` and plots:
:meth:`DiagnosisReport.write` writes them, :meth:`DiagnosisReport.figures`
gives the plots as matplotlib figures, and in a notebook a report, a
:class:`Session` and a :class:`CalibrationReport` show a summary
(``_repr_html_``; ``docs/examples/diagnose.ipynb``).

Every public function checks its arguments before any work, as the command
line does, with the same ranges: a wrong type is an
:class:`~bgc.errors.ArgumentTypeError` (also a :class:`TypeError`), a value
out of range an :class:`~bgc.errors.ArgumentValueError` (also a
:class:`ValueError`), each one line naming the function and the argument;
problems of the data (a run file, a :class:`~bgc.data.runs.Run`) are the
runtime's :class:`~bgc.errors.DataError`, naming the run's ``source``.

>>> bgc.diagnose("models/circuit.yaml", scenario="none", seed=-1)
Traceback (most recent call last):
...
bgc.errors.ArgumentValueError: bgc.diagnose: seed=-1 is negative (give an integer >= 0, e.g. seed=0)
"""

from __future__ import annotations

from ..diagnosis.options import DiagnosisOptions
from .analyse import AnalysisReport, analyse
from .diagnose import diagnose
from .distinguish import distinguishability
from .reports import CalibrationReport, DiagnosisReport, DistinguishabilityReport
from .session import ScenarioWarning, Session, open
from .simulate import Simulation, simulate
from .tables import Table

__all__ = ["open", "Session", "simulate", "Simulation", "diagnose", "DiagnosisReport", "DiagnosisOptions",
           "distinguishability", "DistinguishabilityReport", "analyse", "AnalysisReport", "CalibrationReport", "Table",
           "ScenarioWarning"]
