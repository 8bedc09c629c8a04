"""MkDocs hook: the documentation's figures, drawn at build time with jaxmr itself.

Every figure of the model gallery (and the quick example's) is simulated here with
`jaxmr.sweep` and drawn with `jaxmr.plot`, so the pages show what this checkout of
jaxmr computes. The PNGs are added to the site as generated files (nothing is written
into `docs/`, which `mkdocs serve` watches) and cached in a temporary directory under
a hash of this file, jaxmr's sources and the JAX version: a rebuild that changed
neither draws nothing. `JAXMR_DOCS_FIGURES` names another cache directory.

Run on its own to draw them into a directory: `python docs/_hooks/figures.py OUT`.
"""

import hashlib
import io
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
URI = "figures"  # where the pages find them: `figures/<name>.png` from the site root


def _quick_example():
    # The quick example of the getting-started page and the README, as printed there
    # (one panel, three currents); the README shows this figure from
    # docs/_static/quick_example.png.
    import jax.numpy as jnp

    import jaxmr
    import jaxmr.plot

    brake = jaxmr.sas_brake_bouc_wen()
    motion = jaxmr.Sine(jnp.deg2rad(3.5), 1.0)
    ts = jnp.linspace(0.0, 3.0, 3001)
    sol = jaxmr.sweep(brake, motion, [0.0, 0.5, 1.0], ts)
    ax = jaxmr.plot.loop(
        sol, units="rotary", labels=["0 A", "0.5 A", "1 A"], last_cycles_from=2.0
    )
    ax.set_title("SAS brake, Bouc–Wen, ±3.5° at 1 Hz")
    return ax.figure


def _pair(sol, units, labels, last_cycles_from, title, legend=True):
    """Force against displacement and against velocity, side by side."""
    import matplotlib.pyplot as plt

    import jaxmr.plot

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
    for ax, against in zip(axes, ("displacement", "velocity")):
        jaxmr.plot.loop(
            sol,
            against,
            ax=ax,
            units=units,
            labels=labels,
            last_cycles_from=last_cycles_from,
            legend=legend if against == "velocity" else False,
        )
    fig.suptitle(title)
    return fig


def _at_inputs(device, motion, ts, inputs, unit):
    """One device at several constant currents (or voltages): the sweep and labels."""
    import jaxmr

    return jaxmr.sweep(device, motion, inputs, ts), [f"{i:g} {unit}" for i in inputs]


def _brake_motion():
    import jax.numpy as jnp

    import jaxmr

    # The SAS study's test: ±3.5°, 1 Hz; three cycles, the last one drawn.
    return jaxmr.Sine(jnp.deg2rad(3.5), 1.0), jnp.linspace(0.0, 3.0, 3001)


def _damper_motion(amplitude, frequency, duration, samples):
    import jax.numpy as jnp

    import jaxmr

    return jaxmr.Sine(amplitude, frequency), jnp.linspace(0.0, duration, samples)


def _bingham():
    import jaxmr

    motion, ts = _brake_motion()
    f_c = (0.1, 0.2)
    devices = [jaxmr.sas_brake_bingham(f_c=f) for f in f_c]
    # The smooth form that gradients need: tanh(v / v_s) in place of the sign.
    devices.append(jaxmr.Bingham(f_c=0.2, c0=0.002, velocity_scale=0.05))
    sol = jaxmr.sweep(devices, motion, 0.0, ts)
    labels = [f"$f_c$ = {f:g} N·m" for f in f_c] + ["0.2 N·m, $v_s$ = 0.05 rad/s"]
    title = "Bingham: the SAS brake (sas_brake_bingham)"
    return _pair(sol, "rotary", labels, 2.0, title)


def _bouc_wen():
    import jaxmr

    sol, labels = _at_inputs(
        jaxmr.sas_brake_bouc_wen(), *_brake_motion(), [0.0, 0.5, 1.0], "A"
    )
    title = "Bouc–Wen: the SAS brake (sas_brake_bouc_wen)"
    return _pair(sol, "rotary", labels, 2.0, title)


def _normalized_bouc_wen():
    import jaxmr

    # One force amplitude, one saturation length, three shapes sigma.
    sigmas = (0.25, 0.5, 1.0)
    devices = [
        jaxmr.NormalizedBoucWen(
            kappa_x=0.0, kappa_w=500.0, c0=1000.0, rho=500.0, sigma=s, n=1.0
        )
        for s in sigmas
    ]
    motion, ts = _damper_motion(0.01, 1.0, 2.0, 2001)  # ±10 mm, 1 Hz
    sol = jaxmr.sweep(devices, motion, 0.0, ts)
    labels = [f"σ = {s:g}" for s in sigmas]
    title = "Normalised Bouc–Wen: κw = 500 N, ρ = 500 1/m, n = 1, c0 = 1000 N·s/m"
    return _pair(sol, "linear_mm", labels, 1.0, title)


def _dahl():
    import jax.numpy as jnp

    import jaxmr

    motion, _ = _brake_motion()
    # Dahl's state forgets its start slowly at this amplitude: six cycles, the last
    # drawn (as in notebook 01).
    ts = jnp.linspace(0.0, 6.0, 6001)
    sol, labels = _at_inputs(jaxmr.sas_brake_dahl(), motion, ts, [0.0, 3.0, 6.0], "A")
    title = "Dahl: the SAS brake (sas_brake_dahl)"
    return _pair(sol, "rotary", labels, 5.0, title, legend="outside")


def _lugre():
    import jaxmr

    # An illustrative linear damper (no preset): Coulomb and break-away forces and the
    # viscous term grow with current.
    device = jaxmr.LuGre(
        sigma0=1e6,  # [N/m]
        sigma1=3e3,  # [N·s/m]
        sigma2=jaxmr.LinearLaw(500.0, 1500.0),  # [N·s/m]
        F_c=jaxmr.LinearLaw(50.0, 400.0),  # [N]
        F_s=jaxmr.LinearLaw(80.0, 600.0),  # [N]
        v_s=0.01,  # [m/s]
    )
    motion, ts = _damper_motion(0.01, 1.0, 2.0, 2001)  # ±10 mm, 1 Hz
    sol, labels = _at_inputs(device, motion, ts, [0.0, 0.5, 1.0], "A")
    return _pair(sol, "linear_mm", labels, 1.0, "LuGre: an illustrative damper")


def _spencer():
    import jaxmr

    # Spencer et al. (1997), voltage-driven through its 190 1/s filter: 2.5 Hz, ±15 mm.
    motion, ts = _damper_motion(0.015, 2.5, 1.2, 2401)
    sol, labels = _at_inputs(jaxmr.spencer_1997(), motion, ts, [0.0, 0.75, 2.25], "V")
    title = "Spencer: the 1997 damper (spencer_1997)"
    return _pair(sol, "linear_mm", labels, 0.8, title)


def _shear_thinning_spencer():
    import dataclasses

    import jaxmr

    # The UTFSM damper's published Spencer model with thinning dashpots added.
    published = jaxmr.utfsm_spencer()
    fields = {f.name: getattr(published, f.name) for f in dataclasses.fields(published)}
    e0s = (0.0, 5.0, 20.0)  # [s/m]
    devices = [jaxmr.ShearThinningSpencer(**fields, e0=e0) for e0 in e0s]
    motion, ts = _damper_motion(0.01, 3.0, 1.0, 2001)  # ±10 mm, 3 Hz
    sol = jaxmr.sweep(devices, motion, 1.0, ts)
    labels = [f"$e_0$ = {e0:g} s/m" for e0 in e0s]
    title = "Shear-thinning Spencer: the UTFSM damper at 1 A ($e_0$ = 0: Spencer)"
    return _pair(sol, "linear_mm", labels, 2 / 3, title)


def _bwbn():
    import jaxmr

    # Notebook 01's pinched damper, with less and no pinching (zeta_s = 0: Bouc–Wen).
    z_u = 0.25e-3  # [m]
    zetas = (0.0, 0.5, 0.9)
    devices = [
        jaxmr.BoucWenBaberNoori(
            k=1.3e6,
            alpha=0.08,
            c=1500.0,
            A0=1.0,
            beta=0.4 / z_u**2,
            gamma=0.6 / z_u**2,
            n=2.0,
            f0=5.0,
            zeta_s=zeta,
            p=5e7,
            q=0.1,
            psi=5e-5,
            lam=0.5,
        )
        for zeta in zetas
    ]
    motion, ts = _damper_motion(1e-3, 1.0, 2.0, 2001)  # ±1 mm, 1 Hz
    sol = jaxmr.sweep(devices, motion, 0.0, ts)
    labels = [f"$\\zeta_s$ = {z:g}" for z in zetas]
    return _pair(sol, "linear_mm", labels, 1.0, "Bouc–Wen–Baber–Noori: pinching")


FIGURES: dict[str, Callable] = {
    "quick_example": _quick_example,
    "bingham": _bingham,
    "bouc_wen": _bouc_wen,
    "normalized_bouc_wen": _normalized_bouc_wen,
    "dahl": _dahl,
    "lugre": _lugre,
    "spencer": _spencer,
    "shear_thinning_spencer": _shear_thinning_spencer,
    "bwbn": _bwbn,
}


def _fingerprint() -> str:
    import jax

    digest = hashlib.sha256(Path(__file__).read_bytes())
    for path in sorted((ROOT / "jaxmr").rglob("*.py")):
        digest.update(str(path.relative_to(ROOT)).encode())
        digest.update(path.read_bytes())
    digest.update(jax.__version__.encode())
    return digest.hexdigest()[:16]


def draw(names=None, log=print) -> dict[str, bytes]:
    """PNG bytes of each figure, from the cache when this source was drawn before."""
    # This checkout's jaxmr, installed or not (as the notebooks' tests run it). Here,
    # not at import: MkDocs restores `sys.path` after loading a hook.
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    cache = Path(
        os.environ.get("JAXMR_DOCS_FIGURES")
        or Path(tempfile.gettempdir()) / "jaxmr-docs-figures"
    )
    folder = cache / _fingerprint()
    names = list(FIGURES) if names is None else names
    missing = [n for n in names if not (folder / f"{n}.png").is_file()]
    if missing:
        import jax
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        # The build is the user here: the integrators' tolerances need float64.
        jax.config.update("jax_enable_x64", True)
        folder.mkdir(parents=True, exist_ok=True)
        for name in missing:
            start = time.perf_counter()
            fig = FIGURES[name]()
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=110)
            plt.close(fig)
            # Through a temporary file and a rename: a cached figure is whole.
            part = folder / f"{name}.png.part"
            part.write_bytes(buffer.getvalue())
            part.replace(folder / f"{name}.png")
            log(f"jaxmr docs: drew {name}.png in {time.perf_counter() - start:.1f} s")
    return {n: (folder / f"{n}.png").read_bytes() for n in names}


def on_files(files, config):
    """Add the figures to the site as generated files."""
    import logging

    from mkdocs.structure.files import File

    logger = logging.getLogger("mkdocs.hooks.jaxmr_figures")
    for name, content in draw(log=logger.info).items():
        files.append(File.generated(config, f"{URI}/{name}.png", content=content))
    return files


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python docs/_hooks/figures.py OUT_DIR")
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    for name, content in draw().items():
        (out / f"{name}.png").write_bytes(content)
