r"""Hodgdon's rate-independent model of ferromagnetic hysteresis (Coleman & Hodgdon 1986;
Hodgdon 1988, IEEE Trans. Magn. 24(1)), in SI units.

Units: induction $B$ [T], field $H$ [A/m], permeabilities [H/m = T·m/A]. Source documents
in Gaussian units convert as 1 kG = 0.1 T, 1 Oe = 1000/(4π) A/m ≈ 79.58 A/m and
1 kG/Oe = 4π·10⁻⁴ H/m (the study behind this module tabulates its steels in kG and Oe).
"""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._current_law import as_parameter
from .._custom_types import Array, ArrayLike, Float, Scalar, ScalarLike
from .._misc import Check, as_float_array, check_concrete, is_concrete, rk4_step

MU_0 = 4e-7 * math.pi  # vacuum permeability [H/m]


class HodgdonMaterial(eqx.Module):
    r"""Hodgdon's model of a ferromagnetic material's $B$–$H$ hysteresis.

    $$\dot H = \alpha_h\,|\dot B|\,\big(f(B) - H\big) + g(B)\,\dot B$$

    with the material functions (odd $f$, even $g$)

    $$f(B) = A_1\tan(A_2 B)\ \ (|B| \le B_s),\qquad
    f(B) = \pm A_1\tan(A_2 B_s) + (B \mp B_s)/\mu_s\ \ (\pm B > B_s),$$
    $$g(B) = f'(B)\,\big[1 - A_3\,e^{-A_4|B|/(B_s - |B|)}\big]\ \ (|B| < B_s),\qquad
    g(B) = f'(B)\ \ \text{otherwise}.$$

    On a branch of constant direction $s = \mathrm{sgn}\,\dot B$ the model is the linear
    ODE $dH/dB = \alpha_h s (f - H) + g$: after a reversal $H - f$ relaxes, over an
    induction interval of about $1/\alpha_h$, to $s\,(g - f')/\alpha_h$. So $f$ is the
    centre curve of the loop, $g > f'$ (a negative $A_3$, which is what
    `from_major_loop` finds for real steels) puts the rising branch at larger $H$ than the
    falling one (a loop that dissipates $\oint H\,dB > 0$), and beyond $B_s$ (where
    $g = f'$) the branches close onto $f$.

    Since $\dot B$ has the sign of $\dot H$ wherever $dH/dB > 0$, the model is integrated
    with $H$ as the input: $\dot B = \dot H / \big(\alpha_h\,\mathrm{sgn}(\dot H)(f(B) - H)
    + g(B)\big)$ (`dB_dt`), and, being rate-independent, a $B$–$H$ curve can be traced
    with $H$ itself as the independent variable (`trace`).

    **Arguments:**

    - `A1`: [A/m], scale of $f$; > 0.
    - `A2`: [1/T]; > 0 with $A_2 B_s < \pi/2$ (so $f$ is finite up to $B_s$).
    - `A3`: [1], amplitude of the hysteretic part of $g$; < 1 (so $g > 0$). Negative
      for a loop of the usual orientation.
    - `A4`: [1], how fast that part fades towards $B_s$; ≥ 0.
    - `alpha_h`: $\alpha_h$ [1/T]; > 0.
    - `B_s`: closure (saturation) induction $B_s$ [T]; > 0.
    - `mu_s`: permeability beyond closure $\mu_s$ [H/m]; > 0.

    Build one from the measured major loop with `HodgdonMaterial.from_major_loop`.
    """

    A1: Float[Array, ""] = eqx.field(converter=as_parameter)
    A2: Float[Array, ""] = eqx.field(converter=as_parameter)
    A3: Float[Array, ""] = eqx.field(converter=as_parameter)
    A4: Float[Array, ""] = eqx.field(converter=as_parameter)
    alpha_h: Float[Array, ""] = eqx.field(converter=as_parameter)
    B_s: Float[Array, ""] = eqx.field(converter=as_parameter)
    mu_s: Float[Array, ""] = eqx.field(converter=as_parameter)

    def __check_init__(self):
        # Parameters inside fitting wrappers (`Positive`, ...) or traced are checked
        # when `simulate` runs, after they are resolved.
        if has_wrapped_fields(self) or not is_concrete(self):
            return
        with jax.ensure_compile_time_eval():
            constraints = self.constraints()
        for check in constraints:
            check_concrete(check.ok, check.named("HodgdonMaterial").message(), self)

    def constraints(self) -> list[Check]:
        """Validity checks of the parameters."""
        return [
            Check(self.A1 > 0, "`A1` must be > 0 (in A/m)", self.A1),
            Check(self.A2 > 0, "`A2` must be > 0 (in 1/T)", self.A2),
            Check(
                self.A2 * self.B_s < jnp.pi / 2,
                "`A2 * B_s` must be < pi/2 so that f(B) = A1 tan(A2 B) stays finite "
                "up to the closure induction",
                self.A2 * self.B_s,
            ),
            Check(
                self.A3 < 1,
                "`A3` must be < 1 so that g(B) > 0 (negative for a loop of the usual "
                "orientation)",
                self.A3,
            ),
            Check(self.A4 >= 0, "`A4` must be >= 0", self.A4),
            Check(self.alpha_h > 0, "`alpha_h` must be > 0 (in 1/T)", self.alpha_h),
            Check(self.B_s > 0, "`B_s` must be > 0 (in T)", self.B_s),
            Check(self.mu_s > 0, "`mu_s` must be > 0 (in H/m)", self.mu_s),
        ]

    # -- material functions ----------------------------------------------------------

    def functions(
        self, B: Float[ArrayLike, "*shape"]
    ) -> tuple[Float[Array, "*shape"], Float[Array, "*shape"], Float[Array, "*shape"]]:
        """$f(B)$ [A/m], $f'(B)$ and $g(B)$ [A/(m·T)] at induction $B$ [T], in one pass
        (they share $\\tan(A_2B)$; one pass also keeps the compiled derivative small)."""
        B = jnp.asarray(B)
        a = jnp.abs(B)
        inside = a <= self.B_s
        # tan is evaluated only on [-B_s, B_s] (clipped), so neither branch of a `where`
        # is inf or nan, nor its derivative; f' = A1 A2 (1 + tan^2).
        t = jnp.tan(self.A2 * jnp.clip(B, -self.B_s, self.B_s))
        side = jnp.where(B >= 0, 1.0, -1.0)
        H_s = self.A1 * jnp.tan(self.A2 * self.B_s)
        f = jnp.where(
            inside, self.A1 * t, side * H_s + (B - side * self.B_s) / self.mu_s
        )
        f_prime = jnp.where(inside, self.A1 * self.A2 * (1 + t * t), 1.0 / self.mu_s)
        # The exponent -A4|B|/(B_s - |B|) runs to -inf at the closure induction, where
        # e^x and its derivative vanish; flooring the distance to B_s keeps the quotient
        # (and its derivative, which squares the distance) finite in floating point.
        distance = jnp.maximum(self.B_s - a, 1e-12 * self.B_s)
        hysteretic = jnp.where(
            a < self.B_s, self.A3 * jnp.exp(-self.A4 * a / distance), 0.0
        )
        return f, f_prime, f_prime * (1.0 - hysteretic)

    def f(self, B: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """The centre curve $H = f(B)$ [A/m] of the loop, for $B$ [T]."""
        return self.functions(B)[0]

    def f_prime(self, B: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """$f'(B)$ [A/(m·T)]."""
        return self.functions(B)[1]

    def g(self, B: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """$g(B)$ [A/(m·T)]."""
        return self.functions(B)[2]

    def branch_slope(
        self,
        B: Float[ArrayLike, "*shape"],
        H: Float[ArrayLike, "*shape"],
        direction: Float[ArrayLike, "*shape"],
    ) -> Float[Array, "*shape"]:
        r"""$dH/dB = \alpha_h s (f(B) - H) + g(B)$ [A/(m·T)] on a branch of direction
        $s$ (+1 rising, -1 falling; a value in between blends the two)."""
        f, _, g = self.functions(B)
        return self.alpha_h * direction * (f - H) + g

    def dB_dt(
        self,
        B: ScalarLike,
        H: ScalarLike,
        dH_dt: ScalarLike,
        sign_scale: ScalarLike = 0.0,
    ) -> Scalar:
        r"""$\dot B$ [T/s] for the field rate $\dot H$ [A/(m·s)] at $(B, H)$.

        $\dot B = \dot H / (\alpha_h\,\mathrm{sgn}(\dot H)(f(B) - H) + g(B))$: $|\dot B|$
        of Hodgdon's equation becomes the sign of the input rate, so no $|\cdot|$ of an
        unknown appears. The rate is continuous where $\dot H$ changes sign (it is 0
        there from both sides), and the exact sign has zero derivative, so gradients
        stay finite through reversals. With `sign_scale` $> 0$ [A/(m·s)] the sign is
        $\tanh(\dot H/\text{scale})$, which makes the rate smooth in $\dot H$ too.
        """
        dH_dt = jnp.asarray(dH_dt)
        direction = smooth_sign(dH_dt, jnp.asarray(sign_scale))
        return dH_dt / self.branch_slope(B, H, direction)

    # -- curves ------------------------------------------------------------------------

    def trace(
        self,
        fields: Float[ArrayLike, " points"],
        initial_induction: ScalarLike = 0.0,
        *,
        substeps: int = 8,
    ) -> Float[Array, " points"]:
        """The induction $B$ [T] along a field history $H$ [A/m].

        The model is rate-independent, so a $B$–$H$ curve needs no time: $B$ is
        integrated against $H$ (classical RK4, `substeps` steps between consecutive
        samples, each interval traversed in one direction) from `initial_induction` at
        `fields[0]` (0 with `fields[0] = 0`: the demagnetised, virgin state). Put the
        reversal points of the history among the samples.

        **Returns:** $B$ at every sample of `fields`.
        """
        fields = as_float_array(fields)
        if fields.ndim != 1 or fields.shape[0] < 2:
            raise ValueError(
                f"`fields` must be a 1-D array of at least two fields [A/m], got shape "
                f"{fields.shape}."
            )
        if not isinstance(substeps, int) or substeps < 1:
            raise ValueError(f"`substeps` must be a positive integer, got {substeps}.")
        return trace_induction(
            self, 0.0, fields, as_float_array(initial_induction), substeps
        )

    def major_loop_points(self, *, steps: int = 2000) -> tuple[Scalar, Scalar]:
        """Remanence $B_r$ [T] and coercivity $H_c$ [A/m] of the model's major loop.

        Follows the falling branch from the closure point $(B_s, f(B_s))$ (where a loop
        driven beyond closure meets $f$) down to $H = 0$ and to $B = 0$, with `steps` RK4
        steps on each.

        **Returns:** `(B_r, H_c)`.
        """
        H_top = self.f(self.B_s)
        B_r = _integrate_B_of_H(self, self.B_s, H_top, jnp.zeros_like(H_top), steps)
        H_zero = _integrate_H_of_B(self, self.B_s, H_top, jnp.zeros_like(H_top), steps)
        return B_r, -H_zero

    # -- identification from the major loop -------------------------------------------

    @classmethod
    def from_major_loop(
        cls,
        *,
        B_s: ScalarLike,
        H_s: ScalarLike,
        B_r: ScalarLike,
        H_c: ScalarLike,
        mu_r: ScalarLike,
        mu_c: ScalarLike,
        mu_s: ScalarLike,
        alpha_h: ScalarLike | None = None,
    ) -> "HodgdonMaterial":
        r"""Material constants from a measured major loop (Hodgdon 1988's conditions).

        The data (SI): closure point $(H_s, B_s)$ [A/m, T], where the two branches
        meet; remanence $B_r$ [T]; coercivity $H_c$ [A/m]; differential permeabilities
        [H/m] $\mu_r$ at the remanence point, $\mu_c$ at the coercive point, $\mu_s$ at
        closure.

        Conditions imposed, in order (each is solved exactly):

        1. $f$ passes through the closure point, $A_1\tan(A_2B_s) = H_s$; beyond it the
           branches follow $f$.
        2. $f$ has the closure slope there, $f'(B_s) = A_1A_2/\cos^2(A_2B_s) =
           1/\mu_s$, so $f$ joins its linear continuation smoothly. With 1:
           $\sin(2A_2B_s)/(2A_2B_s) = \mu_sH_s/B_s$, one root $A_2B_s \in (0, \pi/2)$
           when $\mu_s H_s < B_s$; then $A_1 = H_s\cot(A_2B_s)$.
        3. The slope at the coercive point $(\pm H_c, 0)$ is $\mu_c$: there
           $dH/dB = g(0) - \alpha_h H_c$, so
           $A_3 = 1 - (1/\mu_c + \alpha_h H_c)/(A_1A_2)$.
        4. The slope at the remanence point $(0, \pm B_r)$ is $\mu_r$: there
           $dH/dB = g(B_r) - \alpha_h f(B_r)$, so
           $A_4 = \frac{B_s - B_r}{B_r}\ln\frac{A_3}{1 - (1/\mu_r + \alpha_h
           f(B_r))/f'(B_r)}$ (Hodgdon's closed forms for $A_1 \dots A_4$).
        5. $\alpha_h$, when not given (Hodgdon tabulates it with the material), is the
           smallest value for which the falling branch, integrated from the closure
           point, passes through the remanence point $(0, B_r)$ exactly.

        Conditions 3–4 place the slopes at the measured points; the branch passes
        through the remanence point exactly (5) and through the coercive point to within
        a few per cent for consistent data (the model has no sixth constant to enforce
        it too): check with `major_loop_points()`. As $\alpha_h \to \infty$ every
        condition holds in the limit (a loop with square corners); condition 5 picks
        the finite value that rounds the corners most.

        **Raises:** `ValueError` naming the value when the data are not a valid loop
        (non-positive values, remanence at or above closure, coercivity at or above the
        closure field, $\mu_s H_s \ge B_s$), and when no $\alpha_h$ satisfies 4–5 (pass
        `alpha_h`, or check $\mu_r$, $\mu_c$).
        """
        data = {
            "B_s": B_s,
            "H_s": H_s,
            "B_r": B_r,
            "H_c": H_c,
            "mu_r": mu_r,
            "mu_c": mu_c,
            "mu_s": mu_s,
        }
        if alpha_h is not None:
            data["alpha_h"] = alpha_h
        values = {}
        for name, value in data.items():
            try:
                number = float(np.asarray(value))
            except (TypeError, ValueError) as e:
                raise TypeError(
                    f"from_major_loop: `{name}` must be a real number, got {value!r}."
                ) from e
            if not math.isfinite(number) or number <= 0:
                what = {
                    "H_c": "the coercivity `H_c` (A/m) must be positive",
                    "B_r": "the remanence `B_r` (T) must be positive",
                }.get(name, f"`{name}` must be positive and finite")
                raise ValueError(f"from_major_loop: {what}, got {name} = {number}.")
            values[name] = number
        v = values
        if v["B_r"] >= v["B_s"]:
            raise ValueError(
                f"from_major_loop: the remanence B_r = {v['B_r']} T must lie below the "
                f"closure (saturation) induction B_s = {v['B_s']} T."
            )
        if v["H_c"] >= v["H_s"]:
            raise ValueError(
                f"from_major_loop: the coercivity H_c = {v['H_c']} A/m must lie below "
                f"the closure field H_s = {v['H_s']} A/m."
            )
        if v["mu_s"] * v["H_s"] >= v["B_s"]:
            raise ValueError(
                f"from_major_loop: the closure permeability mu_s = {v['mu_s']} H/m must "
                f"be below the secant B_s/H_s = {v['B_s'] / v['H_s']} H/m (the loop "
                "flattens towards saturation)."
            )
        with jax.ensure_compile_time_eval():
            return _from_major_loop(**v)


def has_wrapped_fields(module: eqx.Module, exclude: tuple[str, ...] = ()) -> bool:
    """Whether a numeric field holds a module (a fitting constraint such as `Positive`)
    rather than an array; `exclude` names fields that are modules by design."""
    return any(
        isinstance(getattr(module, f.name), eqx.Module)
        for f in dataclasses.fields(module)
        if f.name not in exclude
    )


def smooth_sign(x: Float[ArrayLike, "*shape"], scale) -> Float[Array, "*shape"]:
    r"""$\mathrm{sgn}(x)$ for `scale` = 0, else $\tanh(x/\text{scale})$."""
    x = jnp.asarray(x)
    smooth = scale > 0
    safe = jnp.where(smooth, scale, 1.0)
    return jnp.where(smooth, jnp.tanh(x / safe), jnp.sign(x))


def field_slope(material: HodgdonMaterial, demagnetising_factor, B, H_a, direction):
    r"""$dH_a/dB$ of a magnetic circuit with applied field $H_a$ [A/m] and (SI)
    demagnetising factor $N$: $H = (H_a - N B/\mu_0)/(1 - N)$ and
    $dH_a/dB = (1 - N)\,dH/dB + N/\mu_0$."""
    N = demagnetising_factor
    H = (H_a - N * B / MU_0) / (1 - N)
    return (1 - N) * material.branch_slope(B, H, direction) + N / MU_0


def trace_induction(material, demagnetising_factor, applied, B0, substeps):
    """$B$ along a piecewise-linear applied-field history (RK4 in $H_a$)."""

    def segment(B, pair):
        h0, h1 = pair
        step = (h1 - h0) / substeps
        direction = jnp.sign(h1 - h0)

        def slope(h, B, args):
            return 1.0 / field_slope(material, demagnetising_factor, B, h, direction)

        def one(k, B):
            return rk4_step(slope, h0 + k * step, B, step, None)

        B = jax.lax.fori_loop(0, substeps, one, B)
        return B, B

    _, Bs = jax.lax.scan(segment, B0, (applied[:-1], applied[1:]))
    return jnp.concatenate([B0[None], Bs])


def _integrate_H_of_B(material, B0, H0, B1, steps):
    """$H$ at $B_1$ on the branch through $(B_0, H_0)$ (direction from $B_0$ to $B_1$)."""
    direction = jnp.sign(B1 - B0)
    h = (B1 - B0) / steps

    def slope(B, H, args):
        return material.branch_slope(B, H, direction)

    def one(k, H):
        return rk4_step(slope, B0 + k * h, H, h, None)

    return jax.lax.fori_loop(0, steps, one, H0)


def _integrate_B_of_H(material, B0, H0, H1, steps):
    """$B$ at $H_1$ on the branch through $(B_0, H_0)$."""
    return trace_induction(material, 0.0, jnp.stack([H0, H1]), B0, steps)[-1]


def _closure_constants(B_s, H_s, mu_s):
    """$A_1, A_2$ from conditions 1–2: the root $y = 2A_2B_s$ of $\\sin y / y = r$
    (decreasing from 1 to 0 on $(0, \\pi)$), by bisection in float64."""
    r = mu_s * H_s / B_s
    lo, hi = 0.0, math.pi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if math.sin(mid) / mid > r:
            lo = mid
        else:
            hi = mid
    A2 = 0.5 * (lo + hi) / (2 * B_s)
    return H_s / math.tan(A2 * B_s), A2


def _slope_constants(alpha, A1, A2, B_s, B_r, H_c, mu_r, mu_c):
    """$A_3$ and $A_4$ from conditions 3–4 at a given $\\alpha_h$ (nan where $A_4$ does
    not exist)."""
    A3 = 1 - (1 / mu_c + alpha * H_c) / (A1 * A2)
    f_r = A1 * jnp.tan(A2 * B_r)
    fp_r = A1 * A2 / jnp.cos(A2 * B_r) ** 2
    ratio = A3 / (1 - (1 / mu_r + alpha * f_r) / fp_r)
    A4 = jnp.where(ratio > 0, (B_s - B_r) / B_r * jnp.log(jnp.abs(ratio)), jnp.nan)
    return A3, A4


_BRANCH_STEPS = 1000  # RK4 steps over [B_r, B_s] (alpha_h * step < 1 below 1e3 B_s/ T)


@jax.jit
def _remanence_residual(alpha, A1, A2, B_s, B_r, H_c, mu_r, mu_c, mu_s):
    """$H$ [A/m] of the falling branch at $B = B_r$, divided by $H_c$ (0 when the
    branch passes through the remanence point)."""
    A3, A4 = _slope_constants(alpha, A1, A2, B_s, B_r, H_c, mu_r, mu_c)
    material = HodgdonMaterial(A1, A2, A3, A4, alpha, B_s, mu_s)
    H = _integrate_H_of_B(material, B_s, A1 * jnp.tan(A2 * B_s), B_r, _BRANCH_STEPS)
    return H / H_c


def _from_major_loop(*, B_s, H_s, B_r, H_c, mu_r, mu_c, mu_s, alpha_h=None):
    A1, A2 = _closure_constants(B_s, H_s, mu_s)
    args = (A1, A2, B_s, B_r, H_c, mu_r, mu_c)
    if alpha_h is None:
        alpha_h = _solve_alpha(args, mu_s)
    A3, A4 = _slope_constants(jnp.asarray(alpha_h), *args)
    if not (np.isfinite(float(A4)) and float(A4) > 0 and float(A3) < 1):
        raise ValueError(
            f"from_major_loop: with alpha_h = {float(alpha_h):.4g} 1/T the remanence "
            f"slope mu_r = {mu_r} H/m gives A3 = {float(A3):.4g}, A4 = {float(A4):.4g}; "
            "Hodgdon's functions need A3 < 1 and A4 > 0. Use a larger alpha_h, or check "
            "mu_r and mu_c."
        )
    return HodgdonMaterial(A1, A2, A3, A4, alpha_h, B_s, mu_s)


def _solve_alpha(args, mu_s) -> float:
    A1, A2, B_s, B_r, H_c, mu_r, mu_c = args
    # Condition 4 needs A4 > 0, i.e. ratio > 1 in _slope_constants. A log grid from
    # the field scale up to where the RK4 branch integration stays accurate: alpha_h
    # times the step in B below 1.
    grid = np.geomspace(0.1 / B_s, 0.8 * _BRANCH_STEPS / B_s, 160)
    A4s = np.asarray(_slope_constants(jnp.asarray(grid), *args)[1])
    feasible = np.isfinite(A4s) & (A4s > 0)
    residual = jax.vmap(
        lambda a: _remanence_residual(a, A1, A2, B_s, B_r, H_c, mu_r, mu_c, mu_s)
    )
    values = np.where(feasible, np.asarray(residual(jnp.asarray(grid))), np.nan)
    # The smallest alpha where the branch crosses the remanence point from above.
    crossings = np.nonzero((values[:-1] > 0) & (values[1:] <= 0))[0]
    if crossings.size == 0:
        closest = H_c * np.nanmin(np.abs(values)) if np.any(feasible) else np.nan
        raise ValueError(
            "from_major_loop: no alpha_h makes Hodgdon's falling branch pass through "
            f"the remanence point (0, B_r = {B_r} T) with the slopes mu_r = {mu_r} H/m "
            f"and mu_c = {mu_c} H/m (the branch's H at B_r comes no closer to 0 than "
            f"{closest:.3g} A/m). Check the data, or give alpha_h."
            if np.any(feasible)
            else "from_major_loop: the permeabilities mu_r = "
            f"{mu_r} H/m and mu_c = {mu_c} H/m admit no A4 > 0 for any alpha_h "
            "(Hodgdon's g would grow towards saturation); check them."
        )
    # Bisection in log(alpha_h) inside the bracket (float64 on the host; each
    # evaluation is one compiled branch integration).
    lo, hi = math.log(grid[crossings[0]]), math.log(grid[crossings[0] + 1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        value = float(
            _remanence_residual(math.exp(mid), A1, A2, B_s, B_r, H_c, mu_r, mu_c, mu_s)
        )
        if value > 0:
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))
