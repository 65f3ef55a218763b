"""The runtime: what runs on generated packages and recorded data.

``simulate`` (the truth simulator), ``runs`` (recorded runs as CSV), ``track``
(the generated filters over a run). It uses the IRs and the generated
packages, never the compiler's internals.
"""
