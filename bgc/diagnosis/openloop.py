"""The nominal model run open loop from the onset, for the symbols (step 3):
the nominal cloud before a step (:func:`cloud_before`; the cubature Kalman
filter's Gaussian, :func:`gaussian_cloud`) and the run itself
(:func:`open_loop`)."""

from __future__ import annotations


import numpy as np

from ..filters import cubature as kalman
from .isolate import OpenLoop
from .options import DiagnosisOptions


#: Open-loop particle paths kept for the symbols' null distribution: enough for
#: the variance of a statistic to within a few per cent, whatever N.
PATHS = 4000


def cloud_before(clouds: dict, start: int):
    """The nominal cloud after the step before ``start`` (None: start at the model's prior)."""
    before = [k for k in clouds if k < start]
    return clouds[max(before)] if before else None


def gaussian_cloud(observer: kalman.NominalTrack, onset: int, options: DiagnosisOptions):
    """A cloud of ``options.particles`` equally weighted draws from the
    nominal cubature Kalman filter's state before step ``onset`` (its
    Gaussian), for the open-loop run of the symbols."""
    rng = np.random.default_rng([options.seed, 9997])
    L = kalman.cholesky(observer.cov[onset][None])[0]
    x = observer.mean[onset][:, None] + L @ rng.standard_normal((len(observer.mean[onset]), options.particles))
    return x, np.zeros(options.particles)


def open_loop(package, cls, nominal, cloud, ys, us, onset, steps, options) -> OpenLoop:
    """The nominal model run open loop from the cloud before the onset (the
    observer stopped): the data's deviations from its mean prediction and
    each particle's path (see :class:`bgc.diagnosis.isolate.OpenLoop`)."""
    rng = np.random.default_rng([options.seed, 9999])
    x = None if cloud is None else cloud[0][:, package.filters.systematic_resample(cloud[1], rng)]
    pf = cls(nominal, options.particles, rng, x=x)
    blind = np.full(ys.shape[1], np.nan)
    deviation = np.empty((steps, ys.shape[1]))
    # the paths kept: all of them up to PATHS, else PATHS drawn at random (memory: steps x sensors x PATHS)
    kept = (slice(None) if options.particles <= PATHS
            else np.sort(np.random.default_rng([options.seed, 9998]).choice(options.particles, PATHS, replace=False)))
    paths = np.empty((steps, ys.shape[1], min(options.particles, PATHS)))
    with np.errstate(all="ignore"):
        for t in range(steps):
            r = pf.step(blind, us[onset + t])  # no measurement: no weighing, no resampling
            deviation[t] = ys[onset + t] - r.y_mean
            paths[t] = nominal.observe(pf.x[:, kept], us[onset + t], pf.theta) - r.y_mean[:, None]
    return OpenLoop(onset, deviation, paths, np.asarray(nominal.MEASUREMENT_STD, dtype=float))
