"""The baselines of `simulate_sweep.py`: what a SciPy, NumPy or numba user would write.

Each solves the Bouc–Wen brake of `jaxmr.sas_brake_bouc_wen()` (its numbers are written
out below; `simulate_sweep.check_preset_numbers` fails if the preset moves) under sine
rotations θ(t) = a sin(2π f t) [rad], and returns the torque [N·m] at the output times
`ts` [s]. None imports JAX, so that the NumPy/numba timings carry no JAX overhead.

Two forms of each:

- *shared* (`amp`, `freq` per motion, all `currents` [A]): z is solved once per motion
  and the torque evaluated at every current, -> (motions, currents, times). This is the
  work `jaxmr.sweep`'s shared-state path does: the current acts only on the output gains
  α(i), c0(i), so z does not depend on it.
- *per run* (`amp`, `freq`, `current` per run): one solve per (motion, current) pair,
  -> (runs, times).

The numba kernels need numba (`pip install -e .[bench]`); `numba_kernel()` compiles
one and says how long that took.
"""

import math
import time

import numpy as np
from scipy.integrate import solve_ivp

# The preset's numbers: alpha(i) = ALPHA_A + ALPHA_B i [N·m], c0(i) = C0_A + C0_B i
# [N·m·s/rad]; dz/dt = δ v - γ |v| sign(z) |z|^n - β v |z|^n, v = dθ/dt [rad/s].
ALPHA_A, ALPHA_B = 1.0, 0.07
C0_A, C0_B = 0.0015, 0.07
DELTA, BETA, GAMMA, N_EXP = 843.0, 737.0, 1.0, 0.9


def _gains(currents):
    """(alpha, c0) at `currents` [A], as arrays."""
    currents = np.asarray(currents, dtype=float)
    return ALPHA_A + ALPHA_B * currents, C0_A + C0_B * currents


def _rate(z, v):
    """dz/dt [1/s] at state z and angular velocity v [rad/s] (NumPy, any shape)."""
    p = np.abs(z) ** N_EXP
    return DELTA * v - GAMMA * np.abs(v) * np.sign(z) * p - BETA * v * p


def _shared_torque(z, v, currents):
    """Torque (motions, currents, times) from z, v of shape (motions, times)."""
    alpha, c0 = _gains(currents)
    return alpha[None, :, None] * z[:, None, :] + c0[None, :, None] * v[:, None, :]


# ---------------------------------------------------------------------------------------
# SciPy, one run at a time: a plain-Python right-hand side (the old baseline).


def scipy_loop_torque(a, f, i, ts, method, rtol):
    """One run: `solve_ivp` with a scalar Python right-hand side -> (torque, nfev)."""
    w = 2 * math.pi * f
    aw = a * w

    def rhs(t, y):
        z = y[0]
        v = aw * math.cos(w * t)
        p = abs(z) ** N_EXP
        return [DELTA * v - GAMMA * abs(v) * math.copysign(p, z) - BETA * v * p]

    sol = solve_ivp(
        rhs,
        (float(ts[0]), float(ts[-1])),
        [0.0],
        method=method,
        t_eval=ts,
        rtol=rtol,
        atol=rtol * 1e-2,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} rtol={rtol}: {sol.message}")
    alpha, c0 = _gains(i)
    return alpha * sol.y[0] + c0 * aw * np.cos(w * ts), sol.nfev


# ---------------------------------------------------------------------------------------
# SciPy, vectorised: one `solve_ivp` over the whole batch, NumPy right-hand side.


def _solve_ivp_batch(amp, freq, ts, method, rtol):
    """z (batch, times) and v (batch, times) from one `solve_ivp` over the batch, and
    the number of right-hand-side calls. The step is the batch's (scipy's error norm is
    the RMS over the components), so every run gets the steps of the hardest ones."""
    w = 2 * np.pi * np.asarray(freq, dtype=float)
    aw = np.asarray(amp, dtype=float) * w

    def rhs(t, z):
        return _rate(z, aw * np.cos(w * t))

    sol = solve_ivp(
        rhs,
        (float(ts[0]), float(ts[-1])),
        np.zeros(w.shape),
        method=method,
        t_eval=ts,
        rtol=rtol,
        atol=rtol * 1e-2,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} rtol={rtol}: {sol.message}")
    return sol.y, aw[:, None] * np.cos(w[:, None] * ts[None, :]), sol.nfev


def solve_ivp_shared(amp, freq, currents, ts, method, rtol):
    """z per motion in one `solve_ivp`, torque at every current -> (torque, nfev)."""
    z, v, nfev = _solve_ivp_batch(amp, freq, ts, method, rtol)
    return _shared_torque(z, v, currents), nfev


def solve_ivp_runs(amp, freq, current, ts, method, rtol):
    """One `solve_ivp` over every run -> (torque (runs, times), nfev)."""
    z, v, nfev = _solve_ivp_batch(amp, freq, ts, method, rtol)
    alpha, c0 = _gains(current)
    return alpha[:, None] * z + c0[:, None] * v, nfev


# ---------------------------------------------------------------------------------------
# NumPy, vectorised fixed-step RK4 over the whole batch: a Python loop over the steps.


def _rate_at(z, terms, m):
    """dz/dt [1/s] at the m-th half step, from the velocity terms (δ v, γ |v|, β v)
    (half steps, batch): δ v - γ |v| sign(z) |z|^n - β v |z|^n."""
    dv, gv, bv = terms
    p = np.abs(z) ** N_EXP
    return dv[m] - (gv[m] * np.copysign(p, z) + bv[m] * p)


def _numpy_rk4_batch(amp, freq, ts, substeps):
    """z, v (batch, times): classical RK4, `substeps` steps per output interval (as
    `jaxmr.FixedStep`), each stage one set of NumPy operations over the batch.

    Written for speed as a NumPy user would: the velocity terms of the rate at every
    half step of an output interval come from one operation per interval, and the rate
    is factored to the fewest array operations (about 25 % faster than the textbook
    form, same result to 1e-12 of it). Its cost is per NumPy call, not per element
    (32 lanes took 91 % of 64 lanes' time; in-place `out=` operations gained nothing):
    splitting the batch over processes would not use a second core to any gain.
    """
    w = 2 * np.pi * np.asarray(freq, dtype=float)
    aw = np.asarray(amp, dtype=float) * w
    n_t = len(ts)
    z = np.zeros(w.shape)
    zs = np.empty((n_t,) + w.shape)
    zs[0] = z
    half_steps = np.arange(2 * substeps + 1) / (2 * substeps)  # fractions of dt
    for j in range(n_t - 1):
        t0 = ts[j]
        dt = ts[j + 1] - t0
        h = dt / substeps
        v = aw * np.cos(w * (t0 + dt * half_steps)[:, None])  # (half steps, batch)
        terms = DELTA * v, GAMMA * np.abs(v), BETA * v
        for k in range(substeps):
            k1 = _rate_at(z, terms, 2 * k)
            k2 = _rate_at(z + 0.5 * h * k1, terms, 2 * k + 1)
            k3 = _rate_at(z + 0.5 * h * k2, terms, 2 * k + 1)
            k4 = _rate_at(z + h * k3, terms, 2 * k + 2)
            z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        zs[j + 1] = z
    v = aw[:, None] * np.cos(w[:, None] * ts[None, :])
    return zs.T, v


def numpy_rk4_shared(amp, freq, currents, ts, substeps):
    """z per motion, torque at every current -> (motions, currents, times)."""
    z, v = _numpy_rk4_batch(amp, freq, ts, substeps)
    return _shared_torque(z, v, currents)


def numpy_rk4_runs(amp, freq, current, ts, substeps):
    """One RK4 solve per run -> (runs, times)."""
    z, v = _numpy_rk4_batch(amp, freq, ts, substeps)
    alpha, c0 = _gains(current)
    return alpha[:, None] * z + c0[:, None] * v


# ---------------------------------------------------------------------------------------
# numba: an RK4 loop per run, compiled, parallel over the runs (prange).


def numba_warm_up(threads: int) -> float:
    """Compile and run a trivial parallel numba function -> seconds. numba's one-time
    costs in a process (its compiler pipeline, the threading layer) then fall here and
    not on the first kernel, as JAX's do on the benchmark's earlier solves."""
    import numba

    numba.set_num_threads(threads)
    t0 = time.perf_counter()

    @numba.njit(parallel=True, cache=False)
    def total(x):
        s = 0.0
        for i in numba.prange(x.shape[0]):
            s += math.cos(x[i]) ** 0.5
        return s

    total(np.ones(64))
    return time.perf_counter() - t0


def numba_kernel(shared: bool, threads: int):
    """Compile a numba kernel -> (kernel, compile seconds).

    `shared`: `kernel(amp, freq, currents, ts, substeps)` -> (motions, currents, times),
    z once per motion, parallel over motions. Otherwise `kernel(amp, freq, current, ts,
    substeps)` -> (runs, times), parallel over runs. Classical RK4, `substeps` steps per
    output interval, as `jaxmr.FixedStep`. Compiled here, eagerly from its signature
    (C-contiguous float64 arrays, int64 substeps), each call of this function afresh
    (its helpers too), and that time is the second value; `threads` numba threads run
    it. No `fastmath`: it changed the run time by less than the noise here and would
    let the compiler reorder the arithmetic the accuracy check was made on.
    """
    import numba

    numba.set_num_threads(threads)
    t0 = time.perf_counter()

    @numba.njit(inline="always", cache=False)
    def rate(z, v):
        p = abs(z) ** N_EXP
        return DELTA * v - GAMMA * abs(v) * math.copysign(p, z) - BETA * v * p

    @numba.njit(inline="always", cache=False)
    def solve(a, f, ts, substeps, zs):
        # z [-] at the output times into zs; the velocity at a step's end is reused at
        # the next step's start.
        w = 2 * math.pi * f
        aw = a * w
        z = 0.0
        zs[0] = z
        v0 = aw * math.cos(w * ts[0])
        for j in range(ts.shape[0] - 1):
            t0 = ts[j]
            h = (ts[j + 1] - t0) / substeps
            for k in range(substeps):
                t = t0 + k * h
                v_mid = aw * math.cos(w * (t + 0.5 * h))
                v1 = aw * math.cos(w * (t + h))
                k1 = rate(z, v0)
                k2 = rate(z + 0.5 * h * k1, v_mid)
                k3 = rate(z + 0.5 * h * k2, v_mid)
                k4 = rate(z + h * k3, v1)
                z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
                v0 = v1
            zs[j + 1] = z

    arr = numba.float64[::1]
    if shared:

        @numba.njit(numba.float64[:, :, ::1](arr, arr, arr, arr, numba.int64),
                    parallel=True, cache=False)  # fmt: skip
        def kernel(amp, freq, currents, ts, substeps):
            n_t = ts.shape[0]
            out = np.empty((amp.shape[0], currents.shape[0], n_t))
            for m in numba.prange(amp.shape[0]):
                zs = np.empty(n_t)
                solve(amp[m], freq[m], ts, substeps, zs)
                w = 2 * math.pi * freq[m]
                aw = amp[m] * w
                vs = np.empty(n_t)
                for j in range(n_t):
                    vs[j] = aw * math.cos(w * ts[j])
                for c in range(currents.shape[0]):
                    alpha = ALPHA_A + ALPHA_B * currents[c]
                    c0 = C0_A + C0_B * currents[c]
                    for j in range(n_t):
                        out[m, c, j] = alpha * zs[j] + c0 * vs[j]
            return out

    else:

        @numba.njit(numba.float64[:, ::1](arr, arr, arr, arr, numba.int64),
                    parallel=True, cache=False)  # fmt: skip
        def kernel(amp, freq, current, ts, substeps):
            n_t = ts.shape[0]
            out = np.empty((amp.shape[0], n_t))
            for r in numba.prange(amp.shape[0]):
                solve(amp[r], freq[r], ts, substeps, out[r])
                w = 2 * math.pi * freq[r]
                aw = amp[r] * w
                alpha = ALPHA_A + ALPHA_B * current[r]
                c0 = C0_A + C0_B * current[r]
                for j in range(n_t):
                    out[r, j] = alpha * out[r, j] + c0 * aw * math.cos(w * ts[j])
            return out

    return kernel, time.perf_counter() - t0
