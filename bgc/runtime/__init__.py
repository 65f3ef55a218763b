"""The runtime: what runs on generated packages and recorded data.

``simulate`` (the truth simulator), ``runs`` (recorded runs as CSV), ``track``
(the generated filters over a run), ``detect`` (the Z-test detector),
``isolate`` (observed symbols against TRANSCEND signatures) and ``diagnose``
(detection, isolation and identification together). It uses the IRs and the
generated packages, never the compiler's internals.
"""
