"""The hysteretic oscillator of the Bouc–Wen benchmark (SYSTEMS.md §4) and the
band-limited interpolation of its sampled inputs."""

import numpy as np

from .._hysteresis import BoucWen
from .._signal import Sampled
from .sdof import SingleDegreeOfFreedom


def hysteretic_benchmark_oscillator(
    mass: float = 2.0,
    damping: float = 10.0,
    stiffness: float = 5e4,
    alpha: float = 5e4,
    beta: float = 1e3,
    gamma: float = 0.8,
    delta: float = -1.1,
    nu: float = 1.0,
) -> SingleDegreeOfFreedom:
    r"""The Bouc–Wen hysteretic benchmark oscillator of Noël & Schoukens (2016).

    $$m \ddot y + c \dot y + k y + z = u(t),\qquad
    \dot z = \alpha \dot y - \beta\,(\gamma |\dot y| |z|^{\nu-1} z
    + \delta \dot y |z|^\nu),$$
    input $u$ a force [N], output $y$ a displacement [m]. The arguments are the
    benchmark's own parameters (its defaults: the true values). In jaxmr's `BoucWen`
    convention ($\dot z = A v - \gamma_j |v| z |z|^{n-1} - \beta_j v |z|^n$,
    $F = \alpha_j z + c_0 v + k_0 x$) the hysteretic force is $z$ itself [N]:
    $\alpha_j = 1$, $A = \alpha$ [N/m], $\gamma_j = \beta\gamma$, $\beta_j = \beta\delta$
    [N^{1-\nu}/m], $n = \nu$, and the spring and dashpot are the oscillator's
    (`stiffness`, `damping`; the damper's `c0 = k0 = 0`). The true values give
    $\beta_j + \gamma_j = -300 < 0$: $z$ is unbounded while loading, which
    `BoucWen` allows.

    With $\nu = 1$ only $\beta\gamma$ and $\beta\delta$ are identifiable (as jaxmr
    writes them); to fit the jaxmr model, keep `alpha` (jaxmr's) fixed at 1 and the
    damper's `c0`, `k0` fixed at 0, else the set is redundant.

    **Arguments:** the benchmark's, in its units: `mass` $m$ [kg], `damping` $c$
    [N·s/m], `stiffness` $k$ [N/m], `alpha` $\alpha$ [N/m], `beta` $\beta$
    [N^{1-\nu}/m, so 1/m at $\nu = 1$], `gamma` $\gamma$ [1], `delta` $\delta$ [1],
    `nu` $\nu$ [1].

    **Returns:** a `SingleDegreeOfFreedom` (simulate it with `simulate_system`, the
    force as the excitation, open loop: `controller=0.0`).
    """
    hysteresis = BoucWen(
        alpha=1.0,
        c0=0.0,
        A=alpha,
        beta=beta * delta,
        gamma=beta * gamma,
        n=nu,
    )
    return SingleDegreeOfFreedom(
        mass=mass, damper=hysteresis, damping=damping, stiffness=stiffness
    )


def band_limited_input(
    u, fs: float, factor: int, *, periodic: bool, half_width: int = 32
) -> Sampled:
    r"""A sampled input made continuous by band-limited interpolation.

    A force sampled at `fs` is, between its samples, neither held nor straight: the
    benchmark's generator integrated the underlying band-limited signal at a higher
    rate. Linear interpolation between the 750 Hz samples errs by
    $h^2 \ddot u / 8$, ~1e-2 of a 150 Hz component: far above the benchmark's
    1e-7 m resolution. Here the samples are first upsampled by `factor`, then
    interpolated linearly (`Sampled`); with `factor` twice the RK4 substeps per
    sample every RK4 stage (at $t$, $t + h/2$, $t + h$) falls on an upsampled point.

    - `periodic=True` (one period of a periodic input, e.g. a multisine): exact
      trigonometric interpolation by zero-padding the FFT (the Nyquist bin split
      between $\pm f_s/2$).
    - `periodic=False` (a transient record, e.g. a sweep from rest): a Kaiser-windowed
      sinc (±`half_width` samples, window β = 12), the record continued beyond its
      ends by point reflection ($2u_0 - u_k$: value and slope continuous, so a sweep
      that starts at zero with a finite slope does not ring). Its error is below
      1e-6 of the amplitude for tones up to 0.3 $f_s$ (measured; the benchmark's
      inputs stay below 0.2 $f_s$); within `half_width` samples of the end it grows
      to ~1e-4 of the amplitude (the reflection's kink in the second derivative).

    **Arguments:** `u` the samples (1-D), `fs` their rate [Hz], `factor` the
    upsampling factor (int ≥ 1), `periodic`, `half_width`.

    **Returns:** a `Sampled` signal on $t = k/(f_s \cdot \mathrm{factor})$, $k < N\cdot$
    `factor` (the periodic case) or $\le (N-1)\cdot$`factor` (the transient case).
    """
    u = np.asarray(u, dtype=float)
    if u.ndim != 1 or u.size < 2:
        raise ValueError(f"`u` must be a 1-D array of samples, got shape {u.shape}.")
    if not isinstance(factor, int) or factor < 1:
        raise ValueError(f"`factor` must be a positive integer, got {factor!r}.")
    n = u.size
    if periodic:
        spectrum = np.fft.rfft(u)
        if n % 2 == 0:
            # Real signal: the Nyquist bin is the sum of +fs/2 and -fs/2 components.
            spectrum[-1] *= 0.5
        padded = np.zeros(n * factor // 2 + 1, dtype=complex)
        padded[: spectrum.size] = spectrum
        fine = np.fft.irfft(padded, n * factor) * factor
    else:
        fine = _windowed_sinc_upsample(u, factor, half_width)
    t = np.arange(fine.size) / (fs * factor)
    return Sampled(t, fine, uniform=True)


def _windowed_sinc_upsample(u, factor, half_width, window_beta=12.0):
    # Polyphase: the point k + j/factor (0 < j < factor) is Σ_d u[k + d] h(j/factor - d)
    # over d = -half_width + 1 ... half_width, h a Kaiser-windowed sinc: one short
    # correlation per phase instead of one long convolution of a zero-stuffed signal.
    n = u.size
    fine = np.empty((n - 1) * factor + 1)
    fine[::factor] = u
    d = np.arange(-half_width + 1, half_width + 1)
    # Beyond the ends the record is continued by point reflection (2 u[0] - u[k]):
    # value and slope stay continuous, so a sweep starting at u = 0 with a finite
    # slope is not seen as a kink (zeros there rang at 1 % of the amplitude).
    before = 2 * u[0] - u[half_width:0:-1]
    after = 2 * u[-1] - u[-2 : -half_width - 2 : -1]
    padded = np.concatenate([before, u, after])
    for j in range(1, factor):
        x = j / factor - d
        window = np.i0(window_beta * np.sqrt(1 - (x / half_width) ** 2))
        h = np.sinc(x) * window / np.i0(window_beta)
        # correlate(...)[i] = Σ_t padded[i + t] h[t] = Σ_d u[i - 1 + d] h(j/factor - d)
        fine[j::factor] = np.correlate(padded, h, mode="valid")[1:n]
    return fine
