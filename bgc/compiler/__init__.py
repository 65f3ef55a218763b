"""The compiler: one module per stage, from a model file to a generated package.

``load`` (path -> RawModel), ``validate`` (-> BondGraph; with ``expressions``,
the safe parser), ``causality`` (SCAP -> CausalBondGraph), ``tcg`` (->
TemporalCausalGraph), ``equations`` (-> StateSpaceModel), ``dbn`` (->
DbnModel), ``numerics`` (-> Numerics), ``codegen`` (-> GeneratedPackage; with
``printing``, the strict NumPy printer). :mod:`bgc.pipeline` chains them.
Stages import :mod:`bgc.ir`, :mod:`bgc.kinds`, :mod:`bgc.errors` and each
other's public names only; they do no I/O but ``load``'s reading.
"""
