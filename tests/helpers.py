"""Shared test utilities: tree comparison, finite differences, and the model cases every
generic test runs over (add a model to `MODEL_CASES` and it is tested)."""

import dataclasses
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxmr

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# A Spencer model that `jaxmr.fit` found on three UTFSM files (2mm5Hz0A, 5mm3Hz0x25A,
# 5mm3Hz1A; the "spencer" template, 30 steps, NRMSE 0.085-0.100), its values rounded
# to 4-5 digits and kept here because the fit takes 30 s. Its state relaxes within
# ~0.1 mm of travel (A = 1e4 1/m): stiff where the passenger car drives it fast (an
# ISO C road at ~2 m/s needs 64 substeps where `FixedStep()`'s 4 diverge).
FITTED_SPENCER = jaxmr.Spencer(
    alpha=jaxmr.LinearLaw(168.4, 775.5),
    c0=jaxmr.LinearLaw(0.02475, 6713.3),
    k0=0.0,
    c1=jaxmr.LinearLaw(7743.2, 118746.5),
    k1=9.221,
    x0=-0.2904,
    gamma=8739.5,
    beta=0.6274,
    A=1e4,
    n=3.1838,
)


def shared_data(*parts: str) -> Path:
    """A path in the public datasets beside the repository; missing data is a
    failure, not a skip."""
    path = SHARED_DATA.joinpath(*parts)
    assert path.exists(), (
        f"test data missing: {path}. The public datasets must lie in ../shared/data "
        "beside the repository (see that folder's README)."
    )
    return path


def tree_allclose(x, y, *, rtol=1e-5, atol=1e-8) -> bool:
    xs, ys = (
        jax.tree.leaves(eqx.filter(x, eqx.is_array)),
        jax.tree.leaves(eqx.filter(y, eqx.is_array)),
    )
    if len(xs) != len(ys):
        return False
    return all(
        a.shape == b.shape and np.allclose(a, b, rtol=rtol, atol=atol)
        for a, b in zip(xs, ys, strict=True)
    )


def finite_difference_jvp(fn: Callable, x, tangent, *, eps: float = 1e-6):
    """Central difference of `fn` at pytree `x` along pytree `tangent`: error O(eps²)."""
    plus = jax.tree.map(lambda a, t: a + eps * t, x, tangent)
    minus = jax.tree.map(lambda a, t: a - eps * t, x, tangent)
    return (fn(plus) - fn(minus)) / (2 * eps)


def relative_tangent(arrays, seed: int = 0):
    """A random direction scaled to each parameter's magnitude (so a step of eps is a
    relative change of about eps in every parameter)."""
    leaves, treedef = jax.tree.flatten(arrays)
    keys = jax.random.split(jax.random.key(seed), len(leaves))
    out = [
        jax.random.uniform(k, a.shape, a.dtype, 0.5, 1.0) * jnp.where(a == 0, 1.0, a)
        for k, a in zip(keys, leaves, strict=True)
    ]
    return jax.tree.unflatten(treedef, out)


@dataclasses.dataclass(frozen=True)
class ModelCase:
    """One model in a setting where it is exercised: reversals, a z = 0 start, and for
    Bouc–Wen an exponent below 1."""

    name: str
    device: Callable[[], object]
    motion: Callable[[], jaxmr.AbstractSignal]
    current: Callable[[], object]
    ts: Callable[[], jax.Array]
    substeps: int  # fixed-step substeps that keep RK4 stable and accurate here

    def __repr__(self):
        return self.name


def _brake_ts():
    return jnp.linspace(0.0, 1.5, 151)


def _brake_motion():
    return jaxmr.Sine(jnp.deg2rad(3.5), 1.0)


MODEL_CASES = (
    ModelCase(
        "bingham_smooth",
        lambda: jaxmr.Bingham(
            f_c=jaxmr.LinearLaw(0.1, 0.2), c0=0.002, f0=0.01, velocity_scale=0.05
        ),
        _brake_motion,
        lambda: 0.5,
        _brake_ts,
        2,
    ),
    ModelCase(
        "bouc_wen_sas_brake",
        jaxmr.sas_brake_bouc_wen,
        _brake_motion,
        lambda: 0.5,
        _brake_ts,
        20,
    ),
    ModelCase(
        "normalized_bouc_wen",
        lambda: jaxmr.NormalizedBoucWen(
            kappa_x=0.5, kappa_w=1.2, c0=0.01, rho=300.0, sigma=0.7, n=1.5
        ),
        _brake_motion,
        lambda: 0.0,
        _brake_ts,
        10,
    ),
    ModelCase(
        "dahl_sas_brake",
        jaxmr.sas_brake_dahl,
        _brake_motion,
        lambda: 1.0,
        _brake_ts,
        2,
    ),
    ModelCase(
        "lugre",
        lambda: jaxmr.LuGre(
            sigma0=2.0e4,
            sigma1=5.0,
            sigma2=jaxmr.LinearLaw(200.0, 400.0),
            F_c=jaxmr.LinearLaw(20.0, 80.0),
            F_s=jaxmr.LinearLaw(30.0, 100.0),
            v_s=0.01,
        ),
        lambda: jaxmr.Sine(0.005, 2.0),
        lambda: 0.5,
        lambda: jnp.linspace(0.0, 0.75, 151),
        20,
    ),
    ModelCase(
        "spencer_1997",
        jaxmr.spencer_1997,
        lambda: jaxmr.Sine(0.015, 2.5),
        lambda: 1.0,
        lambda: jnp.linspace(0.0, 0.4, 201),
        40,
    ),
    ModelCase(
        "bwbn_pinched_degrading",
        lambda: jaxmr.BoucWenBaberNoori(
            k=2.0e5,
            alpha=0.05,
            c=jaxmr.LinearLaw(500.0, 1000.0),
            A0=1.0,
            beta=jaxmr.LinearLaw(2.0e5, 1.0e5),
            gamma=3.0e5,
            n=1.5,
            f0=5.0,
            delta_nu=1.0e5,
            delta_eta=1.0e5,
            delta_A=1.0e4,
            zeta_s=0.8,
            p=1.0e6,
            q=0.1,
            psi=1.0e-4,
            delta_psi=10.0,
            lam=0.5,
        ),
        lambda: jaxmr.Sine(0.001, 1.0),
        lambda: 0.3,
        lambda: jnp.linspace(0.0, 1.5, 151),
        10,
    ),
    ModelCase(
        "bouc_wen_with_lag_and_current_steps",
        lambda: jaxmr.Damper(jaxmr.sas_brake_bouc_wen(), jaxmr.FirstOrderLag(100.0)),
        _brake_motion,
        lambda: jaxmr.Steps(jnp.array([0.0, 0.3, 0.9]), jnp.array([0.0, 1.0, 0.5])),
        _brake_ts,
        20,
    ),
    ModelCase(
        "mrb_107_3_magnetic",
        lambda: jaxmr.mrb_107_3(velocity_scale=0.05, sign_scale=1e-3),
        lambda: jaxmr.Sine(0.5, 1.0),
        lambda: jaxmr.Sine(0.4, 2.0, offset=0.5),
        lambda: jnp.linspace(0.0, 1.0, 101),
        4,
    ),
)


def dahl_runs(rhos, k_ws, samples: int = 101, substeps: int = 4, rotary: bool = True):
    """One experiment per (rho, k_w): a Dahl brake, 1 Hz ±20°, one cycle of
    `samples` samples, 1 % noise, simulated with `substeps` RK4 steps a sample;
    `rotary`: whether the runs say they are a brake's (see below)."""
    ts = jnp.linspace(0.0, 1.0, samples)
    motion = jaxmr.Sine(jnp.deg2rad(20.0), 1.0)
    rng = np.random.default_rng(1)
    runs = []
    for rho, k_w in zip(rhos, k_ws):
        # Fixed RK4 steps (by default four per sample, 2.5 ms; the torque within
        # 1e-7 of k_w of the adaptive solve's, far below the noise): these are the
        # data, not what is tested, and fixed steps compile in a fraction of the
        # adaptive solve's time (3 s against 12 s, in every process that calls this).
        sol = jaxmr.simulate(
            jaxmr.Dahl(k_x=0.01, k_w=k_w, rho=rho),
            motion,
            0.0,
            ts,
            integrator=jaxmr.FixedStep(substeps),
        )
        force = np.asarray(sol.force)
        runs.append(
            SimpleNamespace(
                t=np.asarray(ts),
                x=np.asarray(sol.displacement),
                v=np.asarray(sol.velocity),
                current=np.zeros(ts.shape),
                force=force + 0.01 * np.std(force) * rng.standard_normal(force.shape),
                name=f"rho={rho}",
                # A brake: angle [rad], torque [N·m]. Fitted with a rotary device's
                # steps (0.5 ms, 20 a sample); read as a linear damper's, ±20° would
                # be ±0.35 m at up to 2.2 m/s, and the 25 µm travel limit would take
                # 576 steps a sample on average (29 times the runtime, same fits).
                rotary=rotary,
            )
        )
    return runs


def dahl_guess():
    P = jaxmr.Positive
    return jaxmr.Dahl(k_x=P(0.02), k_w=P(2.0), rho=P(8.0))
