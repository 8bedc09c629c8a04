from .base import (
    AbstractController as AbstractController,
    ConstantCurrent as ConstantCurrent,
    DamperPlant as DamperPlant,
)
