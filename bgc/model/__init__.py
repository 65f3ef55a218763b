"""The generated model as the runtime reads it: the protocol of a generated
model and package and the conventions of a fault (``protocol``: the bottom
of the runtime, imported by every wing above it), a package loaded from its
folder and the choice of backend (``package``), and the compiled backend's
warm-up (``warmup``)."""

#: The backend every door defaults to (``--backend``, ``run_campaign``): chosen by what is installed
#: and the work (:func:`bgc.model.package.auto_backend`; ``BGC_BACKEND`` first). The results do not
#: depend on it, the time does. Here, not in ``package``: the command line reads it without numpy.
DEFAULT_BACKEND = "auto"
