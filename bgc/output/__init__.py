"""Output: text, JSON and DOT dumps of every IR (``render``), pictures of the
TCG and DBNs (``draw``), plots of runs and estimates (``plots``), and
``artifacts``, the only module that writes files.
"""
