"""Measured data: experiments, jaxmr's CSV format and loaders of public datasets.

Not jit-able (files and NumPy), hence apart from the models: `import jaxmr.data`.
An `Experiment` holds one test in SI units and turns it into the signals that
`jaxmr.simulate` takes (`experiment.motion()`, `experiment.current_signal()`).
"""

from ._convert import DATASETS as DATASETS, convert_dataset as convert_dataset
from ._csv import (
    experiment_name as experiment_name,
    read_comments as read_comments,
    read_csv as read_csv,
    read_processing as read_processing,
    write_csv as write_csv,
)
from ._digest import (
    experiment_digest as experiment_digest,
    file_digest as file_digest,
)
from ._experiment import DataWarning as DataWarning, Experiment as Experiment
from ._files import write_atomically as write_atomically
from ._loaders import (
    BOUCWEN_BENCHMARK_FS as BOUCWEN_BENCHMARK_FS,
    BoucWenBenchmarkInput as BoucWenBenchmarkInput,
    BoucWenBenchmarkTrain as BoucWenBenchmarkTrain,
    UTFSMConditions as UTFSMConditions,
    load_boucwen_benchmark_input as load_boucwen_benchmark_input,
    load_boucwen_benchmark_train as load_boucwen_benchmark_train,
    load_nees as load_nees,
    load_utfsm as load_utfsm,
    utfsm_first_cycle as utfsm_first_cycle,
    utfsm_smoothing as utfsm_smoothing,
    utfsm_test_conditions as utfsm_test_conditions,
)
from ._table import read_table as read_table
