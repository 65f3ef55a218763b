""":func:`run_campaign`: a campaign file (``bgc experiment``) run from Python; its :class:`CampaignResult`
(``bgc.run_campaign``, ``bgc.CampaignResult``: the campaign wing's public door, beside :mod:`bgc.api`)."""

from __future__ import annotations

import os
from pathlib import Path

from .. import arguments
from ..model import DEFAULT_BACKEND
from .campaign import CampaignResult
from .campaign import run_campaign as _run
from .campaign_file import Campaign, load_campaign
from .dispatch import check_workers

__all__ = ["run_campaign", "CampaignResult"]


def run_campaign(campaign: str | Path | Campaign, out: str | Path, *, scheduler: str | None = None,
                 workers: int | None = None, progress: bool | None = None, outputs: bool = True,
                 backend: str = DEFAULT_BACKEND) -> CampaignResult:
    """Run a campaign (its file, docs/experiments.md, or one read by
    :func:`bgc.experiment.campaign_file.load_campaign`) into the folder
    ``out``, as ``bgc experiment CAMPAIGN -o OUT`` does, with the same
    defaults: local processes (``workers``: one per core) or a Dask
    ``scheduler``, ``backend`` ``auto``, the tables and plots written at the
    end. A folder this campaign wrote before resumes it. The result's
    :meth:`CampaignResult.to_frame` is its rows as a DataFrame; the folder's
    ``runs.csv`` loads with ``pandas.read_csv`` as it is.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range.
    ExperimentError
        A malformed campaign file, a folder holding another campaign, a
        scheduler that cannot be reached.
    """
    check_workers(workers, "bgc.run_campaign: workers")
    if not isinstance(campaign, Campaign):
        arguments.path("bgc.run_campaign", "campaign", campaign)
        campaign = load_campaign(os.fspath(campaign))
    return _run(campaign, out, scheduler, workers, progress, outputs, backend=backend)
