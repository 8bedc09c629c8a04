from .base import AbstractSystem as AbstractSystem, MEASUREMENT_NAMES as MEASUREMENT_NAMES
from .quarter_car import (
    QuarterCar as QuarterCar,
    passenger_car as passenger_car,
    spencer_quarter_car as spencer_quarter_car,
)
from .sdof import SingleDegreeOfFreedom as SingleDegreeOfFreedom
