"""Real measurements (issue 3): the published models reproduce their baselines, and a
jaxmr identification beats them, on the data and on data it has not seen.

The data are read from `../shared/data` (beside the project); missing data is an
error, not a skip. The fits themselves — the joint UTFSM fit (median NRMSE <= 0.08,
better than the published model), its prediction of currents it did not see, and the
NEES fit that beats Spencer 1997 on 19 s it was not fitted to — run once, in
`notebooks/02_identify_real_damper.ipynb`, whose assertion cells check those claims;
the notebook runs in `test_notebooks.py`, so a regression fails the suite. Here: the
parts those results rest on.
"""

import dataclasses
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data as jd
from jaxmr import ShearThinningSpencer, record_nrmse, utfsm_spencer
from jaxmr.data import utfsm_first_cycle, utfsm_smoothing
from jaxmr.scores import moving_average

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
UTFSM = DATA / "utfsm_mr_damper" / "sine"
NEES = DATA / "nees_dyke_mr_damper" / "ranran_50.csv"


@pytest.fixture(scope="module")
def utfsm():
    experiments = jd.load_utfsm(UTFSM)  # FileNotFoundError when the data are missing
    assert len(experiments) == 30
    return experiments


@pytest.fixture(scope="module")
def nees():
    return jd.load_nees(NEES, trim=True)


def test_shear_thinning_spencer_without_thinning_is_spencer():
    published = utfsm_spencer()
    fields = {f.name: getattr(published, f.name) for f in dataclasses.fields(published)}
    thinning = ShearThinningSpencer(**fields)
    ts = jnp.linspace(0.0, 1.0, 1001)
    motion = jaxmr.Sine(0.01, 1.0)
    options = dict(integrator=jaxmr.FixedStep(4))
    a = jaxmr.simulate(published, motion, 0.5, ts, **options).force
    b = jaxmr.simulate(thinning, motion, 0.5, ts, **options).force
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
    # Thinning lowers the post-yield force: c0 halves at |v| = 1/e0 = 16 mm/s.
    thinner = ShearThinningSpencer(**(fields | {"e0": 60.0}))
    c = jaxmr.simulate(thinner, motion, 0.5, ts, **options).force
    assert np.max(np.abs(c)) < np.max(np.abs(a)) - 20.0


def test_moving_average():
    t = np.arange(2001) * 1e-3
    width = 0.1
    # A centred average of a sine of frequency f scales it by sinc(f width), no lag.
    smoothed = moving_average(np.sin(2 * np.pi * 2.0 * t), t, width)
    inside = (t > width) & (t < t[-1] - width)
    expected = np.sinc(2.0 * width) * np.sin(2 * np.pi * 2.0 * t)
    np.testing.assert_allclose(smoothed[inside], expected[inside], atol=5e-5)
    # Exact for a straight line inside, and the window shrinks at the ends.
    np.testing.assert_allclose(moving_average(3 * t, t, width)[inside], 3 * t[inside])
    assert moving_average(3 * t, t, width)[0] == pytest.approx(3 * width / 4)
    np.testing.assert_array_equal(moving_average(t, t, 0.0), t)
    # A width in samples given for seconds (5 for 5 ms), a negative one, or arrays
    # that do not match: named, not a flat line or the values unchanged.
    for bad, match in ((5.0, "wider than the record"), (-0.1, ">= 0")):
        with pytest.raises(ValueError, match=match):
            moving_average(t, t, bad)
    with pytest.raises(ValueError, match="one length"):
        moving_average(t[:-1], t, width)


def test_published_utfsm_model_reproduces_its_baseline(utfsm):
    # Unsmoothed (`load_utfsm` sets the authors' smoothing), as the data's README.
    scores = record_nrmse(
        utfsm_spencer(), utfsm, discard=utfsm_first_cycle(utfsm), smoothing=0.0
    )
    # The data's README: median 0.109, range 0.07-0.25 (jaxmr: 0.105, 0.069-0.247).
    assert 0.09 <= np.median(scores) <= 0.13, np.median(scores)
    assert 0.05 <= scores.min() and scores.max() <= 0.3, (scores.min(), scores.max())


def test_the_loaders_processing_is_the_protocols(utfsm, nees):
    """`load_utfsm` carries the authors' smoothing and the first cycle as the
    experiments' own, so the scores default to the protocol: the same bits as when
    they are given."""
    model = utfsm_spencer()
    np.testing.assert_array_equal(
        record_nrmse(model, utfsm),
        record_nrmse(
            model,
            utfsm,
            discard=utfsm_first_cycle(utfsm),
            smoothing=utfsm_smoothing(utfsm),
        ),
    )
    assert nees.discard == 0.2 and nees.smoothing == 0.0


def test_nees_spencer_1997_baseline(nees):
    spencer = jaxmr.spencer_1997()
    # The record starts mid-motion: the first 0.2 s are left out of every score.
    reference = record_nrmse(spencer, [nees], discard=0.2, remove_mean=True)[0]
    assert abs(reference - 0.24) <= 0.03, reference  # measured 0.238


def test_a_fit_crawling_along_a_valley_is_not_stopped_as_stalled(utfsm):
    # LuGre on nine UTFSM records (0, 0.5 and 1 A; 2.5 cycles each, ~250 samples a
    # cycle, the first discarded) creeps along a valley: from step 8 on, three steps
    # in a row lowered its loss by less than `ftol` (1e-4) while its Gauss–Newton
    # model still promised 1.2 %. Counted as a stall, the fit stopped there at a loss
    # of 0.0321; followed until the model promises less than `ftol`, it reaches
    # 0.0249. The bound 0.026 lies between the two, 4 % above the optimum (what
    # another step order or compiler may move it by is far smaller).
    periods = dict(zip([e.name for e in utfsm], utfsm_first_cycle(utfsm)))
    widths = dict(zip([e.name for e in utfsm], utfsm_smoothing(utfsm)))
    records = []
    for e in utfsm:
        pair = e.name.partition("Hz")[0] + "Hz"
        if pair not in ("2mm5Hz", "10mm1Hz", "5mm3Hz"):
            continue
        if jd.utfsm_test_conditions(e).current not in (0.0, 0.5, 1.0):
            continue
        t0 = float(np.asarray(e.t)[0])
        cut = e.window(None, t0 + 2.5 * periods[e.name])
        step = max(1, int(round(len(cut) / (2.5 * 250))))
        s = slice(None, None, step)
        every = jd.Experiment(
            *(np.asarray(a)[s] for a in (cut.t, cut.x, cut.v, cut.current, cut.force)),
            name=e.name,
        )
        records.append((every, e.name))
    assert len(records) == 9
    experiments = [r for r, _ in records]
    result = jaxmr.fit(
        jaxmr.templates.MODEL_TEMPLATES["lugre"](experiments),
        experiments,
        discard=[periods[n] for _, n in records],
        smoothing=[widths[n] for _, n in records],
        progress=False,
    )
    assert result.loss < 0.026, (result.loss, result.num_steps, result.stop)
    assert result.converged, result.outcome
