from .base import (
    MEASUREMENT_NAMES as MEASUREMENT_NAMES,
    AbstractSystem as AbstractSystem,
)
from .quarter_car import (
    QuarterCar as QuarterCar,
    passenger_car as passenger_car,
    spencer_quarter_car as spencer_quarter_car,
)
from .sas_rig import (
    SASRig as SASRig,
    decay_settling_time as decay_settling_time,
    inverse_dynamics as inverse_dynamics,
    sas_rig as sas_rig,
    sas_rig_brake as sas_rig_brake,
)
from .sdof import SingleDegreeOfFreedom as SingleDegreeOfFreedom
