"""Export of a tuned controller: the C99 that `jaxmr.export_c` writes, compiled with
the system C compiler, gives the JAX controller's commands on the same measurements
(to 1e-9 A) and the same comfort in the closed loop; the StableHLO program that
`jaxmr.export_stablehlo` writes gives them too; neither overwrites a file."""

import sys
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.metrics
from jaxmr._cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _compile_c import CompiledController  # noqa: E402

T = 0.5  # [s] of road for the closed-loop runs
DT = 1e-3  # [s] the controllers' sample time (Sampling's default)
# C and JAX evaluate the same operations in the same order in float64; they differ
# only where libm and XLA round a transcendental function (pow, exp, tanh, log1p)
# differently, by an ulp or so, which the filters and the observer carry along
# without growth (all contract). 1e-9 A is what the issue asks; the measured gap is
# some 1e-15 A.
COMMAND_TOLERANCE = 1e-9


def _observer_based(law, damper=None, gain=0.1):
    return jaxmr.ObserverBasedController(
        law,
        estimator=jaxmr.VelocityEstimator(),
        observer=jaxmr.DamperObserver(
            jaxmr.passenger_car_mr_damper() if damper is None else damper, gain=gain
        ),
    )


def _replay(controller, names, inputs):
    """The JAX controller's states and its commands [A] on the rows of `inputs`
    (`jaxmr.replay`: its `init` at the first, then one call per row), as
    `simulate_system` runs it."""
    commands, states = jaxmr.replay(
        controller, {n: inputs[:, i] for i, n in enumerate(names)}
    )
    return states, commands


class _Margin(jaxmr.AbstractController):
    """A stateless on/off `law`'s commands; its state the smallest |ŝ| so far, with
    the angular switching function ŝ = 2ab / (a² + b²) of the law's factors (a, b) =
    `factors(law, readings)` (dimensionless, in [0, 1]): how near its decisions came
    to its switch ab = 0. A factor exactly 0 counts as far (inf): H(0) = 1 is then
    exact arithmetic in C and JAX alike (the estimator's velocities are 0 at the
    first sample)."""

    law: jaxmr.AbstractController
    factors: Callable = eqx.field(static=True)

    @property
    def i_max(self):
        return self.law.i_max

    @property
    def reads_positions(self):
        # The law's: an estimator estimates the positions it reads.
        return getattr(self.law, "reads_positions", False)

    def init(self, measurement):
        return jnp.asarray(jnp.inf)

    def __call__(self, measurement, state, plant):
        command, _ = self.law(measurement, (), plant)
        a, b = self.factors(self.law, measurement)
        product = a * b
        s_hat = 2 * product / jnp.where(product == 0, 1.0, a**2 + b**2)
        margin = jnp.where(product == 0, jnp.inf, jnp.abs(s_hat))
        return command, jnp.minimum(state, margin)


def _compiled(controller, folder, name, names):
    jaxmr.export_c(controller, folder, name=name, measurements=names)
    return CompiledController(folder, name)


def _synthetic(names, samples=1500, seed=0):
    """Readings of a suspension stroking at 1.3 and 9 Hz, with noise and biases: the
    deflection [m], the accelerations [m/s²] and a damper force [N]."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * DT
    w1, w2 = 2 * np.pi * 1.3, 2 * np.pi * 9.0
    x = 0.01 * np.sin(w1 * t) + 0.002 * np.sin(w2 * t)
    v = 0.01 * w1 * np.cos(w1 * t) + 0.002 * w2 * np.cos(w2 * t)
    signals = {
        "damper_displacement": x + 1e-4 * rng.standard_normal(samples),
        "body_acceleration": -0.3 * w1**2 * x
        + 0.1
        + 0.05 * rng.standard_normal(samples),
        "wheel_acceleration": 0.7 * w2**2 * x
        - 0.5
        + 0.3 * rng.standard_normal(samples),
        "damper_force": 600 * np.tanh(v / 0.02)
        + 900 * v
        + 5 * rng.standard_normal(samples),
    }
    # The quarter car's state [m, m/s], measured (a full-state law), the body
    # moving at 1.3 Hz and the wheel by the deflection below it.
    body = 0.004 * np.sin(w1 * t + 0.5)
    body_velocity = 0.004 * w1 * np.cos(w1 * t + 0.5)
    signals |= {
        "body_position": body,
        "body_velocity": body_velocity,
        "wheel_position": body - signals["damper_displacement"],
        "wheel_velocity": body_velocity - v,
        "damper_velocity": v + 1e-3 * rng.standard_normal(samples),
    }
    return np.stack([signals[n] for n in names], axis=1)


# -- the recorded closed loop ----------------------------------------------------------


@pytest.fixture(scope="module")
def car():
    return jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())


@pytest.fixture(scope="module")
def skyhook():
    # Relaxed: the closed loop's comfort is then continuous in the commands.
    return _observer_based(jaxmr.Skyhook(2000.0, 1.0, temperature=0.1))


@pytest.fixture(scope="module")
def recorded(car, skyhook):
    """A closed-loop run on the car's realistic sensors: the readings the controller
    got (samples x measurements, in `names` order) and the run."""
    sensors = jaxmr.realistic_sensors(car)
    road = jaxmr.iso8608_road("C", 20.0, T, jax.random.key(0))
    sol = jaxmr.simulate_system(
        car, road, skyhook, T, sensors=sensors, key=jax.random.key(1)
    )
    assert sol.measured is not None
    names = sensors.names
    inputs = np.stack([np.asarray(sol.measured[n]) for n in names], axis=1)
    return names, inputs, sol, road, sensors


def test_the_c_controller_gives_the_jax_commands_on_recorded_readings(
    tmp_path, skyhook, recorded
):
    names, inputs, sol, *_ = recorded
    c = _compiled(skyhook, tmp_path, "skyhook", names)
    ours = np.asarray(_replay(skyhook, names, jnp.asarray(inputs))[1])
    # The replay is the closed loop's controller: its commands are the run's.
    np.testing.assert_allclose(ours, np.asarray(sol.command), rtol=0, atol=1e-12)
    assert np.ptp(ours) > 0.25  # the law acts (a third of its range: measured 0.34)
    np.testing.assert_allclose(c.run(inputs), ours, rtol=0, atol=COMMAND_TOLERANCE)
    header = (tmp_path / "skyhook.h").read_text()
    assert "#define SKYHOOK_SAMPLE_PERIOD 0.001" in header
    assert "Sample period: 0.001 s" in header


@pytest.mark.parametrize("observer", [True, False])
def test_a_non_finite_reading_is_skipped_alike_in_c_and_jax(
    tmp_path, skyhook, recorded, observer
):
    """One NaN reading (a sensor's dropout) at sample 300: the command there is 0 A
    and the controller goes on from its state before it, in C and JAX alike (the C
    had taken the NaN into its filters and commanded 0 A for good, JAX NaN)."""
    names, inputs, *_ = recorded
    controller = (
        skyhook
        if observer
        else jaxmr.ObserverBasedController(
            jaxmr.OnOffSkyhook(1.0), estimator=jaxmr.VelocityEstimator()
        )
    )
    name = "dropout" if observer else "dropout_estimator"
    c = _compiled(controller, tmp_path, name, names)
    bad = np.array(inputs)
    bad[300, 1] = np.nan
    ours = np.asarray(_replay(controller, names, jnp.asarray(bad))[1])
    clean = np.asarray(_replay(controller, names, jnp.asarray(inputs))[1])
    assert ours[300] == 0.0 and np.all(np.isfinite(ours))
    np.testing.assert_array_equal(ours[:300], clean[:300])
    # It goes on commanding (not 0 A for good).
    assert np.ptp(ours[301:]) > 0.25
    np.testing.assert_allclose(c.run(bad), ours, rtol=0, atol=COMMAND_TOLERANCE)
    assert f"{name}_state.skipped counts such" in (tmp_path / f"{name}.h").read_text()


def test_the_default_inputs_are_in_the_sensors_order(tmp_path, car):
    """With an estimator and no `measurements=`, the C inputs are the car's
    realistic sensors in `Sensors.names` order, the order `sol.measured` is laid
    out in (the default had been another: a deflection read as an acceleration)."""
    controller = jaxmr.ObserverBasedController(
        jaxmr.OnOffSkyhook(1.0), estimator=jaxmr.VelocityEstimator()
    )
    jaxmr.export_c(controller, tmp_path, name="ordered")
    header = (tmp_path / "ordered.h").read_text()
    names = jaxmr.realistic_sensors(car).names
    for k, n in enumerate(names):
        assert f"#define ORDERED_IN_{n.upper()} {k} " in header


def test_replay_refuses_what_it_cannot_run(skyhook, recorded):
    names, inputs, *_ = recorded
    log = {n: inputs[:, i] for i, n in enumerate(names)}
    with pytest.raises(ValueError, match="1-D array of one length"):
        jaxmr.replay(skyhook, {**log, names[0]: inputs[:-1, 0]})
    with pytest.raises(KeyError, match="'damper_displacement' is not measured"):
        jaxmr.replay(skyhook, {n: c for n, c in log.items() if n != names[1]})
    # A law that inverts the damper with no observer: there is no device to read.
    with pytest.raises(Exception, match="no device to read"):
        jaxmr.replay(jaxmr.Skyhook(2000.0, 1.0), {"body_velocity": inputs[:, 0]})


class _CInTheLoop(jaxmr.AbstractController):
    """The compiled C controller as a jaxmr controller: its state the C struct's
    bytes, each step a pure callback (so that `simulate_system` may call it as it
    calls any controller)."""

    i_max: jax.Array
    names: tuple[str, ...] = eqx.field(static=True)
    c: CompiledController = eqx.field(static=True)

    def init(self, measurement):
        inputs = jnp.stack([measurement[n] for n in self.names])
        shape = jax.ShapeDtypeStruct((self.c.state_size,), jnp.uint8)
        return jax.pure_callback(self.c.init, shape, inputs)

    def __call__(self, measurement, state, plant):
        inputs = jnp.stack([measurement[n] for n in self.names])
        shapes = (
            jax.ShapeDtypeStruct((), inputs.dtype),
            jax.ShapeDtypeStruct(state.shape, state.dtype),
        )
        return jax.pure_callback(self.c.step, shapes, state, inputs)


def test_the_c_controller_in_the_loop_gives_the_same_comfort(
    tmp_path, car, skyhook, recorded
):
    names, _, sol, road, sensors = recorded
    c = _compiled(skyhook, tmp_path, "skyhook", names)
    in_the_loop = jaxmr.simulate_system(
        car,
        road,
        _CInTheLoop(jnp.asarray(1.0), names, c),
        T,
        sensors=sensors,
        key=jax.random.key(1),
        sampling=skyhook.sampling,
    )
    np.testing.assert_allclose(
        np.asarray(in_the_loop.command), np.asarray(sol.command), rtol=0, atol=1e-9
    )
    # Commands equal to 1e-9 A through a stable loop: the comfort figure agrees to
    # 1e-9 relative (measured: some 1e-15).
    ours, theirs = (float(jaxmr.metrics.comfort(s)) for s in (sol, in_the_loop))
    assert theirs == pytest.approx(ours, rel=1e-9)


# -- other laws and dampers, on synthetic readings -------------------------------------


def _rich_law(features, model=None):
    """`ForceFeedback.mlp` with width 16 and depth 1 (84 weights on three features),
    its weights drawn (its zero start would command nothing)."""
    law = jaxmr.ForceFeedback.mlp(
        (0.2, 2.0, 0.3),
        1.0,
        features=features,
        width=16,
        depth=1,
        key=jax.random.key(3),
        model=model,
    )
    leaves, tree = jax.tree.flatten(eqx.filter(law.network, eqx.is_array))
    keys = jax.random.split(jax.random.key(4), len(leaves))
    drawn = [0.5 * jax.random.normal(k, x.shape, x.dtype) for k, x in zip(keys, leaves)]
    network = eqx.combine(jax.tree.unflatten(tree, drawn), law.network)
    return eqx.tree_at(lambda f: f.network, law, network)


# The measured quarter-car state [m, m/s] of the full-state laws.
_STATE = ("body_position", "body_velocity", "wheel_position", "wheel_velocity")
_GAIN = jnp.array([4e4, 6000.0, -2e4, -1500.0])  # [N/m, N s/m, N/m, N s/m]


def _groundhook_factors(law, r):
    """OnOffGroundhook's switch: -wheel_velocity and damper_velocity [m/s]."""
    return -r["wheel_velocity"], r["damper_velocity"]


def _clipped_factors(law, r):
    """ClippedOptimal's switch: the lag f_c - f and the force f [N]."""
    force = r["damper_force"]
    return -(law.gain @ jnp.stack([r[n] for n in _STATE])) - force, force


@pytest.mark.parametrize(
    "case",
    [
        "mlp",
        "spencer",
        "on-off",
        "groundhook-dahl",
        "hybrid-lugre",
        "clipped-bingham",
        "on-off-groundhook",
        "clipped-on-off",
        "clipped-normalized",
        "skyhook-shear-thinning",
        "hybrid-bwbn",
        "clipped-on-off-estimated",
        "continuous-clipped-estimated",
    ],
)
def test_the_c_controller_gives_the_jax_commands(tmp_path, case):
    car_sensors = ("body_acceleration", "damper_displacement", "wheel_acceleration")
    factors = None  # a hard on/off law's switch, for its margin
    if case == "mlp":
        # The 84-weight law, inverting its own model (a stiffer unit of the same
        # family, other current laws) at the state of an observer corrected by a
        # load cell.
        stiffer = jaxmr.Damper(
            jaxmr.BoucWen(
                alpha=jaxmr.LinearLaw(4e4, 1.1e6),
                c0=jaxmr.PolynomialLaw(np.array([250.0, 1500.0, 300.0])),
                A=1.0,
                beta=400.0,
                gamma=600.0,
                n=1.5,
            )
        )
        features = ("body_velocity", "body_acceleration", "damper_velocity")
        controller = _observer_based(_rich_law(features, stiffer))
        names = car_sensors + ("damper_force",)
    elif case == "spencer":
        # Spencer's voltage-driven damper (its 190 1/s filter integrated by the
        # observer), corrected by a load cell, under the hard skyhook law. Its z is
        # stiff (d(dz/dt)/dz = -2 (beta + gamma) |u| z0 = -9e4 |u| 1/s): at 0.2 m/s
        # four RK4 substeps of 0.25 ms sit at RK4's stability edge, where each
        # substep amplifies a difference of one ulp (XLA's pow against libm's) and
        # the commands drift apart by 1e-8 A over the run, in C and JAX alike; 16
        # substeps keep h |lambda| < 0.6, and the two agree to 1e-13 A.
        controller = jaxmr.ObserverBasedController(
            jaxmr.Skyhook(1500.0, 2.25),
            estimator=jaxmr.VelocityEstimator(),
            observer=jaxmr.DamperObserver(jaxmr.spencer_1997(), gain=0.3, substeps=16),
        )
        names = car_sensors + ("damper_force",)
    elif case == "groundhook-dahl":
        # Relaxed groundhook on a Dahl damper with a coil lag, the observer corrected
        # by a load cell.
        dahl = jaxmr.Damper(
            jaxmr.Dahl(
                k_x=jaxmr.LinearLaw(900.0, 2000.0),
                k_w=jaxmr.LinearLaw(100.0, 500.0),
                rho=300.0,
            ),
            jaxmr.FirstOrderLag(60.0),
        )
        # Its estimator starts from calibrated biases [m/s²], not the first readings.
        controller = jaxmr.ObserverBasedController(
            jaxmr.Groundhook(1500.0, 1.0, temperature=0.1),
            estimator=jaxmr.VelocityEstimator(body_bias=0.05, wheel_bias=-0.02),
            observer=jaxmr.DamperObserver(dahl, gain=0.3),
        )
        names = car_sensors + ("damper_force",)
    elif case == "hybrid-lugre":
        # The hard hybrid law (both on/off gates) on a LuGre damper, load cell.
        lugre = jaxmr.LuGre(
            sigma0=1e5,
            sigma1=300.0,
            sigma2=jaxmr.LinearLaw(800.0, 1500.0),
            F_c=jaxmr.LinearLaw(100.0, 500.0),
            F_s=jaxmr.LinearLaw(150.0, 700.0),
            v_s=0.02,
        )
        controller = jaxmr.ObserverBasedController(
            jaxmr.Hybrid(2000.0, 0.6, 1.0),
            estimator=jaxmr.VelocityEstimator(),
            observer=jaxmr.DamperObserver(lugre, gain=0.3),
        )
        names = car_sensors + ("damper_force",)
    elif case == "clipped-bingham":
        # Relaxed continuous clipped-optimal on the measured state (no estimator)
        # through a stateless smoothed Bingham model.
        bingham = jaxmr.Bingham(
            f_c=jaxmr.LinearLaw(50.0, 600.0),
            c0=jaxmr.LinearLaw(900.0, 1500.0),
            velocity_scale=0.01,
        )
        controller = jaxmr.ObserverBasedController(
            jaxmr.ContinuousClippedOptimal(_GAIN, 1.0, temperature=0.1),
            observer=jaxmr.DamperObserver(bingham),
        )
        names = _STATE + ("damper_displacement", "damper_velocity")
    elif case == "on-off-groundhook":
        # The hard on/off groundhook on the estimated velocities.
        controller = jaxmr.ObserverBasedController(
            jaxmr.OnOffGroundhook(1.0), estimator=jaxmr.VelocityEstimator()
        )
        names = car_sensors
        factors = _groundhook_factors
    elif case == "clipped-on-off":
        # The hard on/off clipped-optimal law on the measured state and force.
        controller = jaxmr.ObserverBasedController(jaxmr.ClippedOptimal(_GAIN, 1.0))
        names = _STATE + ("damper_force",)
        factors = _clipped_factors
    elif case == "clipped-normalized":
        # Relaxed clipped-optimal without a load cell: it reads the force of the
        # observer's normalised Bouc-Wen model (the observer run open-loop).
        normalized = jaxmr.NormalizedBoucWen(
            kappa_x=1000.0,
            kappa_w=jaxmr.LinearLaw(100.0, 500.0),
            c0=jaxmr.LinearLaw(900.0, 1500.0),
            rho=1000.0,
            sigma=0.3,
            n=1.5,
            x0=1e-3,
            f0=20.0,
        )
        controller = jaxmr.ObserverBasedController(
            jaxmr.ClippedOptimal(_GAIN, 1.0, temperature=0.1),
            observer=jaxmr.DamperObserver(normalized),
        )
        names = _STATE + ("damper_displacement", "damper_velocity")
    elif case == "skyhook-shear-thinning":
        # Relaxed skyhook on Spencer's voltage-driven damper with thinning dashpots
        # (c0 halved at 0.2 m/s, c1 at 0.5 m/s), load cell; 16 substeps as for
        # Spencer's (above).
        spencer = jaxmr.spencer_1997()
        fields = ("alpha", "c0", "k0", "c1", "k1", "x0", "gamma", "beta", "A", "n")
        thinning = jaxmr.ShearThinningSpencer(
            **{f: getattr(spencer.hysteresis, f) for f in fields}, e0=5.0, e1=2.0
        )
        controller = jaxmr.ObserverBasedController(
            jaxmr.Skyhook(1500.0, 2.25, temperature=0.1),
            estimator=jaxmr.VelocityEstimator(),
            observer=jaxmr.DamperObserver(
                jaxmr.Damper(thinning, spencer.dynamics), gain=0.3, substeps=16
            ),
        )
        names = car_sensors + ("damper_force",)
    elif case == "hybrid-bwbn":
        # Relaxed hybrid on a Bouc-Wen-Baber-Noori damper that pinches and degrades
        # within the run (its energy state reaches some 6e-4 m^2 in size), load cell.
        bwbn = jaxmr.BoucWenBaberNoori(
            k=jaxmr.LinearLaw(1e5, 5e5),
            alpha=0.05,
            c=jaxmr.LinearLaw(800.0, 1500.0),
            A0=1.0,
            beta=4e5,
            gamma=6e5,
            n=2.0,
            f0=10.0,
            delta_nu=500.0,
            delta_eta=300.0,
            delta_A=200.0,
            zeta_s=0.5,
            p=1e3,
            q=0.1,
            psi=5e-4,
            delta_psi=0.5,
            lam=0.5,
        )
        controller = jaxmr.ObserverBasedController(
            jaxmr.Hybrid(6000.0, 0.6, 1.0, temperature=0.1),
            estimator=jaxmr.VelocityEstimator(),
            observer=jaxmr.DamperObserver(bwbn, gain=0.3),
        )
        names = car_sensors + ("damper_force",)
    elif case == "clipped-on-off-estimated":
        # The hard on/off clipped-optimal law on the car's sensors and a load cell:
        # the velocities and the positions estimated.
        controller = jaxmr.ObserverBasedController(
            jaxmr.ClippedOptimal(_GAIN, 1.0),
            estimator=jaxmr.VelocityEstimator(position_high_pass=0.2),
        )
        names = car_sensors + ("damper_force",)
        factors = _clipped_factors
    elif case == "continuous-clipped-estimated":
        # The hard continuous clipped-optimal law on the car's three sensors alone:
        # the state estimated, the damper's state observed (open loop).
        controller = _observer_based(jaxmr.ContinuousClippedOptimal(_GAIN, 1.0))
        names = car_sensors
    else:
        # No observer, no wheel accelerometer, another sample time and no delay.
        controller = jaxmr.ObserverBasedController(
            jaxmr.OnOffSkyhook(1.0, temperature=0.2),
            estimator=jaxmr.VelocityEstimator(crossover=3.0),
            sampling=jaxmr.Sampling(2e-3, 0),
        )
        names = ("damper_displacement", "body_acceleration")
    inputs = _synthetic(names)
    replayed = controller
    if factors is not None:  # the same commands, and the margin in the law's state
        margin = _Margin(controller.law, factors)
        replayed = eqx.tree_at(lambda c: c.law, controller, margin)
    states, ours = _replay(replayed, names, jnp.asarray(inputs))
    ours = np.asarray(ours)
    assert np.ptp(ours) > 0.3  # the law acts
    if factors is not None:
        # A hard switch: a decision that differed would be a gap of I_max. C and JAX
        # compute the factors to some 1e-13 relative (the continuous laws' commands
        # agree as closely), which moves |ŝ| by as much; no sample here comes within
        # 1e-6 of the switch (measured: 3e-3 groundhook, 8e-2 clipped-optimal, 8e-4
        # clipped-optimal on estimated positions), so every decision is the same in
        # both and the commands agree exactly.
        assert float(states.law[-1]) > 1e-6  # the smallest |ŝ| over the run
    c = _compiled(controller, tmp_path, "law", names)
    np.testing.assert_allclose(c.run(inputs), ours, rtol=0, atol=COMMAND_TOLERANCE)
    # The header says where an estimator runs without a wheel accelerometer.
    unmeasured = controller.estimator is not None and "wheel_acceleration" not in names
    header = (tmp_path / "law.h").read_text()
    assert ("No wheel accelerometer" in header) == unmeasured


# -- StableHLO -------------------------------------------------------------------------


def test_the_stablehlo_program_gives_the_jax_commands(tmp_path, skyhook, recorded):
    names, inputs, sol, *_ = recorded
    path = tmp_path / "skyhook.stablehlo"
    jaxmr.export_stablehlo(skyhook, path, measurements=names)
    program = jax.export.deserialize(bytearray(path.read_bytes()))

    @jax.jit
    def run(inputs):
        size = program.in_avals[0].shape[0]
        first = jnp.arange(inputs.shape[0]) == 0

        def one(state, row):
            command, state = program.call(state, row[1:], row[0] > 0)
            return state, command

        rows = jnp.concatenate([first[:, None].astype(inputs.dtype), inputs], axis=1)
        return jax.lax.scan(one, jnp.zeros(size, inputs.dtype), rows)[1]

    commands = np.asarray(run(jnp.asarray(inputs)))
    np.testing.assert_allclose(
        commands, np.asarray(sol.command), rtol=0, atol=COMMAND_TOLERANCE
    )


def test_a_float32_program_is_warned_of(tmp_path, skyhook, monkeypatch):
    monkeypatch.setattr(jnp, "result_type", lambda *a: np.dtype("float32"))
    with pytest.warns(UserWarning, match="export_stablehlo is running in float32"):
        with pytest.raises(Exception):  # noqa: B017 - only the warning matters here
            jaxmr.export_stablehlo(skyhook, tmp_path / "f32.stablehlo")


def test_an_open_loop_law_exports_on_the_clock_by_default(tmp_path):
    # An open-loop law reads only the time: its export's default input is the clock
    # (it failed with "'time' is not measured" before), and the program follows the
    # schedule sample by sample.
    schedule = jaxmr.CurrentSchedule(jnp.array([-2.0, 0.0, 3.0]), i_max=2.0, dt=0.01)
    controller = jaxmr.ObserverBasedController(schedule)
    path = tmp_path / "schedule.stablehlo"
    jaxmr.export_stablehlo(controller, path)
    program = jax.export.deserialize(bytearray(path.read_bytes()))
    assert program.in_avals[1].shape == (1,)  # the time alone
    state = jnp.zeros(program.in_avals[0].shape, jnp.float64)
    commands = [
        float(program.call(state, jnp.array([t]), jnp.array(k == 0))[0])
        for k, t in enumerate([0.0, 0.01, 0.02, 0.05])
    ]
    expected = 2.0 * jax.nn.sigmoid(jnp.array([-2.0, 0.0, 3.0, 3.0]))
    np.testing.assert_allclose(commands, expected, rtol=1e-14)
    # A constant current needs nothing else either.
    constant = jaxmr.ObserverBasedController(jaxmr.ConstantCurrent(0.5, 1.0))
    jaxmr.export_stablehlo(constant, tmp_path / "constant.stablehlo")


# -- files and refusals ----------------------------------------------------------------


def test_an_export_never_replaces_a_file_unless_forced(tmp_path, skyhook):
    source = tmp_path / "controller.c"
    source.write_text("mine")
    with pytest.raises(FileExistsError, match="force=True"):
        jaxmr.export_c(skyhook, tmp_path)
    assert source.read_text() == "mine"
    assert not (tmp_path / "controller.h").exists()  # nothing written
    header, written = jaxmr.export_c(skyhook, tmp_path, force=True)
    assert written == source and "controller_step" in source.read_text()
    assert header.name == "controller.h"
    with pytest.raises(FileExistsError):
        jaxmr.export_stablehlo(skyhook, header)
    # A file where the folder goes, or a folder where a file goes: named, and even
    # with force nothing is written (the pair whole or not at all).
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        jaxmr.export_c(skyhook, source, force=True)
    other = tmp_path / "other"
    (other / "controller.c").mkdir(parents=True)
    with pytest.raises(IsADirectoryError, match="is a folder"):
        jaxmr.export_c(skyhook, other, force=True)
    assert not (other / "controller.h").exists()


class _Viscous(jaxmr.AbstractHysteresis):
    """A user's own damper model, F = c v (c [N s/m]), which no C writer knows."""

    c: float

    def rates(self, state, x, v):
        return state

    def force(self, state, x, v):
        return self.c * v


def test_what_has_no_c_writer_says_so(skyhook):
    # Each refusal names the class and what is supported.
    power = _observer_based(jaxmr.PowerDrivenDamper(1000.0, 1.0))
    with pytest.raises(
        NotImplementedError, match="PowerDrivenDamper.*supported: Sky.*ClippedOptimal"
    ):
        jaxmr.export_c(power, "unused")
    with pytest.raises(NotImplementedError, match="_Viscous.*Dahl, LuGre, Bingham"):
        jaxmr.export_c(
            _observer_based(jaxmr.Skyhook(2000.0, 1.0), damper=_Viscous(900.0)),
            "unused",
        )
    with pytest.raises(NotImplementedError, match="ObserverBasedController"):
        jaxmr.export_c(jaxmr.Skyhook(2000.0, 1.0), "unused")
    with pytest.raises(ValueError, match="C identifier"):
        jaxmr.export_c(skyhook, "unused", name="my-law")


def test_the_command_line_exports_a_saved_controller(tmp_path, skyhook):
    saved = tmp_path / "skyhook.json"
    jaxmr.save_model(skyhook, saved)
    out = tmp_path / "out"
    assert main(["export", saved, "--out", out, "--name", "sky", "--stablehlo"]) == 0
    assert {p.name for p in out.iterdir()} == {"sky.h", "sky.c", "sky.stablehlo"}
    assert main(["export", saved, "--out", out, "--name", "sky"]) == 1  # exists
    assert main(["export", saved, "--out", out, "--name", "sky", "--force"]) == 0
