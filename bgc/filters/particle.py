"""Particle filters over the generated models of a package (NumPy only).

bgc copies this file unchanged into every package it generates, as
``filters.py`` (its source is ``bgc/filters/particle.py``): it
imports numpy only, and reaches the package's numerics through each model's
``_kernel``. Every filter here meets the filter protocol
(``bgc.filters.Filter``): ``step(y, u, dt)`` takes one sample and
gives a :class:`StepResult`, ``run(ys, us, dt)`` a whole record.

The model (initial sampler, transition, observation log-likelihood) lives in
the model modules; the filters below read like the thesis's algorithms:

* :class:`GenericParticleFilter`: Algorithm 1 (prior proposal, weight update,
  effective sample size, systematic resampling when N_eff < N_T);
* :class:`AuxiliaryParticleFilter`: Algorithm 2 (Pitt and Shephard, 1999):
  first-stage weights from p(y | mu) with mu the noise-free prediction,
  second-stage weights p(y | x) / p(y | mu);
* :class:`OptimalProposalParticleFilter`: not in the thesis; the locally
  optimal proposal (Doucet, Godsill and Andrieu, 2000), for plants whose
  sensors are sharp against the spread of the prediction.

Weights are kept as log-weights. When every weight underflows (or particles
diverge to NaN) the filter resets the weights (and replaces the broken
particles) and counts the event in ``recoveries`` instead of returning NaN. A
measurement that is NaN is not used; an all-NaN measurement skips the update.
"""

import numpy as np


def _exp_normalised(logw):
    """(w, m, s): the weights exp(logw) normalised to sum 1 (``logw`` left alone),
    max(logw) and the sum of exp(logw - m)."""
    m = logw.max()
    w = np.subtract(logw, m)
    np.exp(w, out=w)
    s = w.sum()
    w /= s
    return w, m, s


def systematic_resample(logw, rng):
    """Ancestor indices by systematic resampling (one uniform draw U), in O(N);
    ``logw`` need not be normalised. See :func:`offspring_counts`."""
    w, _, _ = _exp_normalised(logw)
    return np.repeat(np.arange(w.shape[0]), offspring_counts(w, rng, overwrite=True))


def offspring_counts(w, rng, overwrite=False, chunk=8192):
    """How many copies of each particle systematic resampling of the normalised
    weights ``w`` keeps (one uniform draw U; an intp array summing to N).

    With the positions (j + U) / N and c the cumulative weights, particle i is
    the ancestor of the positions in (c[i-1], c[i]], that is of K[i] - K[i-1]
    of them, K[i] = floor(N c[i] - U) + 1 (K[N-1] = N): no search, no index
    array. With ``overwrite`` the counts are computed in the memory of ``w``
    (its values are lost), with temporaries of ``chunk`` elements only."""
    if w.dtype != np.float64:  # the counts are made in float64 memory
        w, overwrite = w.astype(np.float64), True
    n = w.shape[0]
    c = np.cumsum(w, out=w if overwrite else None)
    c *= n / c[-1]
    c -= rng.random()
    np.floor(c, out=c)
    np.minimum(c, n - 1, out=c)
    c[-1] = n - 1
    # K[i] - K[i-1] in place, from the last chunk back: each chunk reads the
    # (still cumulative) element before it
    for stop in range(n, 1, -chunk):
        start = max(1, stop - chunk)
        c[start:stop] -= c[start - 1:stop - 1]
    c[0] += 1.0
    counts = c.view(np.intp)
    for start in range(0, n, chunk):
        counts[start:start + chunk] = c[start:start + chunk]  # float -> int in place, a chunk at a time
    return counts


def gauss_terms(cache, seen, std, kernel, compiled=False):
    """The Gaussian log-likelihood's terms of a pattern ``seen`` of sensors
    read (bool (n_y,)) with noise std ``std`` (n_y,), kept in ``cache`` per
    pattern: (the rows read, None when all are, -1 / (2 std^2) of them, the
    sum of their log normalisers); ``compiled``: a compiled kernel's own
    ``gauss_terms`` (what its ``weigh`` takes)."""
    key = (compiled, seen.tobytes())
    hit = cache.get(key)
    if hit is None:
        hit = cache[key] = (kernel.gauss_terms(seen, std) if compiled else
                            (None if seen.all() else np.flatnonzero(seen), -0.5 / (std[seen] * std[seen]),
                             kernel.log_normaliser(std[seen])))
    return hit


def noise_variance(r, w):
    """The measurement noise's variance (n_y,) over weighted particles
    (weights ``w``) from their noise std ``r``, a model's
    ``measurement_std(x)``: MEASUREMENT_STD (n_y,) squared, or for a model
    whose noise std differs from particle to particle (a noise fault: (n_y,
    N)) its weighted mean."""
    return r ** 2 if r.ndim == 1 else (r * r) @ w


def normalise(logw):
    """Normalised log-weights (``logw`` is overwritten) and the effective sample
    size 1 / sum(w^2)."""
    logw, ess, _ = _normalise(logw)
    return logw, ess


def _normalise(logw):
    """normalise(), also giving the normalised weights."""
    w, m, s = _exp_normalised(logw)
    ess = 1.0 / np.dot(w, w)
    logw -= m + np.log(s)
    return logw, ess, w


class StepResult:
    """What one filter step gives (any filter of the protocol): mean and std
    of the state after the update (n_x,), the predicted measurement's mean
    and std before it (n_y,), the effective sample size (``inf`` for a filter
    without particles), whether the particles were resampled and whether the
    filter had to recover, and ``loglik``, log p(y_k | y_0 .. y_k-1), from a
    filter that gives it exactly (the cubature Kalman filter; None here)."""

    __slots__ = ("mean", "std", "y_mean", "y_std", "ess", "resampled", "recovered", "loglik")

    def __init__(self, mean, std, y_mean, y_std, ess, resampled, recovered, loglik=None):
        self.mean, self.std, self.y_mean, self.y_std = mean, std, y_mean, y_std
        self.ess, self.resampled, self.recovered, self.loglik = ess, resampled, recovered, loglik


class FilterRun:
    """What a filter gives over a whole record of T steps: weighted mean and
    std of the state (T, n_x), predicted measurement mean and std before each
    update (T, n_y), ESS (T,), and per step whether the particles were
    resampled and whether the filter had to recover (bool, (T,)); a particle
    filter of a model with modes: each mode's probability, the weight of the
    particles in it after the update (T, number of modes), else None."""

    __slots__ = ("mean", "std", "y_mean", "y_std", "ess", "resampled", "recovered", "modes")

    def __init__(self, steps, n_x, n_y, modes=0):
        self.mean, self.std = np.empty((steps, n_x)), np.empty((steps, n_x))
        self.y_mean, self.y_std = np.empty((steps, n_y)), np.empty((steps, n_y))
        self.ess = np.empty(steps)
        self.resampled = np.zeros(steps, bool)
        self.recovered = np.zeros(steps, bool)
        self.modes = np.empty((steps, modes)) if modes else None


def mode_probabilities(model, x, logw) -> np.ndarray:
    """Each mode's probability under a weighted cloud of a model with modes:
    the normalised weight of the particles whose mode state rounds to it."""
    count = len(model.MODES)
    w = np.exp(logw - np.max(logw))
    numbers = np.clip(np.rint(np.nan_to_num(x[model.MODE_ROW], nan=1.0)), 1, count).astype(np.intp)
    return np.bincount(numbers - 1, weights=w, minlength=count) / w.sum()


def quiet(step):
    """A filter's ``step`` with NumPy's floating-point warnings off: a
    particle that diverges (an overflow, inf - inf) is the step's own to
    handle (its weight fails, the step recovers: ``recovered``), not a
    warning on the caller's standard error."""
    def quietly(self, *args, **kwargs):
        with np.errstate(all="ignore"):
            return step(self, *args, **kwargs)
    quietly.__name__, quietly.__qualname__, quietly.__doc__ = step.__name__, step.__qualname__, step.__doc__
    return quietly


def run_filter(f, ys, us, dt=None):
    """Filter a whole record with ``f`` (any filter of the protocol, on a
    model with ``STATES``): its ``step`` over ys (T, n_y) and us (T, n_u), in
    order. Returns a FilterRun."""
    ys = np.asarray(ys, dtype=float)
    us = np.asarray(us, dtype=float)
    modes = len(getattr(f.model, "MODES", ())) if hasattr(f, "logw") else 0
    out = FilterRun(ys.shape[0], len(f.model.STATES), ys.shape[1], modes)
    for k in range(ys.shape[0]):
        r = f.step(ys[k], us[k], dt)
        out.mean[k], out.std[k], out.ess[k] = r.mean, r.std, r.ess
        out.y_mean[k], out.y_std[k] = r.y_mean, r.y_std
        out.resampled[k], out.recovered[k] = r.resampled, r.recovered
        if modes:
            out.modes[k] = mode_probabilities(f.model, f.x, f.logw)
    return out


class _Filter:
    """What the particle filters share: a weighted cloud of ``n`` particles
    ``x`` (n_x, n) with log-weights ``logw`` (n,), of a model and its
    ``theta``, their random numbers from ``rng``; ``recoveries`` counts the
    steps whose weights all failed. A filter adds ``step``."""

    def __init__(self, model, n_particles, rng, theta=None, threshold=0.5, x=None):
        """model: a generated model module; threshold: resample when ESS < threshold * N."""
        self.model = model
        self.n = int(n_particles)
        self.rng = rng
        self.theta = tuple(float(v) for v in (model.THETA if theta is None else theta))
        self.threshold = float(threshold) * self.n
        self.x = model.initial_particles(rng, self.n) if x is None else np.array(x, dtype=float)
        self.logw = np.full(self.n, -np.log(self.n))
        self.w = None  # normalised exp(logw), kept from step to step for up to two blocks
        #: up to two blocks of particles: keep the weights, resample in one np.repeat
        self._small = self.n < 2 * model._kernel.BLOCK
        self.recoveries = 0
        self._gauss = {}

    def prepare(self, seen) -> None:
        """Make now what the first step would make on first use, so that an
        online diagnosis's first sample costs what the others cost: the
        weights kept from step to step, the Gaussian terms of the pattern
        ``seen`` (bool (n_y,)) of sensors the data are expected to read, and
        a compiled kernel's handle of the generator. No number the filter
        gives changes (each is what that step would have made)."""
        if self._small:
            self.w = self._weights()
        kernel = self.model._kernel
        std = np.asarray(self.model.MEASUREMENT_STD, dtype=float)
        gauss_terms(self._gauss, np.asarray(seen, dtype=bool), std, kernel, compiled=hasattr(kernel, "weigh"))
        handle = getattr(kernel, "generator_handle", None)
        if handle is not None:
            handle(self.rng)

    def _proposed(self, x):
        """Add to the log-weights the importance weights of a step's proposal
        (a model with modes whose guards have a tolerance proposes switches
        beyond the model's probability: their log-weights in row
        ``PROPOSAL_ROW`` of the predicted particles ``x``)."""
        row = getattr(self.model, "PROPOSAL_ROW", None)
        if row is not None:
            self.logw = self.logw + x[row]
            self.w = None

    def _weights(self):
        """The normalised weights exp(logw): the ones kept from the last step
        (up to two blocks of particles), else computed afresh (for more
        particles: one array of N less to keep)."""
        return self.w if self.w is not None else _exp_normalised(self.logw)[0]

    def _recover(self):
        """Replace non-finite particles by copies of finite ones and reset weights."""
        bad = ~np.isfinite(self.x).all(axis=0)
        if bad.all():
            self.x = self.model.initial_particles(self.rng, self.n)
        elif bad.any():
            good = np.flatnonzero(~bad)
            self.x[:, bad] = self.x[:, self.rng.choice(good, bad.sum())]
        self.logw = np.full(self.n, -np.log(self.n))
        self.w = None
        self.recoveries += 1

    def _finish(self, logw, y_mean, y_std, recovered):
        self.w = None  # the weights before the update: not needed any more
        top = logw.max()
        if np.isnan(top) and np.isfinite(self.x).all():
            # a (finite) particle whose likelihood is not a number is impossible,
            # not a reason to throw the step away; broken particles are recovered below
            logw[np.isnan(logw)] = -np.inf
            top = logw.max()
        if not np.isfinite(top):
            if recovered:  # this step's failure is already counted
                self.recoveries -= 1
            self._recover()
            logw, recovered = self.logw, True
        kernel = self.model._kernel
        # a compiled package's kernel: normalising, resampling and the moments in one call (up to two
        # blocks of particles; beyond, the block-wise steps below keep the memory beyond the particle
        # array to a few blocks)
        done = kernel.finish(self.x, logw, self.threshold, self.rng) if self._small and hasattr(
            kernel, "finish") else None
        if done is not None:
            self.logw, ess, resampled, w, mean, std = done
            self.w = w
            return StepResult(mean, std, y_mean, y_std, ess, resampled, recovered)
        compiled = getattr(kernel, "resample", None) if self._small else None
        logw, ess, w = (kernel.normalise if compiled else _normalise)(logw)
        resampled = ess < self.threshold
        if resampled:
            if compiled:
                self.x = compiled(self.x, w, self.rng.random())
            else:
                self.x = self._replicate(self.x, offspring_counts(w, self.rng, overwrite=True))
            logw.fill(-np.log(self.n))
            w.fill(1.0 / self.n)  # (offspring_counts made the counts in w's memory)
        self.logw = logw
        mean, std = self.model._kernel.moments(self.x, w)
        if self._small:
            self.w = w
        return StepResult(mean, std, y_mean, y_std, ess, resampled, recovered)

    def _replicate(self, x, counts):
        """The resampled particles: column i of x repeated counts[i] times. One
        np.repeat for up to two blocks of particles, else row by row in place
        (one row of temporary: no second (n_x, N) array)."""
        if self._small:
            return np.repeat(x, counts, axis=1)
        for j in range(x.shape[0]):
            x[j] = np.repeat(x[j], counts)
        return x

    def _predicted_measurement(self, yhat, x, logw=None):
        """Weighted mean and std of y over the particles' noise-free measurements
        ``yhat`` of particles ``x`` (weights: the filter's, or ``logw``),
        measurement noise included."""
        w = self._weights() if logw is None else _exp_normalised(logw)[0]
        mean, std = self.model._kernel.moments(yhat, w)
        return mean, np.sqrt(std ** 2 + noise_variance(self.model.measurement_std(x), w))

    def run(self, ys, us, dt=None):
        """Filter a whole record: ys (T, n_y), us (T, n_u). Returns a FilterRun."""
        return run_filter(self, ys, us, dt)


class GenericParticleFilter(_Filter):
    """Thesis Algorithm 1: sample from the prior p(x_k | x_k-1), weight by p(y_k | x_k)."""

    @quiet
    def step(self, y, u, dt=None, predicted=False):
        """One step with measurement y (NaN: not read) and input u.
        ``predicted``: the particles were already moved by ``model.predict``
        (a caller that predicts several filters' particles in one array, the
        same model and theta); only the process noise is added here."""
        dt = self.model.DT if dt is None else dt
        y = np.asarray(y, dtype=float)
        # a compiled package's model: the whole step in one call (up to two blocks of particles)
        fused = None if predicted or not self._small else getattr(self.model, "generic_step", None)
        if fused is not None:
            kernel = self.model._kernel
            y = kernel.contiguous(y)
            done = fused(self.x, u, self.theta, dt, self.rng, y,
                         gauss_terms(self._gauss, np.isfinite(y), self.model.MEASUREMENT_STD, kernel, compiled=True),
                         self.logw, self._weights(), self.threshold)
            if done is not None:
                ess, resampled, w, y_mean, y_std, mean, std = done
                if ess < 0:  # the weights failed: recovered as the step below would
                    return self._finish(self.logw, y_mean, y_std, False)
                self.w = w
                return StepResult(mean, std, y_mean, y_std, ess, resampled, False)
        if predicted:
            self.model.perturb(self.x, self.rng)
        else:
            self.model.transition(self.x, u, self.theta, dt, self.rng, out=self.x)
        self._proposed(self.x)
        missing = np.isnan(y).all()
        y_mean, y_std = self._weigh(None if missing else y, u)
        return self._finish(self.logw, y_mean, y_std, False)

    def _weigh(self, y, u):
        """Add log p(y | x) to the log-weights in place (nothing without y) and
        give the predicted measurement (over the weights before the update),
        one block of particles at a time.

        Residuals are taken from a shift K, the first particle's prediction (a
        value inside the cloud keeps the moments free of cancellation, however
        far y is): with d = yhat - K and r = K - y, the predicted measurement
        has mean K + E[d] and variance E[d^2] - E[d]^2, and over the measured
        outputs sum_j (yhat_j - y_j)^2 / std_j^2 = sum_j (d_j^2 + 2 r_j d_j + r_j^2) / std_j^2.
        A model whose noise std differs from particle to particle (a noise
        fault) is weighed by :meth:`_weigh_each`.
        """
        model, kernel = self.model, self.model._kernel
        std = model.measurement_std(self.x)
        if std.ndim == 2:
            return self._weigh_each(y, u, std)
        w = self._weights()
        if self._small and hasattr(kernel, "weigh"):  # a compiled package's kernel: the loop below in one call
            gauss = None if y is None else gauss_terms(self._gauss, np.isfinite(y), std, kernel, compiled=True)
            return kernel.weigh(model.observe(self.x, u, self.theta), y, std, self.logw, w, gauss)
        n_y = len(std)
        if y is not None:
            rows, weight, constant = gauss_terms(self._gauss, np.isfinite(y), std, kernel)
            measured = y if rows is None else y[rows]
        s1 = np.zeros(n_y)
        s2 = np.zeros(n_y)
        shift = None
        parts, _ = kernel.spans(self.n)
        for start, stop in parts:
            d = kernel.block_views("state", 1, n_y, stop - start)[0]  # no kernel call while in use
            model.observe(self.x[:, start:stop], u, self.theta, out=d)
            if shift is None:
                shift = np.where(np.isfinite(d[:, 0]), d[:, 0], 0.0)
                column = shift[:, None]
                if y is not None:
                    r = (shift if rows is None else shift[rows]) - measured
                    linear = 2.0 * weight * r
                    constant = constant + float(weight @ (r * r))
            d -= column
            wb = w[start:stop]
            s1 += d @ wb
            if y is not None:
                cross = linear @ (d if rows is None else d[rows])
            d *= d
            s2 += d @ wb
            if y is not None:
                block = self.logw[start:stop]
                block += weight @ (d if rows is None else d[rows])
                block += cross
        if y is not None:
            self.logw += constant
        var = np.maximum(s2 - s1 * s1, 0.0) + std * std
        return shift + s1, np.sqrt(var)

    def _weigh_each(self, y, u, std):
        """:meth:`_weigh` for measurement noise of a std per particle, ``std``
        (n_y, N): log N(y; yhat, std^2) per particle, and the predicted
        measurement's variance the spread of yhat plus the particles' mean
        noise variance (weights before the update)."""
        model = self.model
        w = self._weights()
        yhat = model.observe(self.x, u, self.theta)
        mean, spread = model._kernel.moments(yhat, w)
        if y is not None:
            self.logw += model._kernel.gaussian_loglik(y, yhat, std)
        return mean, np.sqrt(spread * spread + noise_variance(std, w))


class AuxiliaryParticleFilter(_Filter):
    """Thesis Algorithm 2: choose ancestors by w_k-1 * p(y_k | mu_k), propagate,
    weight by p(y_k | x_k) / p(y_k | mu_k).

    p(y_k | mu_k) is a Gaussian of the model's ``predictive_std`` around the
    cloud's weighted mean (measurement noise plus the process noise seen
    through the outputs where the plant runs now), which
    keeps the second-stage weights from being heavy-tailed when the process
    noise is not small against the measurement noise (Pitt and Shephard, 1999).
    The noise-free prediction mu is computed once: the new particles are
    mu[ancestors] plus process noise.
    """

    @quiet
    def step(self, y, u, dt=None, predicted=False):
        """As :meth:`GenericParticleFilter.step`."""
        dt = self.model.DT if dt is None else dt
        y = np.asarray(y, dtype=float)
        mu = self.x if predicted else self.model.predict(self.x, u, self.theta, dt, out=self.x)
        self._proposed(mu)
        if np.isnan(y).all():
            self.model.perturb(mu, self.rng)
            y_mean, y_std = self._predicted_measurement(self.model.observe(mu, u, self.theta), mu)
            return self._finish(self.logw, y_mean, y_std, False)
        # The predicted measurement (before y is used) from the cloud before the
        # selection: the weighted mean and spread of the noise-free predictions,
        # plus the predictive std (measurement noise and the process noise seen
        # through the outputs around the cloud's mean). The selected particles
        # re-weighted by 1 / p(y | mu) give the same in expectation, but with a
        # large variance when y is far out: the selection has moved them towards it.
        ymu = self.model.observe(mu, u, self.theta)
        w = self._weights()
        y_mean, y_spread = self.model._kernel.moments(ymu, w)
        centre = np.ascontiguousarray(mu) @ w
        predictive = self.model.predictive_std(centre[:, None], u, self.theta)[0]
        y_std = np.sqrt(y_spread * y_spread + predictive ** 2)
        first = self.model._kernel.gaussian_loglik(y, ymu, predictive)
        del ymu
        broken = np.isnan(first)
        if broken.any():  # a finite particle whose prediction is not a number is impossible
            first[broken & np.isfinite(mu).all(axis=0)] = -np.inf
        stage1 = self.logw + first
        recovered = False
        if not np.isfinite(stage1.max()):  # every first-stage weight underflowed: plain GPF step
            first = np.zeros(self.n)
            stage1 = self.logw
            recovered = True
            self.recoveries += 1
        _, _, w1 = _normalise(stage1)
        counts = offspring_counts(w1, self.rng, overwrite=True)
        self.x = self.model.perturb(self._replicate(mu, counts), self.rng)
        yhat = self.model.observe(self.x, u, self.theta)
        back = np.repeat(first, counts)
        np.negative(back, out=back)
        del counts, w1
        logw = self.model.loglik_observed(y, yhat, self.model.measurement_std(self.x)) + back
        return self._finish(logw, y_mean, y_std, recovered)


class OptimalProposalParticleFilter(_Filter):
    """The locally optimal proposal (Doucet, Godsill and Andrieu, 2000,
    section II.D): each particle moves from its noise-free prediction mu
    towards y, drawn from p(x_k | x_k-1, y_k) with the measurement linearised
    around mu, and is weighted by the exact importance ratio
    p(y | x) p(x | mu) / q(x), so the filter stays consistent when the
    linearisation is not exact.

    When a sensor is sharp against the spread the process noise gives the
    prediction (a stiff coupling measured precisely), the prior proposal of
    :class:`GenericParticleFilter` puts almost every particle where the
    likelihood is nil: its effective sample size collapses and the cloud
    loses the state. This proposal keeps the particles where the measurement
    says they are.

    In the process noise's own units z (x = mu + q z, q = ``PROCESS_STD``)
    the prior is N(0, I); the measurement is linearised by central
    differences over one process std, A = (h(mu + q_j e_j) - h(mu - q_j e_j)) / 2
    column by column, S = A A' + R, K = A' S^-1. The proposal N(K (y - h(mu)),
    I - K A) is sampled without a factorisation, z = e + K (y - h(mu) - A e - v)
    with e ~ N(0, I), v ~ N(0, R) (exact for a linear measurement); its
    density needs only S (the precision is I + A' R^-1 A, whose determinant
    is det S / det R). A model whose noise std differs from particle to
    particle (a noise fault) has its own R per particle, at its prediction.
    """

    @quiet
    def step(self, y, u, dt=None, predicted=False):
        """As :meth:`GenericParticleFilter.step`."""
        model = self.model
        dt = model.DT if dt is None else dt
        y = np.asarray(y, dtype=float)
        mu = self.x if predicted else model.predict(self.x, u, self.theta, dt, out=self.x)
        self._proposed(mu)
        if np.isnan(y).all():
            model.perturb(mu, self.rng)
            y_mean, y_std = self._predicted_measurement(model.observe(mu, u, self.theta), mu)
            return self._finish(self.logw, y_mean, y_std, False)
        seen = np.isfinite(y)
        q = np.asarray(model.PROCESS_STD, dtype=float)
        r = np.asarray(model.measurement_std(mu), dtype=float)  # (n_y,), or (n_y, N): one per particle
        n_y = r.shape[0]
        n_x, n = mu.shape
        moved = np.flatnonzero(q > 0)
        m = len(moved)
        # the measurements and their sensitivities in one call: mu, then mu +- q_j e_j
        probes = np.repeat(mu[:, None, :], 1 + 2 * m, axis=1)
        for i, j in enumerate(moved):
            probes[j, 1 + i] += q[j]
            probes[j, 1 + m + i] -= q[j]
        with np.errstate(all="ignore"):
            h = model.observe(probes.reshape(n_x, -1), u, self.theta).reshape(n_y, 1 + 2 * m, n)
        del probes
        h0 = np.ascontiguousarray(h[:, 0])  # (n_y, N)
        A = np.zeros((n, n_y, n_x))  # per particle: the measurements' change per process std of each state
        A[:, :, moved] = ((h[:, 1:1 + m] - h[:, 1 + m:]) / 2.0).transpose(2, 0, 1)
        del h
        # the predicted measurement (before y is used): the cloud's spread of h(mu), plus the process
        # noise seen through the outputs, plus the measurement noise
        w = self._weights()
        y_mean, y_spread = model._kernel.moments(h0, w)
        seen_noise = np.einsum("nij,nij->in", A, A) @ w
        y_std = np.sqrt(y_spread * y_spread + seen_noise + noise_variance(r, w))
        A, h0, r = A[:, seen], h0[seen], r[seen]
        r = r if r.ndim == 1 else r.T  # (n_s,), or (N, n_s): broadcasts against a particle's row
        n_s = r.shape[-1]
        S = A @ A.transpose(0, 2, 1)
        S[:, np.arange(n_s), np.arange(n_s)] += r * r
        innovation = (y[seen][:, None] - h0).T  # (N, n_s)
        e = self.rng.standard_normal((n, n_x))
        v = self.rng.standard_normal((n, n_s)) * r
        with np.errstate(all="ignore"):
            target = innovation - np.einsum("nij,nj->ni", A, e) - v
        # a particle whose prediction is not finite (it diverged) moves by its prior alone and gets no
        # weight; the factorisation below needs finite matrices
        broken = ~(np.isfinite(S).all(axis=(1, 2)) & np.isfinite(target).all(axis=1))
        if broken.any():
            S[broken] = 0.0  # R alone, each particle its own
            diagonal = np.arange(n_s)
            S[np.flatnonzero(broken)[:, None], diagonal, diagonal] = np.broadcast_to(r * r, (n, n_s))[broken]
            A[broken] = 0.0
            innovation[broken] = 0.0
            target[broken] = 0.0
        with np.errstate(all="ignore"):
            L = np.linalg.cholesky(S)
            solved = np.linalg.solve(S, np.stack([innovation, target], axis=2))  # S^-1 [innovation, target]
            mean = np.einsum("nji,nj->ni", A, solved[:, :, 0])  # K (y - h(mu))
            z = e + np.einsum("nji,nj->ni", A, solved[:, :, 1])
            d = z - mean
            Ad = np.einsum("nij,nj->ni", A, d)
            # log q(z) - log N(z; 0, I), the 2 pi terms cancelling
            log_ratio = (-0.5 * ((d * d).sum(axis=1) + (Ad * Ad / (r * r)).sum(axis=1))
                         + np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1) - np.log(r).sum(axis=-1)
                         + 0.5 * (z * z).sum(axis=1))
        x = mu + q[:, None] * z.T
        with np.errstate(all="ignore"):
            logw = (self.logw + model.loglik_observed(y, model.observe(x, u, self.theta), model.measurement_std(x))
                    - log_ratio)
        logw[broken] = -np.inf  # a finite particle whose prediction is not a number is impossible;
        logw[~np.isfinite(x).all(axis=0)] = np.nan  # one that diverged is recovered (_finish)
        if not np.isfinite(logw).any() and np.isfinite(mu).all():  # y far beyond every particle: the prior's step,
            x = mu + q[:, None] * e.T  # as the generic filter takes it (its weights then say what happened)
            with np.errstate(all="ignore"):
                logw = self.logw + model.loglik_observed(y, model.observe(x, u, self.theta), model.measurement_std(x))
        self.x = x
        return self._finish(logw, y_mean, y_std, False)


class FilterBank:
    """Several filters of one model, class, particle count and theta, each
    with its own random numbers, stepped together (the hypothesis filters of
    one fault from several onsets): one call of the integrator, of the
    observation and of each elementwise operation for all their particles,
    instead of one per filter; on a few hundred particles a filter step's cost
    is mostly per call.

    Every filter ends each step exactly as its own :meth:`step` (after
    ``model.predict`` on its particles) leaves it: it draws the same random
    numbers from its own generator in the same order, elementwise arithmetic
    is the same element by element, and every sum over particles is made per
    filter by the same kind of call on the same memory layout as
    :meth:`step`'s (a sum over the particles of a block made by BLAS can round
    differently when the block sits inside a wider array). So a filter's
    numbers do not depend on which filters run beside it. The particles of
    the filters live in one array: each filter's ``x``, ``logw`` and ``w``
    are views of the bank's arrays while it is in the bank.

    A lone filter takes its own step (the bank would only add its
    overhead). Filters of more than two blocks of particles, of mixed
    classes or particle counts, with the optimal proposal (its arithmetic
    is per particle already) or of a model whose noise std differs from
    particle to particle (a noise fault: its own weighing) are stepped one
    by one after one integrator call; so is a step in which a filter's
    weights all underflow (its :meth:`step` recovers)."""

    def __init__(self, model):
        self.model = model
        self.filters = []
        self.packed = False
        self._gauss = {}

    def step(self, filters, y, u):
        """Step ``filters`` (a list; the bank re-packs when it changes) with
        measurement y and input u; their StepResults in the same order."""
        if not filters:
            return []
        y = np.asarray(y, dtype=float)
        if len(filters) == 1:  # nothing to share: the filter's own step, without the bank's overhead
            self.filters, self.packed = list(filters), False
            pf = filters[0]
            self.model.predict(pf.x, u, pf.theta, self.model.DT, out=pf.x)
            return [pf.step(y, u, predicted=True)]
        if [id(pf) for pf in filters] != [id(pf) for pf in self.filters] or not self.packed:
            self.filters = list(filters)
            self._pack()
        if not self.packed:
            return self._one_by_one(y, u)
        model = self.model
        model.predict(self.x, u, self.theta, model.DT, out=self.x)
        if isinstance(self.filters[0], AuxiliaryParticleFilter):
            if np.isnan(y).all():
                return self._lone(y, u)
            return self._apf(y, u)
        return self._gpf(y, u)

    def _pack(self):
        """The filters' particles, log-weights and weights in one array each,
        the filters' own attributes views of them; not packed when the filters
        cannot be stepped together."""
        fs = self.filters
        first = fs[0]
        self.packed = (not isinstance(first, OptimalProposalParticleFilter)
                       and getattr(self.model, "PROPOSAL_ROW", None) is None
                       and np.ndim(self.model.measurement_std(first.x)) == 1
                       and all(type(pf) is type(first) and pf.n == first.n and pf.theta == first.theta
                               and pf._small and pf.threshold == first.threshold for pf in fs))
        if not self.packed:
            return
        n = first.n
        self.n, self.theta, self.threshold = n, first.theta, first.threshold
        self.x = np.concatenate([pf.x for pf in fs], axis=1)
        self.logw = np.stack([pf.logw for pf in fs])
        self.w = np.stack([pf._weights() for pf in fs])
        for f, pf in enumerate(fs):
            self._view(f, pf)

    def _view(self, f, pf):
        pf.x = self.x[:, f * self.n:(f + 1) * self.n]
        pf.logw, pf.w = self.logw[f], self.w[f]

    def _one_by_one(self, y, u):
        """Filters that cannot share arrays: one integrator call for all
        particles of one theta, then each filter's own step."""
        groups = {}
        for pf in self.filters:
            groups.setdefault(pf.theta, []).append(pf)
        for theta, pfs in groups.items():
            x = np.concatenate([pf.x for pf in pfs], axis=1)
            self.model.predict(x, u, theta, self.model.DT, out=x)
            at = 0
            for pf in pfs:
                pf.x = x[:, at:at + pf.n].copy()
                at += pf.n
        return [pf.step(y, u, predicted=True) for pf in self.filters]

    def _lone(self, y, u):
        """Each filter's own step on its (already predicted) particles; the
        bank re-packs before its next step."""
        self.packed = False
        return [pf.step(y, u, predicted=True) for pf in self.filters]

    def _stacked(self, rows):
        """The bank's (rows, F * N) array ``rows`` as (F, rows, N) views."""
        return rows.reshape(rows.shape[0], len(self.filters), self.n).transpose(1, 0, 2)

    def _perturb(self, x):
        """Each filter's process noise, from its own generator, as
        ``model.perturb`` draws it (one block of particles)."""
        buf = np.empty((len(self.filters), x.shape[0], self.n))
        for f, pf in enumerate(self.filters):
            self.model._kernel.normal_into(pf.rng, buf[f])
        buf *= np.asarray(self.model.PROCESS_STD, dtype=float)[:, None]
        self._stacked(x)[...] += buf

    def _moments(self, a, w):
        """Each filter's weighted mean and std of the rows of ``a`` (F, rows, N),
        as ``_kernel.moments`` makes them: (F, rows) each."""
        mean = np.matmul(a, w[:, :, None])[:, :, 0]
        d = np.empty(a.shape)
        np.subtract(a, mean[:, :, None], out=d)
        d *= d
        var = np.zeros(mean.shape)
        var += np.matmul(d, w[:, :, None])[:, :, 0]
        return mean, np.sqrt(np.maximum(var, 0.0))

    def _loglik(self, y, yhat, std):
        """(F, N): each filter's ``_kernel.gaussian_loglik(y, yhat, std[f])``
        of its columns of ``yhat`` (n_y, F * N); ``std`` (F, n_y), or (n_y,)
        for all filters."""
        seen = np.isfinite(y)
        stacked = self._stacked(yhat)
        std = np.broadcast_to(np.asarray(std, dtype=float), (len(self.filters), len(y)))
        if not seen.all():
            y, stacked, std = y[seen], stacked[:, seen], std[:, seen]
        weight = -0.5 / (std * std)
        d = np.empty(stacked.shape)  # (F, n_y, N): each filter's block contiguous, as in gaussian_loglik
        np.subtract(stacked, y[:, None], out=d)
        d *= d
        total = np.zeros((len(self.filters), self.n))
        for j in range(d.shape[1]):  # output by output, in order, as gaussian_loglik adds them
            d[:, j] *= weight[:, j, None]
            total += d[:, j]
        for f in range(len(self.filters)):
            total[f] += self.model._kernel.log_normaliser(std[f])
        return total

    def _gpf(self, y, u):
        """GenericParticleFilter.step for every filter."""
        model = self.model
        self._perturb(self.x)
        missing = np.isnan(y).all()
        std = model.MEASUREMENT_STD
        count = len(self.filters)
        # GenericParticleFilter._weigh, for all filters
        yhat = model.observe(self.x, u, self.theta)
        stacked = self._stacked(yhat)
        shift = stacked[:, :, 0]
        shift = np.where(np.isfinite(shift), shift, 0.0)  # (F, n_y)
        d = np.empty(stacked.shape)  # (F, n_y, N): each filter's block contiguous, as in _weigh
        np.subtract(stacked, shift[:, :, None], out=d)
        s1 = np.zeros(shift.shape)
        s1 += np.matmul(d, self.w[:, :, None])[:, :, 0]
        if not missing:
            rows, weight, constant = gauss_terms(self._gauss, np.isfinite(y), std, model._kernel)
            measured = y if rows is None else y[rows]
            constants = np.empty(count)
            cross = np.empty((count, self.n))
            for f in range(count):
                r = (shift[f] if rows is None else shift[f][rows]) - measured
                linear = 2.0 * weight * r
                constants[f] = constant + float(weight @ (r * r))
                cross[f] = linear @ (d[f] if rows is None else d[f][rows])
        d *= d
        s2 = np.zeros(shift.shape)
        s2 += np.matmul(d, self.w[:, :, None])[:, :, 0]
        if not missing:
            for f in range(count):
                self.logw[f] += weight @ (d[f] if rows is None else d[f][rows])
            self.logw += cross
            self.logw += constants[:, None]
        var = np.maximum(s2 - s1 * s1, 0.0) + std * std
        return self._finish(self.logw, shift + s1, np.sqrt(var), np.zeros(count, bool))

    def _apf(self, y, u):
        """AuxiliaryParticleFilter.step for every filter (y not all NaN)."""
        model = self.model
        count, n = len(self.filters), self.n
        mu = self.x
        ymu = model.observe(mu, u, self.theta)
        y_mean, y_spread = self._moments(np.ascontiguousarray(self._stacked(ymu)), self.w)
        centre = np.matmul(np.ascontiguousarray(self._stacked(mu)), self.w[:, :, None])[:, :, 0]
        predictive = model.predictive_std(np.ascontiguousarray(centre.T), u, self.theta)
        y_std = np.sqrt(y_spread * y_spread + predictive ** 2)
        first = self._loglik(y, ymu, predictive)
        del ymu
        broken = np.isnan(first)
        if broken.any():
            first[broken & np.isfinite(mu).all(axis=0).reshape(count, n)] = -np.inf
        stage1 = self.logw + first
        recovered = ~np.isfinite(stage1.max(axis=1))
        for f in np.flatnonzero(recovered):  # every first-stage weight underflowed: a plain GPF step
            first[f] = 0.0
            stage1[f] = self.logw[f]
            self.filters[f].recoveries += 1
        w1 = self._normalised(stage1)[1]
        counts = self._offspring(w1, np.ones(count, bool))
        self.x = np.repeat(mu, counts, axis=1)  # the filters' views follow in _finish
        self._perturb(self.x)
        yhat = model.observe(self.x, u, self.theta)
        back = np.repeat(first.reshape(-1), counts).reshape(count, n)
        np.negative(back, out=back)
        logw = self._loglik(y, yhat, model.MEASUREMENT_STD)
        logw += back
        return self._finish(logw, y_mean, y_std, recovered)

    def _normalised(self, logw):
        """_normalise of each row of ``logw`` (in place): (logw, w, ess)."""
        top = logw.max(axis=1)
        w = np.subtract(logw, top[:, None])
        np.exp(w, out=w)
        s = w.sum(axis=1)
        w /= s[:, None]
        ess = 1.0 / np.matmul(w[:, None, :], w[:, :, None])[:, 0, 0]
        logw -= (top + np.log(s))[:, None]
        return logw, w, ess

    def _offspring(self, w, rows):
        """Flat (F * N,) offspring counts: each filter of ``rows`` resampled
        from its weights ``w`` (F, N) as :func:`offspring_counts` does (one
        uniform from its own generator), the others kept (1 each)."""
        n = self.n
        counts = np.ones((len(self.filters), n), dtype=np.intp)
        picked = np.flatnonzero(rows)
        if picked.size == 0:
            return counts.reshape(-1)
        c = np.cumsum(w[picked], axis=1)
        c *= n / c[:, -1:]
        c -= np.array([self.filters[f].rng.random() for f in picked])[:, None]
        np.floor(c, out=c)
        np.minimum(c, n - 1, out=c)
        c[:, -1] = n - 1
        c[:, 1:] -= c[:, :-1].copy()
        c[:, 0] += 1.0
        counts[picked] = c
        return counts.reshape(-1)

    def _finish(self, logw, y_mean, y_std, recovered):
        """_Filter._finish for every filter; a step in which some filter's
        weights are all impossible or not numbers is finished filter by filter."""
        count, n = len(self.filters), self.n
        top = logw.max(axis=1)
        if not np.isfinite(top).all():
            self.packed = False
            results = []
            for f, pf in enumerate(self.filters):
                self._view(f, pf)  # its particles of this step
                pf.logw = logw[f].copy()
                results.append(pf._finish(pf.logw, y_mean[f], y_std[f], bool(recovered[f])))
            return results
        logw, w, ess = self._normalised(logw)
        resampled = ess < self.threshold
        if resampled.any():
            self.x = np.repeat(self.x, self._offspring(w, resampled), axis=1)
            logw[resampled] = -np.log(n)
            w[resampled] = 1.0 / n
        self.logw, self.w = logw, w
        for f, pf in enumerate(self.filters):
            self._view(f, pf)
        mean, std = self._moments(np.ascontiguousarray(self._stacked(self.x)), w)
        return [StepResult(mean[f], std[f], y_mean[f], y_std[f], float(ess[f]), bool(resampled[f]),
                           bool(recovered[f])) for f in range(count)]
