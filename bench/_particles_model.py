"""The RO plant as a `particles` state-space model (N. Chopin's library), for column (c).

Runs in bench/.venvs/particles (``particles`` pins numpy < 2). Same equations
as _handwritten_numpy.py (typed in by hand from generated/ro/equations.txt;
derivative and rk4 are imported from there), same RK4 with ``substeps``
substeps, same noise levels; the bootstrap filter is
``particles.SMC(fk=Bootstrap(...), resampling='systematic', ESSrmin=0.5)``,
i.e. systematic resampling when ESS < 0.5 N, the generated filters' rule.
PX0 and PX are custom ProbDists (the RK4 map plus Gaussian noise), PY a
``dists.MvNormal`` around the noise-free outputs (_handwritten_numpy's ``observe``).

Time indexing. The generated filters draw x from the prior, then at step k
propagate with u_k and weight by y_k. `particles` weights X_0 by y_0, so X_0
here is the prior pushed through the first transition (``PX0`` is a
:class:`FirstStep` distribution), and X_t, t >= 1, is ``PX(t, xp)`` with u_t.

`particles` draws from NumPy's global generator; seed it with ``np.random.seed``.
"""

from __future__ import annotations

import numpy as np
from particles import distributions as dists
from particles import state_space_models as ssms

from _handwritten_numpy import observe, rk4

HALF_LOG_2PI = 0.5 * np.log(2.0 * np.pi)


class RK4Transition(dists.ProbDist):
    """X_t | X_t-1 = xp: the RK4 map of xp over one sample period plus N(0, diag(sigma^2)) noise.

    ``xp`` is (N, d); ``rvs(size)`` must be called with size = N (as Bootstrap does).
    """

    def __init__(self, xp, u, dt, substeps, sigma):
        self.xp, self.u, self.dt, self.substeps = xp, u, dt, substeps
        self.sigma = np.asarray(sigma, dtype=float)
        self.dim = self.sigma.shape[0]

    def mean(self):
        return rk4(self.xp, self.u, self.dt, self.substeps)

    def rvs(self, size=None):
        mu = self.mean()
        if size is not None and size != mu.shape[0]:
            raise ValueError("RK4Transition.rvs: size must equal the number of ancestors")
        return mu + self.sigma * np.random.standard_normal(mu.shape)

    def logpdf(self, x):
        z = (x - self.mean()) / self.sigma
        return -0.5 * np.sum(z * z, axis=-1) - np.sum(np.log(self.sigma)) - self.dim * HALF_LOG_2PI


class FirstStep(dists.ProbDist):
    """Law of X_0 for particles: a draw from the prior, pushed through the first transition."""

    def __init__(self, prior, u, dt, substeps, sigma):
        self.prior, self.u, self.dt, self.substeps, self.sigma = prior, u, dt, substeps, sigma
        self.dim = prior.dim

    def rvs(self, size=None):
        return RK4Transition(self.prior.rvs(size=size), self.u, self.dt, self.substeps, self.sigma).rvs(size=size)


class RO(ssms.StateSpaceModel):
    """RO plant: constructed with us (T, n_u), x0, x0_std, process_std, measurement_std, dt, substeps."""

    def PX0(self):
        prior = dists.IndepProd(*[dists.Normal(loc=m, scale=s) for m, s in zip(self.x0, self.x0_std)])
        return FirstStep(prior, self.us[0], self.dt, self.substeps, self.process_std)

    def PX(self, t, xp):
        return RK4Transition(xp, self.us[t], self.dt, self.substeps, self.process_std)

    def PY(self, t, xp, x):
        # MvNormal with (N, d) loc and a (d,) scale, identity cov: independent Gaussian noise per output.
        # An IndepProd of four dists.Normal (scipy.stats logpdf) gives the same numbers, 1.4x slower at N = 200.
        return dists.MvNormal(loc=observe(x), scale=self.measurement_std)
