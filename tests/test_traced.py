"""Traced programs kept on disk (`jaxmr/_traced.py`): a program read back gives the
same bits as the one traced; what the key cannot describe by value is traced as
usual and never written; a static value of another value is another program; a
damaged file is ignored and written again.

One small Dahl fit (two runs of 41 samples, 2 steps) serves every test: a fit calls
all four kept programs (the solver's initial state and its step, the reported
simulation, the statistics' Jacobian)."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
from jaxmr import _traced
from jaxmr._identify import residual as residual_module

from .helpers import dahl_guess, dahl_runs


@functools.cache
def _runs():
    return dahl_runs((5.0, 8.0), (2.0, 3.0), samples=41)


def _fit():
    result = jaxmr.fit(dahl_guess(), _runs(), progress=False, max_steps=2)
    return result.values, result.std_errors, result.rmse, result.loss


@pytest.fixture
def fresh_memory(monkeypatch):
    """No program held in this process: each is read from disk (or traced)."""
    monkeypatch.setattr(_traced, "_MEMORY", {})


def _kept(folder):
    return sorted(p.name for p in folder.glob("*.jaxexport")) if folder.is_dir() else []


def test_a_program_read_back_gives_the_same_bits(tmp_path, fresh_memory, monkeypatch):
    plain = _fit()
    with _traced.traced_programs_in(tmp_path):
        first = _fit()
    kept = _kept(tmp_path)
    # The solver's initial state and its step, the reported simulation and the
    # statistics' Jacobian.
    assert len(kept) == 4, kept
    # A later process: nothing in memory, nothing exported again (it would raise).
    monkeypatch.setattr(_traced, "_MEMORY", {})

    def refuse(*args, **kwargs):
        raise AssertionError("a kept program was traced and exported again")

    monkeypatch.setattr(jax.export, "export", refuse)
    with _traced.traced_programs_in(tmp_path):
        again = _fit()
    assert _kept(tmp_path) == kept
    # Bit for bit: the same lowered programs, compiled alike.
    for a, b in ((plain, first), (first, again)):
        assert jax.tree.structure(a) == jax.tree.structure(b)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # Only within the block: afterwards the library writes nothing.
    assert _traced._FOLDER is None


def test_what_the_key_cannot_describe_is_traced_as_usual(tmp_path, fresh_memory):
    # A closure (its captured values are not in its name), a class of the user's
    # (its code is not in the key), an object with no description by value.
    scale = 2.0
    closure = lambda x: scale * x  # noqa: E731

    class Users(eqx.Module):
        a: float = 1.0

    for unknown in (closure, Users(), object()):
        with pytest.raises(_traced._Unknown):
            _traced._describe(unknown)
    # jaxmr's own function is described by its name; a NumPy array by its bytes.
    assert _traced._describe(residual_module.residuals) == (
        "jaxmr._identify.residual.residuals"
    )
    a, b = np.arange(3.0), np.arange(3.0) + 1e-12
    assert _traced._describe(a) != _traced._describe(b)

    @_traced.cached(lambda f, x: 0)
    def apply(f, x):
        return f(x)

    x = jnp.arange(3.0)
    with _traced.traced_programs_in(tmp_path):
        np.testing.assert_array_equal(np.asarray(apply(closure, x)), 2.0 * np.arange(3))
    assert _kept(tmp_path) == []


def test_another_static_value_is_another_program(tmp_path, fresh_memory):
    @_traced.cached(lambda x, power: 0)
    def raised(x, power):
        return x**power

    x = jnp.arange(4.0)
    with _traced.traced_programs_in(tmp_path):
        squares = np.asarray(raised(x, 2))
        cubes = np.asarray(raised(x, 3))
        # Another shape: another program too.
        longer = np.asarray(raised(jnp.arange(5.0), 2))
    np.testing.assert_array_equal(squares, np.arange(4.0) ** 2)
    np.testing.assert_array_equal(cubes, np.arange(4.0) ** 3)
    np.testing.assert_array_equal(longer, np.arange(5.0) ** 2)
    assert len(_kept(tmp_path)) == 3


def test_a_damaged_file_is_written_again(tmp_path, fresh_memory, monkeypatch):
    @_traced.cached(lambda x: 0)
    def double(x):
        return 2 * x

    x = jnp.arange(3.0)
    with _traced.traced_programs_in(tmp_path):
        double(x)
    (path,) = tmp_path.glob("*.jaxexport")
    path.write_bytes(path.read_bytes()[:100])  # truncated, as by a full disk
    monkeypatch.setattr(_traced, "_MEMORY", {})
    with _traced.traced_programs_in(tmp_path):
        np.testing.assert_array_equal(np.asarray(double(x)), [0.0, 2.0, 4.0])
    assert path.stat().st_size > 100  # written whole again


def test_fit_each_s_chunked_step_is_kept_and_gives_the_same_bits(
    tmp_path, fresh_memory
):
    # `fit_each` steps its problems in chunks inside `shard_map` over the devices (one
    # in the test session): that program too is exported, and read back gives the
    # same fits.
    runs = dahl_runs((3.0, 8.0), (1.0, 3.0), samples=41)

    def values():
        results = jaxmr.fit_each(dahl_guess(), runs, progress=False, max_steps=3)
        return [r.values for r in results]

    plain = values()
    with _traced.traced_programs_in(tmp_path):
        first = values()
    kept = _kept(tmp_path)
    # The column scale's Jacobian, the chunked initial state and step.
    assert len(kept) == 3, kept
    _traced._MEMORY.clear()
    with _traced.traced_programs_in(tmp_path):
        again = values()
    assert _kept(tmp_path) == kept
    for a, b, c in zip(plain, first, again, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(b, c)
