"""Campaigns of diagnoses (``bgc experiment``): the campaign file read and
expanded (``campaign_file``), one run in a worker (``one_run``) measured
against its truth (``metrics``), where the runs go (``dispatch``: local
processes or a Dask cluster), the results file (``runs_csv``) and the
campaign itself (``campaign``)."""
