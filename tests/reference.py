"""Naive reference implementations, written straight from the paper's equations.

Nothing here shares code with box_core: each fold refits mu and Sigma from the n - 1
training rows, and every BOX step solves eq. 2 afresh with numpy.linalg.solve.  The tests
compare box_core against these; benchmarks/bench_loocv.py times them as the baseline.

Conventions shared with box_core (they are part of its documented contract, not its code):
the diagonal jitter 1e-8 * max(diag Sigma), ties within 1e-9 of the best go to the lowest
index, and fold i of a seeded evaluation draws from numpy.random.default_rng((seed, i)).
"""

from __future__ import annotations

import math

import numpy as np

JITTER = 1e-8
TIE = 1e-9


def fit(D):
    mu = D.mean(axis=0)
    X = D - mu
    return mu, X.T @ X / (D.shape[0] - 1)


def pick(values, tried, scale):
    """Lowest untried index among those within the tie tolerance of the best."""
    values = np.where(tried, -np.inf, np.asarray(values, dtype=float))
    best = values.max()
    tol = TIE * max(abs(best), scale)
    return int(np.flatnonzero(values >= best - tol)[0])


def posterior(mu, S, tried_idx, observed):
    """Eq. 2 by direct solves: posterior mean and variance of every column."""
    jitter = JITTER * (S.diagonal().max() if S.diagonal().max() > 0 else 1.0)
    if not tried_idx:
        return mu.copy(), S.diagonal().copy()
    tried = list(tried_idx)
    K = S[np.ix_(tried, tried)] + jitter * np.eye(len(tried))
    cross = S[tried, :]  # t x m
    mean = mu + cross.T @ np.linalg.solve(K, np.asarray(observed) - mu[tried])
    var = S.diagonal() - np.einsum("tm,tm->m", cross, np.linalg.solve(K, cross))
    return mean, var


def ucb_order(mu, S, truth, k, coef):
    """BOX-style order; ``coef(t)`` returns (UCB coefficient, variance factor) at t tries."""
    m = mu.size
    tried = np.zeros(m, dtype=bool)
    idx, obs = [], []
    scale = math.sqrt(max(S.diagonal().max(), 0.0))
    for t in range(k):
        mean, var = posterior(mu, S, idx, obs)
        c, factor = coef(t)
        ucb = mean + c * np.sqrt(factor * np.maximum(var, 0.0))
        j = pick(ucb, tried, scale)
        tried[j] = True
        idx.append(j)
        obs.append(truth[j])
    return idx


def box_order(train, truth, k, c=1.96):
    mu, S = fit(train)
    return ucb_order(mu, S, truth, k, lambda t: (c, 1.0))


def pembo_zeta(t, N, delta=0.01):
    """PEM-BO's zeta_t as the authors' AutomaticZetaUCB computes it, with box_core's
    documented continuation (N - t - 1 held at the smallest value where it is defined)."""
    L6 = math.log(6 / delta)
    r_min = 2
    while 2 * math.sqrt(L6 / r_min) >= 1:
        r_min += 1
    r = max(N - t - 1, r_min)
    iota = math.sqrt(6 * (N - 2 + t + 2 * math.sqrt(t * L6) + 2 * L6) / (delta * N * (r - 1)))
    b = L6 / r
    return (iota + math.sqrt(2 * math.log(3 / delta))) / math.sqrt(1 - 2 * math.sqrt(b))


def pembo_order(train, truth, k, delta=0.01):
    mu, S = fit(train)
    N = train.shape[0]

    def coef(t):  # t observations so far
        return pembo_zeta(t, N, delta), (N - 1) / max(N - t - 1, 1)

    return ucb_order(mu, S, truth, k, coef)


def pembo_compounded_order(train, truth, k, delta=0.01):
    """PEM-BO as the authors' discrete-domain code runs it: each observation conditions the
    previous step's mean and (already scaled) covariance on one column, and the covariance
    is then scaled again by (N - 1) / (N - t - 1), t the observations so far."""
    mu, S = fit(train)
    N, m = train.shape
    jitter = JITTER * (S.diagonal().max() if S.diagonal().max() > 0 else 1.0)
    mean, cov = mu.copy(), S.copy()
    tried = np.zeros(m, dtype=bool)
    scale = math.sqrt(max(S.diagonal().max(), 0.0))
    idx = []
    for t in range(k):
        ucb = mean + pembo_zeta(t, N, delta) * np.sqrt(np.maximum(cov.diagonal(), 0.0))
        j = pick(ucb, tried, scale)
        tried[j] = True
        idx.append(j)
        gain = cov[:, j] / (cov[j, j] + jitter)
        mean = mean + gain * (truth[j] - mean[j])
        cov = (cov - np.outer(gain, cov[j, :])) * ((N - 1) / max(N - (t + 1) - 1, 1))
    return idx


def static_order(train, k):
    mu = train.mean(axis=0)
    return sorted(range(mu.size), key=lambda j: (-mu[j], j))[:k]


def rand_order(m, k, seed):
    return list(np.random.default_rng(seed).permutation(m)[:k])


def doo_order(truth, features, k, seed, lam=1.0, unit=1.0):
    """DOO; scores are divided by ``unit`` first (box_core: the largest |score| of the
    matrix it was given), so ``lam`` is in that unit."""
    truth = np.asarray(truth) / unit
    m = truth.size
    tried, idx = np.zeros(m, dtype=bool), []
    dist = np.linalg.norm(features[None, :, :] - features[:, None, :], axis=2)
    j = int(np.random.default_rng(seed).integers(m))
    for _ in range(k):
        tried[j] = True
        idx.append(j)
        if len(idx) == k:
            break
        bound = (truth[idx][:, None] + lam * dist[idx]).min(axis=0)  # recomputed from scratch
        scale = np.abs(truth[idx]).max()
        j = pick(bound, tried, scale)
    return idx


def oracle_order(truth, k):
    return sorted(range(truth.size), key=lambda j: (-truth[j], j))[:k]


def loocv_orders(D, name, k, seed=0, features=None, **params):
    """Order of selector ``name`` for every held-out row, refitting each fold."""
    n, m = D.shape
    out = []
    for i in range(n):
        train, truth = np.delete(D, i, axis=0), D[i]
        if name == "box":
            out.append(box_order(train, truth, k, **params))
        elif name == "pembo":
            out.append(pembo_order(train, truth, k, **params))
        elif name == "pembo_compounded":
            out.append(pembo_compounded_order(train, truth, k, **params))
        elif name == "static":
            out.append(static_order(train, k))
        elif name == "rand":
            out.append(rand_order(m, k, (seed, i)))
        elif name == "doo":
            out.append(doo_order(truth, features, k, (seed, i), unit=np.abs(D).max(), **params))
        elif name == "oracle":
            out.append(oracle_order(truth, k))
        else:
            raise ValueError(name)
    return np.array(out)


def eips_order(train, feasible, times, truth, k, prior_rows=1.0, mismatch=0.1, time_rows=5.0):
    """EIPS recomputed from scratch at every step: row weights from the whole history,
    the frequency p, the weighted outcome-split geometric mean times, and eq. 2 by direct
    solves for the expected improvement."""
    mu, S = fit(train)
    oks, fails = train[feasible], train[~feasible]
    if not oks.size or not fails.size:  # everything fails / nothing fails
        threshold = math.inf if not oks.size else -math.inf
    else:
        threshold = 0.5 * (fails.max() + oks.min())
    n, m = train.shape
    tried = np.zeros(m, dtype=bool)
    idx, obs = [], []
    pbar = feasible.mean(axis=0)
    logt = np.log(np.maximum(times, 1e-6))
    g_ok, g_fail = np.empty(m), np.empty(m)
    for j in range(m):
        ok, fail = logt[feasible[:, j], j], logt[~feasible[:, j], j]
        g_ok[j] = ok.mean() if ok.size else logt[:, j].mean()
        g_fail[j] = fail.mean() if fail.size else logt[:, j].mean()
    for _ in range(k):
        w = np.ones(n)
        for j, y in zip(idx, obs, strict=True):
            w[feasible[:, j] != (y > threshold)] *= mismatch
        p = (w @ feasible + prior_rows * pbar) / (w.sum() + prior_rows)
        wf, wg = w[:, None] * feasible, w[:, None] * ~feasible
        t_ok = np.exp(((wf * logt).sum(axis=0) + time_rows * g_ok) / (wf.sum(axis=0) + time_rows))
        t_fail = np.exp(((wg * logt).sum(axis=0) + time_rows * g_fail)
                        / (wg.sum(axis=0) + time_rows))
        tau = p * t_ok + (1 - p) * t_fail
        found = [y for y in obs if y > threshold]
        if found:
            mean, var = posterior(mu, S, idx, obs)
            s = np.sqrt(np.maximum(var, 0.0))
            best = max(found)
            gain = np.empty(m)
            for j in range(m):
                z = (mean[j] - best) / s[j] if s[j] > 0 else math.inf
                if z <= -30:  # box_core's documented cut-off
                    gain[j] = 0.0
                elif z < 30:
                    gain[j] = s[j] * (z * 0.5 * math.erfc(-z / math.sqrt(2))
                                      + math.exp(-z * z / 2) / math.sqrt(2 * math.pi))
                else:
                    gain[j] = max(mean[j] - best, 0.0)
        else:
            gain = p
        j = pick(gain / np.maximum(tau, 1e-12), tried, 0.0)
        tried[j] = True
        idx.append(j)
        obs.append(truth[j])
    return idx


class BatchedPosterior:
    """box_core's batched incremental conditioning as it was before the leave-one-out fast
    path (``box_core.gaussian.GaussianPosterior`` at commit 6c488f3), kept verbatim: every
    observation runs the full O(t m) update over all m columns, for every instance.  The
    tests compare the current posterior with it bit for bit."""

    def __init__(self, prior, capacity=16):
        self.prior = prior
        size, m = prior.size, prior.m
        self.mean = prior.mean.copy()
        self.prior_var = prior.diag()
        self.var = self.prior_var.copy()
        self.eps = prior.jitter()
        self.scale = np.sqrt(np.maximum(self.prior_var.max(axis=1), 0.0))
        self.t = 0
        self._W = np.empty((size, max(1, capacity), m))
        self._alpha = np.empty((size, max(1, capacity)))
        self._rows = np.arange(size)

    def observe(self, cols, scores):
        t = self.t
        if t == self._W.shape[1]:
            size, cap, m = self._W.shape
            W = np.empty((size, 2 * cap, m))
            W[:, :cap] = self._W
            alpha = np.empty((size, 2 * cap))
            alpha[:, :cap] = self._alpha
            self._W, self._alpha = W, alpha
        rows = self._rows
        W = self._W[:, :t, :]
        alpha = self._alpha[:, :t]
        lw = W[rows, :, cols]
        cross = self.prior.cov_rows(cols)
        if t:
            cross -= np.matmul(lw[:, None, :], W)[:, 0, :]
        schur = self.prior_var[rows, cols] + self.eps - np.einsum("bt,bt->b", lw, lw)
        delta = np.sqrt(np.maximum(schur, self.eps))
        w = cross / delta[:, None]
        resid = scores - self.prior.mean[rows, cols] - np.einsum("bt,bt->b", lw, alpha)
        a = resid / delta
        self._W[:, t, :] = w
        self._alpha[:, t] = a
        self.mean += a[:, None] * w
        self.var -= w * w
        self.t = t + 1


def argmax_sequence(values, tried, scale, steps):
    """What ``steps`` calls of the tie-tolerant argmax pick from fixed ``values`` (B, m),
    marking each pick tried: one :func:`pick` per step and row."""
    out = []
    for b in range(values.shape[0]):
        mask = tried[b].copy()
        row = []
        for _ in range(steps):
            j = pick(values[b], mask, scale[b])
            mask[j] = True
            row.append(j)
        out.append(row)
    return np.array(out, dtype=np.intp).reshape(values.shape[0], steps)


def contextual_tries(train, feasible, times, checks, X, x, truth, truth_feasible,
                     truth_times, truth_checks, ends, k, mismatch=0.1, prior_rows=1.0,
                     c=1.96, cap=math.inf):
    """CONTEXTUAL's tries on one instance, recomputed from scratch at every step.

    ``train`` (n, m) scores (internal unit), ``feasible``, ``times``, ``checks`` (None: no
    caps) and instance features ``X`` of the training rows; ``x`` the instance's features
    (None: BOX); ``truth*`` its own row.  Returns [(column, allowance, cost, outcome)]
    with outcome 0 failed, 1 plan, 2 paused, until ``ends`` tries have ended (or every
    column has)."""
    n, m = train.shape
    mu, S = fit(train)
    scale = math.sqrt(max(S.diagonal().max(), 0.0))
    if checks is None:
        cap = math.inf
    if x is not None:
        sd = X.std(axis=0)
        z = np.zeros(n)
        for f in range(X.shape[1]):
            if sd[f] > 0:
                z += ((x[f] - X[:, f]) / sd[f]) ** 2
        nb = sorted(range(n), key=lambda r: (z[r], r))[:k]
    state = {j: "fresh" for j in range(m)}  # fresh / paused / ended
    granted = np.zeros(m)
    idx, obs, out = [], [], []
    # class of a training entry: 0 fails within the cap, 1 plans within, 2 plans after,
    # 3 fails after
    cls = np.zeros((n, m), dtype=int)
    share = np.ones((n, m))
    for r in range(n):
        for j in range(m):
            within = checks is None or checks[r, j] <= cap
            cls[r, j] = (1 if feasible[r, j] else 0) if within else (2 if feasible[r, j] else 3)
            if not within:
                share[r, j] = cap / checks[r, j]
    history = []  # (column, outcome, resumed) before the first plan
    found = False
    while sum(s == "ended" for s in state.values()) < min(ends, m):
        mean, var = posterior(mu, S, idx, obs)
        box = mean + c * np.sqrt(np.maximum(var, 0.0))
        choice = None
        if x is not None and not found:
            w = {r: 1.0 for r in nb}
            for j, o, resumed in history:
                for r in nb:
                    planned = cls[r, j] in (1, 2)
                    if o == 2:
                        differs = cls[r, j] == 1
                    else:
                        differs = (not planned) if o == 1 else planned
                        if resumed:
                            differs = differs and cls[r, j] != 1
                    if differs:
                        w[r] *= mismatch
            M = sum(w.values())
            rates = []
            for j in range(m):
                if state[j] != "fresh":
                    rates.append(-math.inf)
                    continue
                ok = sum(w[r] * (cls[r, j] == 1) for r in nb)
                cost = sum(w[r] * times[r, j] * share[r, j] for r in nb)
                p = (ok + prior_rows * np.mean(cls[:, j] == 1)) / (M + prior_rows)
                tau = (cost + prior_rows * np.mean(times[:, j] * share[:, j])) / (M + prior_rows)
                rates.append(p / max(tau, 1e-6))
            for j in range(m):  # a first try without the cap
                rate = -math.inf
                if state[j] == "fresh" and math.isfinite(cap):
                    ok = sum(w[r] * (cls[r, j] in (1, 2)) for r in nb)
                    cost = sum(w[r] * times[r, j] for r in nb)
                    p = (ok + prior_rows * np.mean((cls[:, j] == 1) | (cls[:, j] == 2))) / (
                        M + prior_rows)
                    tau = (cost + prior_rows * np.mean(times[:, j])) / (M + prior_rows)
                    rate = p / max(tau, 1e-6)
                rates.append(rate)
            for j in range(m):
                rate = -math.inf
                if state[j] == "paused":
                    ok = sum(w[r] * (cls[r, j] == 2) for r in nb) + prior_rows * np.mean(
                        cls[:, j] == 2)
                    mass = ok + sum(w[r] * (cls[r, j] == 3) for r in nb) + prior_rows * \
                        np.mean(cls[:, j] == 3)
                    rest = sum(w[r] * times[r, j] * (1 - share[r, j]) for r in nb) + \
                        prior_rows * np.mean(times[:, j] * (1 - share[:, j]))
                    rate = ok / mass / max(rest / mass, 1e-6) if mass > 0 else 0.0
                rates.append(rate)
            best = int(np.argmax(rates))
            if rates[best] > 0:  # capped first try, uncapped first try, or resumed
                choice = (best % m, cap if best < m else math.inf)
        if choice is None:
            fresh = [s == "fresh" for s in state.values()]
            if not found and any(fresh):
                j = pick(box, ~np.array(fresh), scale)
                choice = (j, cap if x is not None else math.inf)
            else:
                j = pick(box, np.array([s == "ended" for s in state.values()]), scale)
                choice = (j, math.inf)
        j, allow = choice
        resumed = state[j] == "paused"
        need = math.inf if truth_checks is None else truth_checks[j]
        if truth_checks is None or need <= allow:
            outcome = 1 if truth_feasible[j] else 0
            done = need if truth_checks is not None else 0
            cost = truth_times[j] * ((done - granted[j]) / need if need > 0 else 1.0) \
                if truth_checks is not None else truth_times[j]
            state[j] = "ended"
            idx.append(j)
            obs.append(truth[j])
        else:
            outcome = 2
            cost = truth_times[j] * (allow - granted[j]) / need
            state[j] = "paused"
        granted[j] = allow
        out.append((j, allow, cost, outcome))
        if not found:
            history.append((j, outcome, resumed))
        found = found or outcome == 1
    return out
