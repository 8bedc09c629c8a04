"""Magnetic hysteresis of an MR device's steel (Hodgdon) and the MR brake actuator."""

from .brake import BinghamDisc as BinghamDisc, mr_brake_actuator as mr_brake_actuator
from .material import HodgdonMaterial as HodgdonMaterial
from .presets import (
    AISI_12L14_MAJOR_LOOP as AISI_12L14_MAJOR_LOOP,
    aisi_12l14 as aisi_12l14,
    mrb_107_3 as mrb_107_3,
)
from .stage import MagneticStage as MagneticStage
