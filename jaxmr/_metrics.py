r"""Evaluation metrics of simulated or measured time histories: comfort (RMS, ISO 2631-1
Wk-weighted RMS, VDV, crest factor), settling, dissipated energy and control effort.

All are pure JAX functions of arrays: jit-able, vmap-able and differentiable (square
and fourth roots are guarded so that a zero signal has a zero, not NaN, gradient).
Signals are sampled uniformly along their last axis unless times are passed; leading
axes are batch axes (several runs), and the result has those axes.
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, ArrayLike, Float, ScalarLike
from ._misc import as_float_array, check_concrete, default_float, is_concrete

TWO_PI = 2 * math.pi  # a Python float: weakly typed under strict promotion

# ---------------------------------------------------------------------------------------
# Arguments


def _samples(x, name: str) -> Array:
    """`x` as a float array with at least one sample on its last axis. A metric of no
    samples is no number (NumPy's mean gives NaN, its max an error, a sum 0), and a
    solution passed for one of its signals is named, not "setting an array element
    with a sequence"."""
    if isinstance(x, eqx.Module):
        raise TypeError(
            f"`{name}` must be an array of samples, got a {type(x).__name__}: pass "
            "one of its signals (e.g. `sol.current`, `sol.body_acceleration`)."
        )
    x = as_float_array(x)
    if x.ndim == 0 or x.shape[-1] == 0:
        raise ValueError(
            f"`{name}` must have at least one sample on its last axis, got shape "
            f"{x.shape}."
        )
    return x


def _positive_step(dt) -> None:
    if is_concrete(dt) and not bool(np.all(np.asarray(dt) > 0)):
        raise ValueError(f"`dt` must be > 0 s (the sampling interval), got {dt!r}.")


# ---------------------------------------------------------------------------------------
# Small guarded roots


def _safe_root(x, p):
    r"""$x^{1/p}$ for $x \ge 0$ with a zero (not infinite) derivative at $x = 0$; NaN
    stays NaN (a diverged run must not score 0)."""
    positive = x > 0
    root = jnp.where(positive, x, 1.0) ** (1.0 / p)
    return jnp.where(positive, root, jnp.where(jnp.isnan(x), x, 0.0))


def rms(x: Float[ArrayLike, "*batch samples"]) -> Float[Array, "*batch"]:
    r"""Root mean square over the last axis, $\sqrt{\tfrac{1}{N}\sum_k x_k^2}$, in the
    unit of $x$ (e.g. body acceleration [m/s²], suspension travel [m]).

    **Arguments:**

    - `x`: uniformly sampled values; leading axes are kept.
    """
    x = _samples(x, "x")
    return _safe_root(jnp.mean(x**2, axis=-1), 2)


def peak(x: Float[ArrayLike, "*batch samples"]) -> Float[Array, "*batch"]:
    r"""Peak magnitude $\max_k |x_k|$ over the last axis, in the unit of $x$."""
    return jnp.max(jnp.abs(_samples(x, "x")), axis=-1)


def crest_factor(x: Float[ArrayLike, "*batch samples"]) -> Float[Array, "*batch"]:
    r"""Crest factor $\max_k |x_k| / \mathrm{rms}(x)$ (dimensionless; $\sqrt 2$ for a
    sine). ISO 2631-1 computes it on the Wk-weighted acceleration (`wk_weighted`) and
    asks for the VDV as well when it exceeds 9.

    **Arguments:**

    - `x`: uniformly sampled values, not all zero.
    """
    return peak(x) / rms(x)


def mean_current(current: Float[ArrayLike, "*batch samples"]) -> Float[Array, "*batch"]:
    r"""Mean commanded current $\tfrac{1}{N}\sum_k i_k$ [A] over uniformly sampled
    commands (control effort; proportional to the mean coil voltage of a resistive
    coil)."""
    return jnp.mean(_samples(current, "current"), axis=-1)


def rms_current(current: Float[ArrayLike, "*batch samples"]) -> Float[Array, "*batch"]:
    r"""RMS current $\sqrt{\tfrac{1}{N}\sum_k i_k^2}$ [A] over uniformly sampled
    commands: $R\,i_{rms}^2$ is the coil's mean Joule power [W]."""
    return rms(_samples(current, "current"))


def dissipated_energy(
    t: Float[ArrayLike, "*time_batch samples"],
    force: Float[ArrayLike, "*batch samples"],
    velocity: Float[ArrayLike, "*batch samples"],
) -> Float[Array, "*batch"]:
    r"""Energy dissipated by a damper, $E = \int F v\,dt$ [J], by the trapezoidal rule.

    Positive for a passive device with the sign convention $F v \ge 0$ (force opposing
    the motion it resists). For a brake pass torque [N·m] and angular rate [rad/s].

    **Arguments:**

    - `t`: sample times [s], increasing (need not be uniform); 1-D or with the
      batch axes of `force`.
    - `force`: damper force $F$ [N].
    - `velocity`: relative velocity $v$ [m/s] across the damper.
    """
    t, force, velocity = map(as_float_array, (t, force, velocity))
    try:
        shape = jnp.broadcast_shapes(force.shape, velocity.shape)
        ok = t.ndim >= 1 and t.shape[-1:] == shape[-1:]
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(
            "dissipated_energy: `t`, `force` and `velocity` must have the same number "
            f"of samples (last axis); got t {t.shape}, force {force.shape}, "
            f"velocity {velocity.shape}."
        )
    # Decreasing times integrate to the energy with its sign flipped (repeated times
    # add nothing). Checked on the host: an eager `jnp` comparison compiles per shape.
    check_concrete(
        lambda times: np.all(np.diff(times) >= 0),
        "dissipated_energy: `t` must be increasing [s].",
        t,
    )
    power = force * velocity
    return jnp.sum(0.5 * (power[..., 1:] + power[..., :-1]) * jnp.diff(t), axis=-1)


def settling_time(
    t: Float[ArrayLike, " samples"],
    y: Float[ArrayLike, "*batch samples"],
    tolerance: ScalarLike,
    final: ScalarLike = 0.0,
    *,
    interpolate: bool = False,
) -> Float[Array, "*batch"]:
    r"""The time after which $|y - y_\infty| \le \epsilon$ holds to the end of the record.

    Hard version (default): $t_j$ for the first sample $j$ such that every sample from
    $j$ on is within the band. With `interpolate=True` the crossing of the band edge
    between the last sample outside it and the next one is located by linear
    interpolation: more accurate for coarse sampling and differentiable with respect to
    `y`, `tolerance` and `final` (almost everywhere; the hard version is piecewise
    constant in `y`).

    Conventions: a record that starts inside and never leaves the band settles at
    `t[0]`; a record whose last sample is outside the band never settles and gives
    `inf` (so a never-settling run ranks last in comparisons; use `jnp.isinf` to count
    them).

    **Arguments:**

    - `t`: sample times [s], increasing.
    - `y`: the response (e.g. body angle [rad]); leading axes are batch axes.
    - `tolerance`: $\epsilon$ > 0, absolute, in the unit of `y` (for a 2 % criterion
      on a step of size $h$ pass $0.02 |h|$).
    - `final`: $y_\infty$, the settled value (default 0).
    - `interpolate`: see above (default `False`).

    **Returns:** the settling time [s], or `inf`.
    """
    t, y = _samples(t, "t"), _samples(y, "y")
    tolerance, final = as_float_array(tolerance), as_float_array(final)
    if t.ndim != 1 or t.shape[0] != y.shape[-1]:
        raise ValueError(
            f"`t` must be 1-D with one time per sample of `y` (its last axis), got "
            f"shapes {t.shape} and {y.shape}."
        )
    if is_concrete(tolerance) and not bool(jnp.all(tolerance > 0)):
        raise ValueError(f"`tolerance` must be > 0, got {tolerance}.")
    return _settling_time(t, y, tolerance, final, interpolate)


@eqx.filter_jit
def _settling_time(t, y, tolerance, final, interpolate):
    error = jnp.abs(y - final)
    outside = error > tolerance
    n = y.shape[-1]
    # Index of the last sample outside the band (-1 when none).
    last = jnp.where(
        jnp.any(outside, axis=-1),
        n - 1 - jnp.argmax(jnp.flip(outside, axis=-1), axis=-1),
        -1,
    )
    settled = last < n - 1
    j = jnp.clip(last + 1, 0, n - 1)
    time = t[j]
    if interpolate:
        i = jnp.clip(last, 0, n - 1)
        e0 = jnp.take_along_axis(error, i[..., None], axis=-1)[..., 0]
        e1 = jnp.take_along_axis(error, j[..., None], axis=-1)[..., 0]
        crossing = (last >= 0) & settled
        # Guarded so that the branch not taken has a finite gradient.
        gap = jnp.where(crossing, e0 - e1, 1.0)
        fraction = jnp.where(crossing, (e0 - tolerance) / gap, 0.0)
        time = jnp.where(crossing, t[i] + fraction * (t[j] - t[i]), time)
    return jnp.where(settled, time, jnp.inf)


# ---------------------------------------------------------------------------------------
# ISO 2631-1 frequency weighting Wk (vertical, seated/standing/recumbent)

# Corner frequencies [Hz] and quality factors of ISO 2631-1:1997 Annex A, Wk.
_F1, _F2 = 0.4, 100.0  # band limiting, Butterworth (Q = 1/sqrt 2)
_F3, _F4, _Q4 = 12.5, 12.5, 0.63  # acceleration-velocity transition
_F5, _Q5, _F6, _Q6 = 2.37, 0.91, 3.35, 0.91  # upward step


def wk_response(f: Float[ArrayLike, "*shape"]) -> Array:
    r"""The ISO 2631-1 Wk weighting's analog frequency response $W_k(j 2\pi f)$
    (complex; take `jnp.abs` for the weighting factor, e.g. 1.054 at 6.3 Hz).

    $W_k(s) = H_h H_l H_t H_s$ with $\omega_i = 2\pi f_i$:
    band limiting $H_h = 1/(1 + \sqrt2\,\omega_1/s + (\omega_1/s)^2)$ and
    $H_l = 1/(1 + \sqrt2\,s/\omega_2 + (s/\omega_2)^2)$ ($f_1$ = 0.4 Hz,
    $f_2$ = 100 Hz); acceleration–velocity transition
    $H_t = (1 + s/\omega_3)/(1 + s/(Q_4\omega_4) + (s/\omega_4)^2)$ ($f_3 = f_4$ =
    12.5 Hz, $Q_4$ = 0.63); upward step
    $H_s = \frac{1 + s/(Q_5\omega_5) + (s/\omega_5)^2}{1 + s/(Q_6\omega_6) +
    (s/\omega_6)^2}\,\frac{\omega_5^2}{\omega_6^2}$ ($f_5$ = 2.37 Hz, $Q_5$ = 0.91,
    $f_6$ = 3.35 Hz, $Q_6$ = 0.91).

    **Arguments:**

    - `f`: frequency [Hz].

    **Returns:** complex, the shape of `f`.
    """
    w = TWO_PI * as_float_array(f)
    s = jax.lax.complex(jnp.zeros_like(w), w)
    w1, w2, w3, w4, w5, w6 = (TWO_PI * x for x in (_F1, _F2, _F3, _F4, _F5, _F6))
    high = s**2 / (s**2 + math.sqrt(2) * w1 * s + w1**2)
    low = w2**2 / (s**2 + math.sqrt(2) * w2 * s + w2**2)
    transition = (w4**2 / w3) * (s + w3) / (s**2 + (w4 / _Q4) * s + w4**2)
    step = (s**2 + (w5 / _Q5) * s + w5**2) / (s**2 + (w6 / _Q6) * s + w6**2)
    return high * low * transition * step


def _section(omega, q, b0, b1, b2):
    r"""State space of $(b_0 s^2 + b_1 s + b_2)/(s^2 + (\omega/q) s + \omega^2)$ with
    states scaled by $\omega$ (entries of order $\omega$, output weights of order 1):
    $\dot x_1 = \omega x_2$, $\dot x_2 = -\omega x_1 - (\omega/q) x_2 + \omega u$, so
    $x_1$ is the unit-gain low-pass and $x_2$ the scaled band-pass."""
    a = np.array([[0.0, omega], [-omega, -omega / q]])
    b = np.array([[0.0], [omega]])
    c = np.array([[(b2 - b0 * omega**2) / omega**2, (b1 - b0 * omega / q) / omega]])
    return a, b, c, np.array([[b0]])


def _series(first, second):
    """State space of `second` after `first`."""
    a1, b1, c1, d1 = first
    a2, b2, c2, d2 = second
    n1, n2 = a1.shape[0], a2.shape[0]
    a = np.block([[a1, np.zeros((n1, n2))], [b2 @ c1, a2]])
    return a, np.vstack([b1, b2 @ d1]), np.hstack([d2 @ c1, c2]), d2 @ d1


def _wk_state_space_numpy():
    w1, w2, w3, w4, w5, w6 = (TWO_PI * x for x in (_F1, _F2, _F3, _F4, _F5, _F6))
    q_butter = 1 / np.sqrt(2)
    sections = [
        _section(w1, q_butter, 1.0, 0.0, 0.0),
        _section(w2, q_butter, 0.0, 0.0, w2**2),
        _section(w4, _Q4, 0.0, w4**2 / w3, w4**2),
        _section(w6, _Q6, 1.0, w5 / _Q5, w5**2),
    ]
    system = sections[0]
    for section in sections[1:]:
        system = _series(system, section)
    return system


_WK_A, _WK_B, _WK_C, _WK_D = _wk_state_space_numpy()


def wk_state_space() -> tuple[
    Float[Array, "8 8"], Float[Array, "8 1"], Float[Array, "1 8"], Float[Array, "1 1"]
]:
    r"""A continuous state-space realisation $(A, B, C, D)$ of the Wk weighting,
    $\dot x = A x + B a$, $a_w = C x + D a$ ($D = 0$), 8 states: the four sections of
    `wk_response` in series, each with states scaled by its corner frequency.

    Append it to a simulation's state to weight the body acceleration exactly in
    continuous time (e.g. to integrate $a_w^2$ inside the ODE).
    """
    a, b, c, d = (
        jnp.asarray(m, dtype=default_float()) for m in (_WK_A, _WK_B, _WK_C, _WK_D)
    )
    return a, b, c, d


def _wk_discrete(dt):
    r"""Zero-order-hold discretisation (exact for a piecewise-constant input): $\Phi$,
    $\Gamma$ from $\exp$ of the augmented matrix $[[A, B], [0, 0]]\,\Delta t$."""
    if is_concrete(dt):
        # The usual case, a number: numpy, once per dt, nothing to compile.
        phi, gamma = _zoh_numpy(float(dt))
        return (
            jnp.asarray(phi, default_float()),
            jnp.asarray(gamma, default_float()),
            jnp.asarray(_WK_C[0], default_float()),
        )
    # A traced dt (under jit/vmap/grad): the same algorithm in jax, differentiable in
    # dt. (jax.scipy.linalg.expm would do too but takes seconds to compile.)
    a, b, c, _ = wk_state_space()
    n = a.shape[0]
    augmented = jnp.zeros((n + 1, n + 1), a.dtype)
    augmented = augmented.at[:n, :n].set(a).at[:n, n:].set(b)
    m = _expm_jax(augmented * dt)
    return m[:n, :n], m[:n, n], c[0]


_TAYLOR_DEGREE = 16
_MAX_SQUARINGS = 30  # enough for |A dt| up to 2**29 (dt ~ 1e5 s for Wk)


def _expm_jax(m):
    """Matrix exponential by scaling and squaring (as `_zoh_numpy`), with a traced
    number of squarings applied by masking a fixed-length scan."""
    norm = jnp.max(jnp.sum(jnp.abs(m), axis=0))
    squarings = jnp.clip(
        jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-30) / 0.5)), 0, _MAX_SQUARINGS
    )
    x = m / 2.0**squarings
    eye = jnp.eye(m.shape[0], dtype=m.dtype)
    term, result = eye, eye
    for k in range(1, _TAYLOR_DEGREE + 1):
        term = term @ x / k
        result = result + term

    def square(r, i):
        return jnp.where(i < squarings, r @ r, r), None

    steps = jnp.arange(_MAX_SQUARINGS, dtype=m.dtype)
    return jax.lax.scan(square, result, steps)[0]


@functools.lru_cache(maxsize=32)
def _zoh_numpy(dt: float) -> tuple[np.ndarray, np.ndarray]:
    n = _WK_A.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n:] = _WK_A * dt, _WK_B * dt
    # Scaling and squaring with a degree-16 Taylor polynomial: after scaling the norm
    # is <= 1/2, so the truncation error is < 0.5**17/17! ~ 2e-20 (float64 rounding
    # dominates). 9x9 matrices: no need for Pade's economy.
    norm = np.linalg.norm(m, 1)
    squarings = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0 else 0
    x = m / 2.0**squarings
    term = np.eye(n + 1)
    result = np.eye(n + 1)
    for k in range(1, _TAYLOR_DEGREE + 1):
        term = term @ x / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result[:n, :n], result[:n, n]


def wk_weighted(
    a: Float[ArrayLike, "*batch samples"], dt: ScalarLike
) -> Float[Array, "*batch samples"]:
    r"""Frequency-weight an acceleration by ISO 2631-1 Wk: the weighted acceleration
    $a_w(t_k)$ [m/s²].

    The analog filter (`wk_state_space`) is discretised exactly for a zero-order-hold
    input: $x_{k+1} = \Phi x_k + \Gamma u_k$, $a_{w,k} = C x_k$ with
    $[\Phi\ \Gamma] $ from $\exp(\begin{smallmatrix} A & B \\ 0 & 0 \end{smallmatrix}
    \Delta t)$ (scaling and squaring; in numpy once per `dt` when `dt` is a number, in
    jax when it is traced), run by `lax.scan`: differentiable in `a` (and in a traced
    `dt`). Why not the
    bilinear transform: its frequency warping (even prewarped per section) leaves
    3.3 % gain error at 100 Hz at 1 kHz sampling, whereas the hold's error is only its
    averaging, the droop $\mathrm{sinc}(f \Delta t) \approx 1 - (\pi f \Delta t)^2/6$
    (1.6 % at 100 Hz). That droop is removed by the zero-phase pre-filter
    $u_k = a_k - \tfrac{1}{24}(a_{k+1} - 2 a_k + a_{k-1})$ (gain $1 + (\omega\Delta
    t)^2/24 + …$, ends replicated), after which the gain on a sampled sine matches
    $|W_k(j2\pi f)|$ within 0.1 % up to $f = 0.1/\Delta t$ at 1 kHz (100 Hz), and
    within 0.2 % up to 20 Hz at 250 Hz. The ZOH
    adds half a sample of delay, immaterial for RMS and VDV. Sample at ≥ 1 kHz for the
    whole Wk band (to 100 Hz); ≥ 250 Hz suffices for vehicle comfort (< 20 Hz).

    The filter starts at rest: discard the first few seconds (the 0.4 Hz high-pass
    settles in ~2 s) when the record starts with a non-zero mean or mid-motion.

    **Arguments:**

    - `a`: acceleration [m/s²] sampled every `dt` (last axis); leading axes are batch
      axes.
    - `dt`: sampling interval $\Delta t$ [s].

    **Returns:** $a_w$ [m/s²], the shape of `a`.
    """
    _positive_step(dt)
    phi, gamma, c = _wk_discrete(dt if is_concrete(dt) else as_float_array(dt))
    return _wk_weighted(_samples(a, "a"), phi, gamma, c)


@eqx.filter_jit
def _wk_weighted(a, phi, gamma, c):
    padded = jnp.concatenate([a[..., :1], a, a[..., -1:]], axis=-1)
    u = a - (padded[..., 2:] - 2 * a + padded[..., :-2]) / 24.0

    def step(x, u_k):
        return x @ phi.T + u_k[..., None] * gamma, x @ c

    x0 = jnp.zeros(a.shape[:-1] + (phi.shape[0],), a.dtype)
    _, out = jax.lax.scan(step, x0, jnp.moveaxis(u, -1, 0))
    return jnp.moveaxis(out, 0, -1)


def wk_rms(
    a: Float[ArrayLike, "*batch samples"], dt: ScalarLike
) -> Float[Array, "*batch"]:
    r"""ISO 2631-1 frequency-weighted RMS acceleration $a_w = \mathrm{rms}(W_k a)$
    [m/s²] (the comfort figure; ≲ 0.315 m/s² "not uncomfortable").

    **Arguments:**

    - `a`: vertical acceleration [m/s²] sampled every `dt`; see `wk_weighted`.
    - `dt`: sampling interval [s].
    """
    return rms(wk_weighted(a, dt))


def vdv(
    a: Float[ArrayLike, "*batch samples"], dt: ScalarLike, *, weighted: bool = True
) -> Float[Array, "*batch"]:
    r"""Vibration dose value $\mathrm{VDV} = \left(\int_0^T a_w^4\,dt\right)^{1/4}$
    [m/s^1.75], summed as $(\Delta t \sum_k a_{w,k}^4)^{1/4}$ with $T = N\Delta t$.

    The fourth power weights shocks more than the RMS does: ISO 2631-1 asks for it when
    the crest factor exceeds 9. For a sine of amplitude $A$ over whole periods,
    $\mathrm{VDV} = A (3T/8)^{1/4}$.

    **Arguments:**

    - `a`: acceleration [m/s²] sampled every `dt` (last axis).
    - `dt`: sampling interval [s].
    - `weighted`: apply the Wk weighting first (default, the ISO definition); `False`
      takes `a` as already weighted (or wants the unweighted dose).
    """
    _positive_step(dt)
    a = wk_weighted(a, dt) if weighted else _samples(a, "a")
    return _safe_root(as_float_array(dt) * jnp.sum(a**4, axis=-1), 4)
