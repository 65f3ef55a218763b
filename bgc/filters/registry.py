"""The filters by their short names (``--filter``, ``filter=``): one registry."""

from __future__ import annotations


from ..arguments import spelled
from ..errors import TrackingError
from . import cubature
from ..model.protocol import Package


#: Memory the particle arrays of one filter may take (several state-sized
#: arrays of N particles live at once: the particles, the RK4 stages, weights).
MAX_FILTER_BYTES = 4_000_000_000


#: Arrays of N particles alive at once, counted in rows of n_x: the particles
#: and a resampled copy, weights and log-weights (the RK4 scratch is per block).
_ROWS_ALIVE = 3


#: The filters by their short names, one entry each; every one meets the
#: filter protocol (:class:`bgc.filters.Filter`). A particle filter
#: is named by its class in a generated package's ``filters`` module (every
#: package has its copy of ``bgc/filters/particle.py``), a filter of
#: bgc's runtime by its class.
FILTER_CLASSES = {"gpf": "GenericParticleFilter", "apf": "AuxiliaryParticleFilter",
                  "opf": "OptimalProposalParticleFilter", "ckf": cubature.CubatureKalmanFilter}


def filter_class(package: Package, method: str):
    """The filter class of ``method`` (gpf, apf, opf or ckf), a particle
    filter's from ``package``; built as ``cls(model, particles, rng, x=None)``."""
    if method not in FILTER_CLASSES:
        raise TrackingError(f"unknown filter {method!r}", None, "use " + ", ".join(FILTER_CLASSES))
    cls = FILTER_CLASSES[method]
    return getattr(package.filters, cls) if isinstance(cls, str) else cls


def check_particles(particles: int, package: Package, model_name: str) -> None:
    """Refuse, before any work, a particle count below 1 or whose arrays
    would take more than MAX_FILTER_BYTES."""
    n_x = len(package.MODELS[model_name].STATES)
    if particles < 1:
        raise TrackingError(f"{spelled('particles=', '--particles ')}{particles}: at least 1 particle is needed", None,
                            f"e.g. {spelled('particles=200', '--particles 200')}")
    need = int(particles) * (_ROWS_ALIVE * n_x + 3) * 8
    if need > MAX_FILTER_BYTES:
        most = MAX_FILTER_BYTES // ((_ROWS_ALIVE * n_x + 3) * 8)
        raise TrackingError(f"{spelled('particles=', '--particles ')}{particles} would take about {need / 1e9:.3g} GB",
                            None,
                            f"use at most {most} particles for this model")
