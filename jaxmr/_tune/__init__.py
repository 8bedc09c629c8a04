"""Tuning controllers (and passive parameters) through the closed loop: by gradients
(`tune`), against derivative-free baselines (`random_search`, `cma_es`) on the same
loss, and `evaluate` on held-out roads."""

from .evaluate import evaluate as evaluate
from .gradient import tune as tune
from .loss import comfort as comfort
from .result import TuneResult as TuneResult
from .search import cma_es as cma_es, random_search as random_search
