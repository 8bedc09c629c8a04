"""Model templates: data-scaled initial models for `jaxmr.fit`, and the wrappers that
build new ones.

`MODEL_TEMPLATES[name](experiments)` is a constrained initial guess (free parameters in
`Positive` or `Bounded`, the rest `Fixed`) scaled from the experiments; `with_lag` and
`with_channel_delay` turn a template into one whose model sees its input through a
fitted first-order lag, or its force through a fitted channel delay, and
`with_saturation` into one whose linear current laws level off (`SaturatingLaw`; the
`<family>_saturating` templates, `SATURATING_FIELDS`); `data_scales`
gives the scales of the data (a `DataScales`) that the templates start from. `jaxmr
fit` builds its candidates from these; the same calls serve a script:

```python
import jaxmr.templates as templates

candidates = {
    name: templates.with_channel_delay(templates.MODEL_TEMPLATES[name])
    for name in ("spencer", "bouc_wen")
}
selection = jaxmr.select_model(candidates, experiments)
```

Importing this module imports JAX.
"""

from ._identify.templates import (
    DEFAULT_CANDIDATES as DEFAULT_CANDIDATES,
    DEFAULT_LAG_CANDIDATES as DEFAULT_LAG_CANDIDATES,
    MODEL_TEMPLATES as MODEL_TEMPLATES,
    SATURATING_FIELDS as SATURATING_FIELDS,
    DataScales as DataScales,
    data_scales as data_scales,
    default_candidates as default_candidates,
    input_levels as input_levels,
    input_varies_in_time as input_varies_in_time,
    saturating_candidates as saturating_candidates,
    with_channel_delay as with_channel_delay,
    with_lag as with_lag,
    with_saturation as with_saturation,
)

__all__ = [
    "DEFAULT_CANDIDATES",
    "DEFAULT_LAG_CANDIDATES",
    "MODEL_TEMPLATES",
    "SATURATING_FIELDS",
    "DataScales",
    "data_scales",
    "default_candidates",
    "input_levels",
    "input_varies_in_time",
    "saturating_candidates",
    "with_channel_delay",
    "with_lag",
    "with_saturation",
]
