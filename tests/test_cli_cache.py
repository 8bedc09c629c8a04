"""The command line's persistent compilation cache (`jaxmr/_cli/cache.py`): where it
lives and when it is on, and that a second `jaxmr fit` of the same files reads the
first one's compiled programs back instead of compiling them.

The two fits run as programs of their own (subprocesses): JAX opens its cache once
per process, and the test's own process must not get one. Each fits a Dahl model to
two short files (0.5 s at 250 Hz) for two steps: seconds of compilation, little else.
"""

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np
import pytest

import jaxmr
import jaxmr.data
from jaxmr._cli import cache

ROOT = Path(__file__).resolve().parents[1]

# A second run: its compilation events counted (`jax.monitoring`, JAX's public hooks)
# while the command runs; the CPU configured as the program configures it, so that
# its programs are the first run's.
_COUNTING_RUN = """
import json, sys
from jaxmr.devices import configure_cpu
configure_cpu()
import jax.monitoring
events = {"hits": 0, "backend_compile_s": 0.0, "traced": []}
def count(event, **kwargs):
    if event == "/jax/compilation_cache/cache_hits":
        events["hits"] += 1
def duration(event, seconds, fun_name="", **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        events["backend_compile_s"] += seconds
    if event == "/jax/core/compile/jaxpr_trace_duration":
        events["traced"].append(fun_name)
jax.monitoring.register_event_listener(count)
jax.monitoring.register_event_duration_secs_listener(duration)
from jaxmr._cli import main
events["status"] = main(sys.argv[1:])
print("EVENTS " + json.dumps(events))
"""


def _files(folder: Path) -> list[Path]:
    """Two files, 0 and 1 A: 10 mm at 2 Hz, a viscous force and a smoothed Coulomb
    friction (the Dahl model's steady sliding), 1 % noise."""
    t = np.linspace(0.0, 0.5, 126)
    w = 2 * np.pi * 2.0
    x, v = 0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t)
    rng = np.random.default_rng(3)
    paths = []
    for current in (0.0, 1.0):
        force = (800 + 1500 * current) * v + (150 + 700 * current) * np.tanh(v / 0.01)
        force = force + 0.01 * np.std(force) * rng.standard_normal(t.shape)
        experiment = jaxmr.data.Experiment(
            t, x, v, current, force, name=f"{current:g} A"
        )
        path = folder / f"dahl_{current:g}A.csv"
        jaxmr.data.write_csv(experiment, path)
        paths.append(path)
    return paths


def _environment(**extra) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in (cache.ENV, "JAX_COMPILATION_CACHE_DIR", "XLA_FLAGS")
    }
    return env | extra


def _entries(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir() if p.name.endswith("-cache")}


def test_a_second_fit_reads_the_first_ones_programs(tmp_path):
    files = _files(tmp_path)
    fit = ["fit", "--model", "dahl", "--max-steps", "2", *map(str, files)]
    # The first, as the `jaxmr` program: the cache in the user's cache folder.
    home = tmp_path / "xdg"
    first = subprocess.run(
        [sys.executable, "-m", "jaxmr._cli", *fit, "--out", str(tmp_path / "a.json")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=_environment(XDG_CACHE_HOME=str(home)),
    )
    assert first.returncode == 0, first.stderr
    folder = home / "jaxmr" / "xla"
    assert f"compilation cache: {folder}" in first.stdout.splitlines()
    written = _entries(folder)
    assert written, "the first fit stored no compiled program"
    # And its traced programs (`jaxmr._traced`): the solver's initial state and its
    # step, the reported simulation, the statistics' Jacobian.
    programs = sorted((folder / cache.PROGRAMS).glob("*.jaxexport"))
    assert len(programs) == 4, programs
    # The second, with the folder from JAXMR_COMPILATION_CACHE.
    second = subprocess.run(
        [sys.executable, "-c", _COUNTING_RUN, *fit, "--out", str(tmp_path / "b.json")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=_environment(**{cache.ENV: str(folder)}),
    )
    assert second.returncode == 0, second.stderr
    (line,) = [x for x in second.stdout.splitlines() if x.startswith("EVENTS ")]
    events = json.loads(line.removeprefix("EVENTS "))
    assert events["status"] == 0
    # Every program the first fit stored was read back, and none compiled anew.
    assert events["hits"] >= len(written), (events, len(written))
    assert _entries(folder) == written
    # Nor was the model traced for them (`traced_once`: its residual, which the
    # solver's initial state needed for its length): they were read back.
    kept = {"_initial_states", "_step", "simulate", "value_and_jacobian_jit"}
    kept.add("traced_once")
    assert not kept & set(events["traced"]), events["traced"]
    assert sorted((folder / cache.PROGRAMS).glob("*.jaxexport")) == programs
    # The same fit: the same parameters.
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    assert a["model"] == b["model"]


class _Config(SimpleNamespace):
    """A stand-in for `jax.config` that records its updates."""

    def update(self, name, value):
        self.updates[name] = value


@pytest.fixture
def config(monkeypatch):
    recorded = _Config(jax_compilation_cache_dir=None, updates={})
    monkeypatch.setattr(jax, "config", recorded)
    monkeypatch.delenv(cache.ENV, raising=False)
    return recorded


def test_where_the_cache_lives_and_when_it_is_on(config, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    default = cache.default_folder()
    if sys.platform not in ("win32", "darwin"):
        assert default == tmp_path / "xdg" / "jaxmr" / "xla"
    # Called from Python with nothing asked: off, JAX's configuration untouched.
    assert cache.configure(None, program=False) is None and config.updates == {}
    # The option, made if missing, with every compilation stored.
    own = tmp_path / "own" / "cache"
    assert cache.configure(str(own), program=False) == own and own.is_dir()
    assert config.updates == {
        "jax_compilation_cache_dir": str(own),
        "jax_persistent_cache_min_compile_time_secs": 0.0,
    }
    # `off`, from the option or the variable, even for the program.
    config.updates.clear()
    assert cache.configure("off", program=True) is None
    monkeypatch.setenv(cache.ENV, "off")
    assert cache.configure(None, program=True) is None and config.updates == {}
    # The option before the variable, the variable before the default.
    monkeypatch.setenv(cache.ENV, str(tmp_path / "from_env"))
    assert cache.configure(str(own), program=True) == own
    assert cache.configure(None, program=True) == tmp_path / "from_env"
    monkeypatch.delenv(cache.ENV)
    # JAX's own folder (JAX_COMPILATION_CACHE_DIR) is kept as it is.
    config.updates.clear()
    config.jax_compilation_cache_dir = str(tmp_path / "jax_own")
    assert cache.configure(None, program=True) == tmp_path / "jax_own"
    assert config.updates == {}
    config.jax_compilation_cache_dir = None
    # The program's default: the user's cache folder.
    assert cache.configure(None, program=True) == default


def test_an_unusable_folder_turns_the_cache_off(config, tmp_path, capsys):
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    assert cache.configure(str(blocked / "cache"), program=True) is None
    assert config.updates == {}
    assert "compilation cache off: cannot make" in capsys.readouterr().err
