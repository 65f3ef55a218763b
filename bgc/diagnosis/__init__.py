"""The diagnosis: the online loop and its end.

Bottom of the wing (imported by the rest, importing none of it): ``options``
and ``values`` (frozen values: the options, an alarm, a symbol, a
hypothesis, a diagnosis, a belief). The loop: ``diagnoser`` (configuration,
state and the fallback policies), ``loop`` (watching, isolating, tracking),
``detect``, ``isolate``, ``openloop``, ``onsets``, ``hypothesis`` (a
hypothesis's filters), ``state`` (the state as plain data). The end:
``finish`` (the record to a diagnosis), ``static`` and ``static_posterior``
(the magnitude held static), ``weigh`` (posterior, credible set, verdict),
``rank``, ``identify``, ``estimate``, ``parallel``. ``diagnose``: a recorded
run diagnosed as a batch.
"""
