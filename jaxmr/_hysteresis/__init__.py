from .base import AbstractHysteresis as AbstractHysteresis
from .bingham import Bingham as Bingham
from .bouc_wen import BoucWen as BoucWen, NormalizedBoucWen as NormalizedBoucWen
from .bwbn import BoucWenBaberNoori as BoucWenBaberNoori
from .dahl import Dahl as Dahl
from .lugre import LuGre as LuGre
from .shear_thinning import ShearThinningSpencer as ShearThinningSpencer
from .spencer import Spencer as Spencer
