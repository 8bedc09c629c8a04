from .acceleration_driven import AccelerationDrivenDamper as AccelerationDrivenDamper
from .backstepping import Backstepping as Backstepping
from .base import (
    AbstractController as AbstractController,
    ConstantCurrent as ConstantCurrent,
    DamperPlant as DamperPlant,
)
from .clipped_optimal import (
    ClippedOptimal as ClippedOptimal,
    ContinuousClippedOptimal as ContinuousClippedOptimal,
)
from .estimator import VelocityEstimator as VelocityEstimator
from .feedback import (
    ForceFeedback as ForceFeedback,
    feature_scales as feature_scales,
)
from .groundhook import Groundhook as Groundhook, OnOffGroundhook as OnOffGroundhook
from .hybrid import Hybrid as Hybrid
from .lyapunov import LyapunovController as LyapunovController
from .observer import DamperObserver as DamperObserver
from .observer_based import ObserverBasedController as ObserverBasedController
from .power_driven import PowerDrivenDamper as PowerDrivenDamper
from .replay import replay as replay
from .riccati import (
    lqr as lqr,
    solve_lyapunov as solve_lyapunov,
    solve_riccati as solve_riccati,
)
from .sampling import Sampling as Sampling
from .schedule import CurrentSchedule as CurrentSchedule
from .sensors import (
    Sensor as Sensor,
    Sensors as Sensors,
    realistic_sensors as realistic_sensors,
)
from .skyhook import OnOffSkyhook as OnOffSkyhook, Skyhook as Skyhook
from .smooth import with_temperature as with_temperature
from .state_space import quarter_car_state_space as quarter_car_state_space
