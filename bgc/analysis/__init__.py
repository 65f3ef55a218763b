"""Work on a model and its data outside the online loop: the truth
simulator (``simulate``, which reads the compiler's equations on purpose: an
evaluation path independent of the generated code), distinguishability
before any data (``distinguish``), calibration from healthy data
(``calibrate``) and one filter over a run (``track``, ``bgc filter``)."""
