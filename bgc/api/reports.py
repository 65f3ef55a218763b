"""What the API returns: a diagnosis's, a calibration's and a distinguishability prediction's report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping


from .. import arguments
from ..ir import NoiseLevels
from ..analysis import distinguish as distinction
from ..output.labels import Labels
from ..data import runs
from ..analysis import simulate
from ..diagnosis.diagnose import Diagnosis
from ..diagnosis.options import DiagnosisOptions
from .calibrate import check_calibration_output


@dataclass(frozen=True, slots=True)
class DiagnosisReport:
    """A diagnosis and what it was made from: the model file, the run (read or
    simulated), the injected fault of a simulated ``scenario`` (None for data
    from a file or a fault-free scenario), the relative noise levels the
    filters assumed (None: the model's), and the options."""

    model: str
    source: str
    run: runs.Run
    scenario: str | None
    injected: simulate.FaultInjection | None
    noise: tuple[float | None, float | None]
    noise_levels: NoiseLevels
    options: DiagnosisOptions
    diagnosis: Diagnosis
    #: What each variable is and its unit, from the model (:mod:`bgc.output.labels`).
    labels: Labels = Labels()

    def __repr__(self) -> str:  # the run and the diagnosis hold arrays: the verdict is what a reader wants
        d = self.diagnosis
        return (f"<bgc.DiagnosisReport of {self.model}: {d.verdict}"
                + (f": {', '.join(d.candidates)}" if d.candidates else "") + ">")

    def write(self, folder: str | Path) -> Path:
        """Write the report folder ``bgc diagnose -o`` writes into ``folder``
        (report.md, report.json, report.html, the plots, the run when it was
        simulated, manifest.json): a new or empty folder, or one a diagnosis
        report was written to before and nobody changed since. Returns the
        folder.

        Raises
        ------
        ArgumentTypeError
            ``folder`` is not a path.
        OutputError
            ``folder`` is a file, or holds files bgc did not write (or that
            changed since), or another command's report.
        """
        arguments.path("bgc.DiagnosisReport.write", "folder", folder)
        from ..output import artifacts, report

        out = Path(folder)
        artifacts.write_folder(out, report.report_files(self))
        return out

    def figures(self) -> dict:
        """The report's plots as live :class:`matplotlib.figure.Figure`
        objects, by the file name :meth:`write` gives each:
        ``measurements.png`` and ``residuals.png``, and ``hypotheses.png``
        and ``estimate.png`` when a fault model was tried. Plain figures,
        not pyplot's: a notebook shows one when it is the cell's value
        (``%matplotlib inline``), ``fig.savefig(...)`` saves it."""
        from ..output import plots

        return plots.diagnosis_plots(self)

    def _repr_html_(self) -> str:
        """A notebook's view: the verdict in words, the detection, the
        estimate with its interval and its picture (:func:`bgc.output.summary.diagnosis_html`)."""
        from ..output import summary

        return summary.diagnosis_html(self)


@dataclass(frozen=True, slots=True)
class CalibrationReport:
    """A calibration (:meth:`Session.calibrate`): the model file, the
    model's name, the sensors whose noise, whether the process level and
    which parameters were estimated, the :class:`~bgc.analysis.calibrate.Calibration`
    (estimates, intervals, innovations) and ``text``, the calibrated model
    file (the user's text with the estimates in place, comments kept)."""

    model: str
    name: str
    sensors: tuple[str, ...]
    process: bool
    parameters: tuple[str, ...]
    calibration: calibration.Calibration
    text: str
    units: Mapping[str, str | None] = field(default_factory=dict)

    def _repr_html_(self) -> str:
        """A notebook's view: whether the model fits the data, the estimates
        with their intervals and their picture (:func:`bgc.output.summary.calibration_html`)."""
        from ..output import summary

        return summary.calibration_html(self)

    def write_report(self, folder: str | Path) -> Path:
        """Write the calibration report into ``folder`` (report.md,
        report.html, report.json, estimates.png, residuals.png, autocorrelation.png;
        docs/calibrate.md, "The report"): a new or empty folder, or one a
        calibration report was written to before and nobody changed since.

        Raises
        ------
        OutputError
            ``folder`` is a file, or holds files bgc did not write.
        """
        arguments.path("bgc.CalibrationReport.write_report", "folder", folder)
        from ..output import artifacts, calibration_report

        out = Path(folder)
        artifacts.write_folder(out, calibration_report.report_files(self))
        return out

    def write(self, path: str | Path) -> Path:
        """Write the calibrated model to ``path`` (a new file, or one bgc
        wrote and nobody changed since: never the model file, a data file
        or another file bgc did not write).

        Raises
        ------
        OutputError
            ``path`` is the model file or a data file, or exists and bgc did
            not write it (or it changed since).
        """
        arguments.path("bgc.CalibrationReport.write", "path", path)
        check_calibration_output(path, self.model, self.calibration.sources)
        from ..output import artifacts

        return artifacts.write_file(Path(path), self.text)


@dataclass(frozen=True, slots=True)
class DistinguishabilityReport:
    """What the data of a model's scenarios are predicted to tell apart
    (:mod:`bgc.analysis.distinguish`): one :class:`Distinction` per scenario,
    over ``steps`` samples at the relative noise levels ``noise`` (None: the
    model's); ``scenario`` when one was asked for, else every fault
    candidate, kind and direction at a relative ``change`` of its parameter
    (a drift reaches it at the end of the run) from the fraction ``at`` of
    the run."""

    model: str
    source: str
    steps: int
    dt: float
    noise: tuple[float | None, float | None]
    scenario: str | None
    change: float | None
    at: float | None
    distinctions: tuple[distinction.Distinction, ...]
    #: Why the model's diagnoser would not expect the scenario's fault (outside its prior), or None.
    warning: str | None = None
    #: How often bgc's own detector alarmed on the scenario in simulated runs
    #: (:class:`bgc.api.detection.DetectorRate`; None: not measured)
    detector: object | None = None
    #: The inputs driven otherwise than the model says: (name, :class:`~bgc.ir.Signal`) pairs
    signals: tuple = ()
