"""jaxmr's OpenSees converters against OpenSees itself (openseespy, an optional
package not among jaxmr's dependencies; issue 14).

For the three materials of `tests/test_opensees.py` (BoucWen, degrading BoucWen,
BWBN with pinching), OpenSees is driven through two cycles of a sine displacement
(`testUniaxialMaterial`, `setStrain`) at 4 000 and 16 000 steps, and compared with
jaxmr's tight simulation of `jaxmr.from_opensees(material, params)`. OpenSees' update
is first order in the step (backward Euler in the displacement), so:

- `error_ratio`: its error at 4 000 steps over that at 16 000: ~4 if first order;
- `richardson_over_fine`: the error left after Richardson extrapolation of the two
  runs, over the fine run's error: well below 1 when the mapping is right (a wrong
  mapping leaves an error of order 1e-2 of the peak force that no step removes).

    PYTHONPATH=/path/to/openseespy python benchmarks/opensees_check.py --json OUT
"""

import argparse
import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import jaxmr  # noqa: E402
from tests.test_opensees import CASES, FREQUENCY, _jaxmr_force  # noqa: E402


def run_opensees(ops, material, params, u):
    ops.wipe()
    ops.model("basic", "-ndm", 1, "-ndf", 1)
    settings = (1e-12, 100) if material == "BWBN" else ()  # its Newton iteration
    ops.uniaxialMaterial(material, 1, *params.values(), *settings)
    ops.testUniaxialMaterial(1)
    force = []
    for x in u:
        ops.setStrain(float(x))
        force.append(ops.getStress())
    ops.wipe()
    return np.array(force)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    import openseespy.opensees as ops

    figures = []
    for material, params, amplitude in CASES:
        model = jaxmr.from_opensees(material, params)
        forces, exact = [], []
        for steps in (4000, 16000):  # over two cycles
            ts = np.linspace(0.0, 2.0 / FREQUENCY, steps + 1)
            u = amplitude * np.sin(2 * np.pi * FREQUENCY * ts)
            forces.append(run_opensees(ops, material, params, u))
            exact.append(_jaxmr_force(model, amplitude, ts))
        peak = np.max(np.abs(exact[0]))
        errors = [np.max(np.abs(f - e)) / peak for f, e in zip(forces, exact)]
        richardson = (4 * forces[1][::4] - forces[0]) / 3
        residual = np.max(np.abs(richardson - exact[0])) / peak
        row = {
            "material": material,
            "error_of_peak_4000_steps": errors[0],
            "error_of_peak_16000_steps": errors[1],
            "error_ratio": errors[0] / errors[1],
            "richardson_error_of_peak": residual,
            "richardson_over_fine": residual / errors[1],
            "mapping_right": bool(
                3 < errors[0] / errors[1] < 5 and residual < 0.1 * errors[1]
            ),
        }
        print(row, flush=True)
        figures.append(row)
    text = json.dumps({"cases": figures}, indent=2)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
