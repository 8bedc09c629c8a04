r"""Road and cam excitations: the road height $z_r(t)$ [m] under a wheel, as signals.

Each road is an `AbstractSignal` of time: `road(t)` is the height $z_r$ [m] at time $t$
[s], `road.derivative(t)` the vertical velocity $\dot z_r$ [m/s] that the tyre damping
sees. A feature met at constant forward speed $V$ [m/s] is a function of the distance
travelled $s = V (t - t_0)$ since it is reached at $t_0$.

- Discrete events: `HaversineBump`, `Pothole`, `SmoothStep`.
- Random roads of ISO 8608 class A–H: `iso8608_road` builds a `RandomRoad`, a profile
  sampled once on a uniform time grid and interpolated, so a closed-loop simulation
  evaluates it in O(1) per call; `iso8608_psd` is the standard's spectrum and
  `road_psd` estimates a profile's spectrum (numpy, for checks and plots).
- The SAS rig's eccentric cam: `Cam`.
- A sine road is `jaxmr.Sine`; a swept-sine road (or shaker test) is `jaxmr.Chirp`.
"""

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ._custom_types import Array, ArrayLike, Float, ScalarLike
from ._misc import as_float_array, check_concrete, default_float
from ._signal import AbstractSignal, Sampled, _hermite, _hermite_slope

TWO_PI = 2 * jnp.pi

# ISO 8608: reference spatial frequency n0 [cycle/m] and, per class, the geometric mean
# of the class's displacement PSD at n0, Gd(n0) = 16 * 4**k * 1e-6 m^3 (k = 0 for A).
ISO8608_N0 = 0.1
ISO8608_CLASSES = {c: 16.0 * 4.0**k * 1e-6 for k, c in enumerate("ABCDEFGH")}


def _cosine_ramp(u):
    """$r(u) = (1 - \\cos \\pi u)/2$ on $[0, 1]$, 0 before, 1 after (C¹), and
    $dr/du$."""
    inside = (u > 0) & (u < 1)
    uc = jnp.clip(u, 0.0, 1.0)
    value = 0.5 * (1 - jnp.cos(jnp.pi * uc))
    slope = jnp.where(inside, 0.5 * jnp.pi * jnp.sin(jnp.pi * uc), 0.0)
    return value, slope


def _dip(s, length, edge):
    """Unit dip profile over $s \\in [0, L]$ with cosine edges of length `edge` [m] and
    its derivative with respect to $s$: 0 outside, 1 on the flat part."""
    up, dup = _cosine_ramp(s / edge)
    down, ddown = _cosine_ramp((length - s) / edge)
    return up * down, (dup * down - up * ddown) / edge


class HaversineBump(AbstractSignal):
    r"""A haversine (raised-cosine) bump crossed at constant speed.

    $z_r = \tfrac{h}{2}\left(1 - \cos\tfrac{2\pi s}{L}\right)$ for $0 \le s \le L$ and 0
    elsewhere, with $s = V (t - t_0)$ the distance travelled since the bump is reached.
    The height and slope are continuous (C¹): the slope is zero at both ends. The peak
    vertical velocity is $\pi h V / L$.

    **Arguments:**

    - `height`: $h$ [m] (negative for a dip; see also `Pothole`).
    - `length`: $L$ [m], > 0, the bump's length along the road.
    - `speed`: $V$ [m/s], > 0, the vehicle's forward speed.
    - `start`: $t_0$ [s], when the wheel reaches the bump (default 0).
    """

    height: Float[Array, ""] = eqx.field(converter=as_float_array)
    length: Float[Array, ""] = eqx.field(converter=as_float_array)
    speed: Float[Array, ""] = eqx.field(converter=as_float_array)
    start: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        _check_event(type(self).__name__, self.length, self.speed)

    def _unit(self, t):
        s = self.speed * (t - self.start)
        value, slope = _dip(s, self.length, 0.5 * self.length)
        return value, slope * self.speed

    def __call__(self, t):
        return self.height * self._unit(t)[0]

    def derivative(self, t):
        return self.height * self._unit(t)[1]

    def bounds(self):
        zero = jnp.zeros_like(self.height)
        return jnp.minimum(zero, self.height), jnp.maximum(zero, self.height)


class Pothole(AbstractSignal):
    r"""A pothole crossed at constant speed: a dip of depth $d$ and length $L$ with
    raised-cosine edges and a flat bottom.

    $z_r = -d\, r(s/e)\, r((L - s)/e)$ with $r(u) = (1 - \cos \pi u)/2$ clipped to
    $[0, 1]$, $s = V (t - t_0)$, and edge length $e = \epsilon L$: the road falls over
    $e$, stays at $-d$ for $L - 2e$, and rises over $e$. The default $\epsilon = 1/2$ is
    the negative haversine $-\tfrac{d}{2}(1 - \cos(2\pi s/L))$; smaller $\epsilon$ gives
    steeper edges (peak vertical velocity $\pi d V / (2 e)$). C¹ for every $\epsilon$.

    **Arguments:**

    - `depth`: $d$ [m], ≥ 0 (the road goes down by $d$).
    - `length`: $L$ [m], > 0, along the road.
    - `speed`: $V$ [m/s], > 0.
    - `start`: $t_0$ [s], when the wheel reaches the pothole (default 0).
    - `edge`: $\epsilon$, the fraction of the length taken by each edge, in
      $(0, 1/2]$ (default 1/2: no flat bottom).
    """

    depth: Float[Array, ""] = eqx.field(converter=as_float_array)
    length: Float[Array, ""] = eqx.field(converter=as_float_array)
    speed: Float[Array, ""] = eqx.field(converter=as_float_array)
    start: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    edge: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.5)

    def __check_init__(self):
        _check_event("Pothole", self.length, self.speed)
        check_concrete(
            self.depth >= 0,
            f"Pothole: `depth` must be >= 0 m (it is how far the road goes down), got "
            f"{self.depth}; for a raised feature use HaversineBump.",
            self.depth,
        )
        check_concrete(
            (self.edge > 0) & (self.edge <= 0.5),
            f"Pothole: `edge` is the fraction of the length taken by each edge and must "
            f"be in (0, 0.5], got {self.edge}; 0.5 is the negative haversine.",
            self.edge,
        )

    def _unit(self, t):
        s = self.speed * (t - self.start)
        value, slope = _dip(s, self.length, self.edge * self.length)
        return value, slope * self.speed

    def __call__(self, t):
        return -self.depth * self._unit(t)[0]

    def derivative(self, t):
        return -self.depth * self._unit(t)[1]

    def bounds(self):
        return -self.depth, jnp.zeros_like(self.depth)


class SmoothStep(AbstractSignal):
    r"""A smooth step of the road (a kerb or a ramp onto a new level).

    $z_r = h\, r((t - t_0)/T_r)$ with the half-cosine ramp $r(u) = (1 - \cos \pi u)/2$
    on $[0, 1]$, 0 before and 1 after: the height rises from 0 to $h$ over the rise
    time $T_r$ with continuous slope (C¹), peak velocity $\pi h / (2 T_r)$.

    **Arguments:**

    - `height`: $h$ [m] (negative for a step down).
    - `rise_time`: $T_r$ [s], > 0 (a step of length $\ell$ [m] met at speed $V$ has
      $T_r = \ell / V$).
    - `start`: $t_0$ [s], when the rise begins (default 0).
    """

    height: Float[Array, ""] = eqx.field(converter=as_float_array)
    rise_time: Float[Array, ""] = eqx.field(converter=as_float_array)
    start: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.rise_time > 0,
            f"SmoothStep: `rise_time` must be > 0 s, got {self.rise_time}; for a "
            "near-ideal step use a rise time well below the fastest period of interest "
            "(e.g. 1e-3 s), not 0.",
            self.rise_time,
        )

    def __call__(self, t):
        return self.height * _cosine_ramp((t - self.start) / self.rise_time)[0]

    def derivative(self, t):
        slope = _cosine_ramp((t - self.start) / self.rise_time)[1]
        return self.height * slope / self.rise_time

    def bounds(self):
        zero = jnp.zeros_like(self.height)
        return jnp.minimum(zero, self.height), jnp.maximum(zero, self.height)


class Cam(AbstractSignal):
    r"""The SAS rig's eccentric cam: vertical excitation $u_{kin}(t) = e \sin(2\pi f t +
    \varphi)$ [m].

    A disc turning at $f$ revolutions per second about an axis offset by the
    eccentricity $e$ from its centre lifts a flat follower by exactly $e \sin\theta$,
    $\theta = 2\pi f t + \varphi$. For a wheel of radius $r$ riding on a disc of radius
    $R$ the lift is $e \sin\theta + \sqrt{(R + r)^2 - e^2 \cos^2\theta} - (R + r)$, whose
    correction to the sine is below $e^2 / (2 (R + r))$ (second order in $e$): the
    sinusoid is the first-order model the source uses.

    **Arguments:**

    - `eccentricity`: $e$ [m].
    - `frequency`: $f$ [Hz] = revolutions per second of the cam (motor speed [rpm] / 60),
      > 0.
    - `phase`: $\varphi$ [rad] (default 0).
    """

    eccentricity: Float[Array, ""] = eqx.field(converter=as_float_array)
    frequency: Float[Array, ""] = eqx.field(converter=as_float_array)
    phase: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.frequency > 0,
            f"Cam: `frequency` must be > 0 Hz (revolutions per second, rpm / 60), got "
            f"{self.frequency}; for a cam at rest use Constant(0.0).",
            self.frequency,
        )

    def __call__(self, t):
        return self.eccentricity * jnp.sin(TWO_PI * self.frequency * t + self.phase)

    def derivative(self, t):
        w = TWO_PI * self.frequency
        return self.eccentricity * w * jnp.cos(w * t + self.phase)

    def bounds(self):
        e = jnp.abs(self.eccentricity)
        return -e, e


def _check_event(name, length, speed):
    check_concrete(
        length > 0,
        f"{name}: `length` must be > 0 m (the feature's length along the road), got "
        f"{length}.",
        length,
    )
    check_concrete(
        speed > 0,
        f"{name}: `speed` must be > 0 m/s (the vehicle's forward speed; 50 km/h is "
        f"13.9 m/s), got {speed}.",
        speed,
    )


# ---------------------------------------------------------------------------------------
# Random roads


def _grid_number(name: str):
    """Converter of `RandomRoad`'s grid fields: a concrete Python float."""

    def convert(value) -> float:
        if isinstance(value, jax.core.Tracer):
            raise TypeError(
                f"RandomRoad: `{name}` must be a concrete number [s], not a traced "
                "value: the grid is static, one per compiled simulation, and a batch "
                "of roads (e.g. `jax.vmap` over keys) shares it. Build the roads "
                f"with one `{name}` and batch over their samples."
            )
        array = np.asarray(value)
        if array.size != 1:
            raise ValueError(
                f"RandomRoad: `{name}` must be one number [s], got shape "
                f"{array.shape}: a batch of roads shares one grid, so roads with "
                "different grids cannot be batched together (resample them onto one "
                "grid, or simulate them in separate calls)."
            )
        return float(array.reshape(()))

    return convert


class RandomRoad(AbstractSignal):
    r"""A road profile sampled on a uniform time grid $t_k = t_0 + k\,\Delta t$ and
    interpolated: cubic Hermite through the heights and velocities when `derivatives`
    are given (continuous velocity), piecewise linear otherwise (velocity = the
    interpolant's slope). Outside the grid the end heights are held and the velocity is
    0. Evaluation costs O(1) (no search, no sum over frequencies), so a closed-loop
    simulation can call it at every solver stage.

    Build one with `iso8608_road`; a batch of roads (e.g. `jax.vmap` over keys) is a
    `RandomRoad` whose `values` and `derivatives` have a leading batch axis. The grid
    ($\Delta t$, $t_0$) is static, Python numbers shared by every road of a batch:
    under `vmap` each lookup then indexes every road at the same sample instead of
    gathering per road (4× faster closed-loop simulations of 12 roads). Roads on
    different grids cannot be batched together.

    **Arguments:**

    - `values`: heights $z_r(t_k)$ [m], at least two.
    - `dt`: $\Delta t$ [s], > 0, a concrete number.
    - `derivatives`: velocities $\dot z_r(t_k)$ [m/s], or `None` (linear).
    - `start`: $t_0$ [s] (default 0), a concrete number.
    """

    values: Float[Array, " samples"] = eqx.field(converter=as_float_array)
    dt: float = eqx.field(static=True, converter=_grid_number("dt"))
    derivatives: Float[Array, " samples"] | None = eqx.field(
        converter=lambda d: None if d is None else as_float_array(d), default=None
    )
    start: float = eqx.field(static=True, converter=_grid_number("start"), default=0.0)

    def __check_init__(self):
        if self.values.ndim != 1 or self.values.shape[0] < 2:
            raise ValueError(
                "RandomRoad: `values` must be a 1-D array of at least two heights [m], "
                f"got shape {self.values.shape}."
            )
        if self.derivatives is not None and self.derivatives.shape != self.values.shape:
            raise ValueError(
                "RandomRoad: `derivatives` must have the shape of `values`, got "
                f"{self.derivatives.shape} and {self.values.shape}."
            )
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"RandomRoad: `dt` must be > 0 s, got {self.dt}.")
        if not np.isfinite(self.start):
            raise ValueError(f"RandomRoad: `start` must be finite, got {self.start}.")
        check_concrete(
            jnp.all(jnp.isfinite(self.values)),
            "RandomRoad: `values` contain NaN or inf; give finite heights.",
            self.values,
        )

    @property
    def end(self) -> float:
        r"""The last sample time $t_0 + (N - 1)\,\Delta t$ [s]."""
        return self.start + (self.values.shape[-1] - 1) * self.dt

    @property
    def times(self) -> Float[Array, "*batch samples"]:
        """The sample times $t_k$ [s] (one row per road of a batch)."""
        n = self.values.shape[-1]
        grid = self.start + self.dt * jnp.arange(n, dtype=self.values.dtype)
        return jnp.broadcast_to(grid, self.values.shape)

    def _locate(self, t):
        # O(1) on the uniform grid; `k` is kept as a float for the arithmetic (strict
        # dtype promotion) and cast only to index.
        u = (t - self.start) / self.dt
        k = jnp.clip(jnp.floor(u), 0, self.values.shape[0] - 2)
        s = jnp.clip(u - k, 0.0, 1.0)
        inside = (u >= 0) & (u <= self.values.shape[0] - 1)
        return k.astype(int), s, inside

    def __call__(self, t):
        k, s, _ = self._locate(t)
        y0, y1 = self.values[k], self.values[k + 1]
        if self.derivatives is None:
            return y0 + s * (y1 - y0)
        d0, d1 = self.derivatives[k] * self.dt, self.derivatives[k + 1] * self.dt
        return _hermite(s, y0, y1, d0, d1)

    def derivative(self, t):
        k, s, inside = self._locate(t)
        y0, y1 = self.values[k], self.values[k + 1]
        if self.derivatives is None:
            return jnp.where(inside, (y1 - y0) / self.dt, 0.0)
        d0, d1 = self.derivatives[k] * self.dt, self.derivatives[k + 1] * self.dt
        slope = _hermite_slope(s, y0, y1, d0, d1) / self.dt
        return jnp.where(inside, slope, 0.0)

    def bounds(self):
        return _sampled_bounds(self.times, self.values, self.derivatives)


@eqx.filter_jit
def _sampled_bounds(times, values, derivatives):
    # Reuse Sampled's exact bounds of the Hermite pieces (compiled: eagerly its few
    # dozen array operations cost seconds).
    return Sampled(times, values, derivatives, uniform=True).bounds()


def _class_gd0(road_class, where: str) -> float:
    if isinstance(road_class, str) and road_class.upper() in ISO8608_CLASSES:
        return ISO8608_CLASSES[road_class.upper()]
    raise ValueError(
        f"{where}: `road_class` must be an ISO 8608 class letter 'A' (very good) to 'H' "
        f"(very poor), got {road_class!r}."
    )


def _positive(value, name: str, unit: str, where: str, hint: str = "") -> float:
    try:
        number = float(value)
    except (TypeError, ValueError, jax.errors.ConcretizationTypeError):
        raise TypeError(
            f"{where}: `{name}` must be a concrete number [{unit}] (it sets array sizes "
            f"and the frequency grid); got {type(value).__name__}. Build one road per "
            "value and vmap over the keys."
        ) from None
    if not (np.isfinite(number) and number > 0):
        raise ValueError(
            f"{where}: `{name}` must be a finite number > 0 {unit}, got {value}.{hint}"
        )
    return number


def iso8608_psd(
    road_class: str, n: Float[ArrayLike, "*shape"], waviness: ScalarLike = 2.0
) -> Float[Array, "*shape"]:
    r"""The ISO 8608 displacement PSD of a road class: $G_d(n) = G_d(n_0)
    (n / n_0)^{-w}$ [m³], one-sided in the spatial frequency $n$ [cycle/m].

    $n_0 = 0.1$ cycle/m and $G_d(n_0) = 16 \cdot 4^k \times 10^{-6}$ m³ is the class's
    geometric mean, $k = 0$ for class A to $k = 7$ for H (the class limits are half and
    twice that). The variance of the height in a band is $\int G_d(n)\,dn$ [m²].

    **Arguments:**

    - `road_class`: 'A' … 'H'.
    - `n`: spatial frequencies [cycle/m], > 0.
    - `waviness`: $w$ (default 2, the standard's value).

    **Returns:** $G_d(n)$ [m³], the shape of `n`.
    """
    gd0 = _class_gd0(road_class, "iso8608_psd")
    n = as_float_array(n)
    return gd0 * (n / ISO8608_N0) ** (-as_float_array(waviness))


def iso8608_road(
    road_class: str,
    speed: ScalarLike,
    duration: ScalarLike,
    key: PRNGKeyArray,
    *,
    method: str = "sinusoids",
    dt: ScalarLike = 1e-3,
    n_min: ScalarLike = 0.011,
    n_max: ScalarLike = 2.83,
    waviness: ScalarLike = 2.0,
    start_at_zero: bool = True,
) -> RandomRoad:
    r"""A random road of ISO 8608 class A–H driven at constant speed, as a time signal.

    The target is the one-sided displacement PSD $G_d(n) = G_d(n_0)(n/n_0)^{-w}$
    (`iso8608_psd`) over the band $n_{min} \le n \le n_{max}$ [cycle/m]. The default band
    0.011–2.83 cycle/m (wavelengths 91 m to 0.35 m) is the standard's classification
    band; at speed $V$ it is the temporal band $V n_{min}$ … $V n_{max}$ [Hz] (0.22–57 Hz
    at 20 m/s, which covers body and wheel-hop modes). Wavelengths shorter than about
    0.3 m are filtered out by the tyre's contact patch anyway.

    Two methods, both sampled once on $t_k = k\,\Delta t$, $k = 0 … \lceil T/\Delta t
    \rceil$ (so the grid covers $[0, T]$), and returned as a `RandomRoad`:

    - `"sinusoids"`: $z_r(x) = \sum_i A_i \cos(2\pi n_i x + \varphi_i)$, $x = V t$, with
      $A_i = \sqrt{2 G_d(n_i) \Delta n}$ (so that $A_i^2/2$, the variance of component
      $i$, is $G_d(n_i)\Delta n$) and phases $\varphi_i$ uniform on $[0, 2\pi)$, for
      every $n_i = i\,\Delta n$ in the band. $\Delta n = 1/(V T_{fft})$ with the FFT
      length $T_{fft}$ ≥ both the duration and $2/(V n_{min})$, so there are at least two
      components per $n_{min}$ and the profile does not repeat within the duration. The
      sum and its exact time derivative are evaluated on the grid by one inverse real
      FFT each; the road interpolates them by cubic Hermite. Any waviness $w$.
    - `"white_noise"`: for $w = 2$ the spectrum is that of integrated white noise; with
      a cut-on $n_c = n_{min}$ to keep the variance finite, the height obeys $\dot z_r =
      -2\pi n_c V z_r + g\,\xi(t)$ with $\xi$ unit-intensity white noise,
      $E[\xi(t)\xi(t')] = \delta(t - t')$. Derivation of the gain: in space, $dz/dx =
      -2\pi n_c z + g_x \eta(x)$ with unit-intensity $\eta$ (two-sided PSD 1) has
      two-sided PSD $g_x^2 / (4\pi^2 (n^2 + n_c^2))$, hence one-sided $G(n) = g_x^2 /
      (2\pi^2 (n^2 + n_c^2))$; equating with $G_d(n_0) n_0^2 / (n^2 + n_c^2)$ gives $g_x
      = \pi n_0 \sqrt{2 G_d(n_0)}$. With $x = V t$, $\eta(Vt) = \xi(t)/\sqrt V$ (since
      $\delta(V\tau) = \delta(\tau)/V$), so $g = V g_x / \sqrt V = \pi n_0 \sqrt{2
      G_d(n_0) V}$. (The often-printed $2\pi n_0 \sqrt{G_d(n_0) V}$ squares to twice
      this: it doubles the PSD.) The Ornstein–Uhlenbeck process is discretised exactly:
      $z_{k+1} = e^{-a\Delta t} z_k + g\sqrt{(1 - e^{-2a\Delta t})/(2a)}\,\epsilon_k$,
      $a = 2\pi n_c V$, $\epsilon_k \sim N(0, 1)$. The samples are exact samples of the
      continuous process, so their PSD is the filter's PSD $G_d(n_0) n_0^2/(n^2 +
      n_c^2)$ (within 5 % of ISO above $4.4\,n_c$) raised by aliasing by the factor
      $(\pi f\Delta t / \sin \pi f\Delta t)^2$ at $f = V n$ (+1 % at $f\Delta t =
      0.055$, +23 % at $n_{max}$ with the coarsest allowed `dt`). The road is the linear
      interpolant. Note that a $w = 2$ road has white vertical velocity: the
      interpolant's slope has variance $\approx g^2/\Delta t$, so a tyre damping force
      $c_t \dot z_r$ depends on $\Delta t$; use `"sinusoids"` (band-limited to
      $n_{max}$) when the tyre damping matters.

    Jit-compatible and vmappable over `key` (a batch of road seeds); the other arguments
    are static numbers.

    **Arguments:**

    - `road_class`: 'A' (very good) … 'H' (very poor); C is a typical secondary road.
    - `speed`: $V$ [m/s], > 0.
    - `duration`: $T$ [s], > 0.
    - `key`: a `jax.random` key.
    - `method`: `"sinusoids"` (default) or `"white_noise"` (waviness 2 only).
    - `dt`: $\Delta t$ [s] of the grid (default 1e-3); must be ≤ $1/(4 n_{max} V)$,
      four samples per shortest wavelength.
    - `n_min`, `n_max`: the band [cycle/m] (defaults 0.011 and 2.83); for
      `"white_noise"` `n_min` is the cut-on $n_c$ and `n_max` only sets the `dt` check.
    - `waviness`: $w$ (default 2).
    - `start_at_zero`: start the road at height 0 (default): the sum of sinusoids is
      shifted by its value at $t = 0$ (a constant, which changes no PSD value at
      $n > 0$), the OU process starts at 0 (its low-frequency content settles within
      $1/(2\pi n_c V)$ s). `False`: stationary start.

    **Returns:** a `RandomRoad` of heights [m] (and velocities [m/s] for `"sinusoids"`).
    """
    where = "iso8608_road"
    if not isinstance(key, jax.Array):
        raise TypeError(
            f"{where}: `key` must be a JAX random key, e.g. jax.random.key(0) (a batch "
            f"of roads: jax.vmap over jax.random.split(key, n)), got {type(key).__name__}."
        )
    if method not in ("sinusoids", "white_noise"):
        raise ValueError(
            f"{where}: `method` must be 'sinusoids' or 'white_noise', got {method!r}."
        )
    gd0 = _class_gd0(road_class, where)
    speed = _positive(
        speed,
        "speed",
        "m/s",
        where,
        " A road needs forward motion (50 km/h = 13.9 m/s).",
    )
    duration = _positive(duration, "duration", "s", where)
    dt = _positive(dt, "dt", "s", where)
    n_min = _positive(n_min, "n_min", "cycle/m", where)
    n_max = _positive(n_max, "n_max", "cycle/m", where)
    waviness = _positive(waviness, "waviness", "", where)
    if n_min >= n_max:
        raise ValueError(
            f"{where}: the band needs n_min < n_max [cycle/m], got n_min = {n_min}, "
            f"n_max = {n_max} (ISO 8608's band is 0.011 to 2.83)."
        )
    dt_max = 1.0 / (4.0 * n_max * speed)
    if dt > dt_max * (1 + 1e-12):
        raise ValueError(
            f"{where}: dt = {dt} s is too coarse for the road band: at {speed} m/s the "
            f"shortest wavelength 1/n_max = {1 / n_max:.3g} m passes in "
            f"{1 / (n_max * speed):.3g} s. Use dt <= {dt_max:.3g} s (four samples per "
            "shortest wavelength), or lower `n_max`."
        )
    n_samples = int(np.ceil(duration / dt - 1e-9)) + 1
    if method == "sinusoids":
        # FFT length: covers the duration (no repetition) and resolves n_min.
        needed = max(n_samples, int(np.ceil(2.0 / (n_min * speed * dt))))
        n_fft = 1 << (needed - 1).bit_length()
        # Numbers as arrays, sizes static: one compilation serves every class and speed
        # with the same grid sizes.
        numbers = [as_float_array(x) for x in (gd0, speed, dt, n_min, n_max, waviness)]
        # pyright cannot count the list's items (six) before the positional ones.
        values, derivatives = _sinusoids(key, *numbers, n_samples, n_fft)  # pyright: ignore[reportCallIssue]
    else:
        if waviness != 2.0:
            raise ValueError(
                f"{where}: method='white_noise' (a first-order filter) gives waviness 2 "
                f"only, got waviness = {waviness}; use method='sinusoids'."
            )
        gain = _white_noise_gain(gd0, speed)
        numbers = [as_float_array(x) for x in (gain, speed, dt, n_min)]
        # pyright cannot count the list's items (four) before the positional ones.
        values = _white_noise(key, *numbers, n_samples, start_at_zero)  # pyright: ignore[reportCallIssue]
        derivatives = None
    if start_at_zero:
        values = values - values[0]
    return RandomRoad(values, dt, derivatives)


@eqx.filter_jit
def _sinusoids(key, gd0, speed, dt, n_min, n_max, waviness, n_samples, n_fft):
    dtype = default_float()
    n_bins = n_fft // 2 + 1
    dn = 1.0 / (n_fft * dt * speed)
    n = jnp.arange(n_bins, dtype=dtype) * dn
    # The band excludes the zero and Nyquist bins (n_min > 0, dt <= 1/(4 n_max V)), so
    # the inverse real FFT below is exactly the real part of the complex sum.
    band = (n >= n_min) & (n <= n_max)
    safe_n = jnp.where(band, n, ISO8608_N0)
    amplitude = jnp.where(
        band, jnp.sqrt(2 * gd0 * (safe_n / ISO8608_N0) ** (-waviness) * dn), 0.0
    )
    phase = jax.random.uniform(key, (n_bins,), dtype, 0.0, 2 * jnp.pi)
    re, im = amplitude * jnp.cos(phase), amplitude * jnp.sin(phase)
    omega = TWO_PI * speed * n
    # sum_i c_i exp(j omega_i t_k) = (n_fft / 2) irfft(c)[k] for c_0 = c_{n_fft/2} = 0.
    scale = 0.5 * n_fft
    values = scale * jnp.fft.irfft(jax.lax.complex(re, im), n_fft)
    derivatives = scale * jnp.fft.irfft(jax.lax.complex(-omega * im, omega * re), n_fft)
    return values[:n_samples], derivatives[:n_samples]


@eqx.filter_jit
def _white_noise(key, gain, speed, dt, n_c, n_samples, start_at_zero):
    dtype = default_float()
    a = TWO_PI * n_c * speed
    decay = jnp.exp(-a * dt)
    step_std = gain * jnp.sqrt(-jnp.expm1(-2 * a * dt) / (2 * a))
    key_start, key_steps = jax.random.split(key)
    if start_at_zero:
        z0 = jnp.zeros((), dtype)
    else:
        z0 = gain / jnp.sqrt(2 * a) * jax.random.normal(key_start, (), dtype)
    noise = step_std * jax.random.normal(key_steps, (n_samples - 1,), dtype)

    def step(z, e):
        z = decay * z + e
        return z, z

    _, rest = jax.lax.scan(step, z0, noise)
    return jnp.concatenate([z0[None], rest])


def _white_noise_gain(gd0: float, speed: float) -> float:
    r"""Gain $g = \pi n_0 \sqrt{2 G_d(n_0) V}$ [m/s^½] of unit-intensity white noise
    in $\dot z_r = -2\pi n_c V z_r + g\,\xi(t)$ that reproduces the one-sided ISO 8608
    PSD $G_d(n_0)(n_0/n)^2$ (derivation in `iso8608_road`)."""
    return float(np.pi * ISO8608_N0 * np.sqrt(2.0 * gd0 * speed))


def road_psd(
    z: Float[ArrayLike, "*batch samples"],
    dt: ScalarLike,
    speed: ScalarLike,
    *,
    segment_length: ScalarLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Estimate the one-sided displacement PSD $G_d(n)$ [m³] of road heights sampled
    in time, against spatial frequency $n$ [cycle/m] (numpy; not jit-able).

    Welch's method: Hann-windowed segments with 50 % overlap, each less its mean,
    periodograms averaged over the segments and over any leading batch axes (several
    roads). With $\Delta x = V \Delta t$ the sample spacing, a segment's estimate is
    $2 |\mathrm{DFT}(w z)|^2 \Delta x / \sum w^2$, so $\int G_d\,dn$ is the variance. The
    relative scatter of each value is about $1/\sqrt{K}$ for $K$ averaged segments.

    **Arguments:**

    - `z`: heights [m] at $t_k = k \Delta t$ (last axis); leading axes are averaged.
    - `dt`: $\Delta t$ [s].
    - `speed`: $V$ [m/s].
    - `segment_length`: the length of a segment along the road [m] (resolution
      $1/\ell$ cycle/m); default: an eighth of the record (15 segments).

    **Returns:** `(n, G_d)`: frequencies [cycle/m] (> 0, the zero bin dropped) and the
    PSD [m³].
    """
    z = np.asarray(z, dtype=float)
    z = z.reshape(-1, z.shape[-1])
    for name, value in (("dt", dt), ("speed", speed)):
        # `ScalarLike` admits complex arrays, which `float` refuses at run time.
        if not (np.ndim(value) == 0 and np.isfinite(value) and float(value) > 0):  # pyright: ignore[reportArgumentType]
            unit = "s" if name == "dt" else "m/s"
            raise ValueError(f"road_psd: `{name}` must be > 0 [{unit}], got {value!r}.")
    dx = float(speed) * float(dt)  # pyright: ignore[reportArgumentType]
    n_total = z.shape[-1]
    if segment_length is None:
        n_seg = n_total // 8
    else:
        n_seg = int(round(float(segment_length) / dx))  # pyright: ignore[reportArgumentType]
    if not 8 <= n_seg <= n_total:
        raise ValueError(
            f"road_psd: a segment of {n_seg} samples does not fit: give a "
            f"`segment_length` between {8 * dx:.3g} m and the record's "
            f"{n_total * dx:.3g} m."
        )
    window = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n_seg) / n_seg)
    starts = np.arange(0, n_total - n_seg + 1, max(n_seg // 2, 1))
    segments = np.stack([z[:, s : s + n_seg] for s in starts], axis=1)
    segments = segments - segments.mean(axis=-1, keepdims=True)
    spectrum = np.abs(np.fft.rfft(segments * window, axis=-1)) ** 2
    psd = spectrum.mean(axis=(0, 1)) * dx / np.sum(window**2)
    psd[1:] *= 2
    if n_seg % 2 == 0:
        psd[-1] /= 2  # the Nyquist bin has no negative-frequency twin
    n = np.fft.rfftfreq(n_seg, dx)
    return n[1:], psd[1:]
