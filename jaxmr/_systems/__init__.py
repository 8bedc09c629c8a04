from .base import (
    MEASUREMENT_NAMES as MEASUREMENT_NAMES,
    AbstractSystem as AbstractSystem,
)
from .quarter_car import (
    QuarterCar as QuarterCar,
    passenger_car as passenger_car,
    spencer_quarter_car as spencer_quarter_car,
)
from .sdof import SingleDegreeOfFreedom as SingleDegreeOfFreedom
