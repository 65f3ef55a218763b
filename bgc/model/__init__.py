"""The generated model as the runtime reads it: the protocol of a generated
model and package and the conventions of a fault (``protocol``: the bottom
of the runtime, imported by every wing above it), a package loaded from its
folder and the choice of backend (``package``), and the compiled backend's
warm-up (``warmup``)."""
