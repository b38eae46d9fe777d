"""Contact laws (the paper's Table 1), smoothed contact primitives and friction."""

from ._laws import CONTACT_LAWS as CONTACT_LAWS
from ._laws import LAW_NAMES as LAW_NAMES
from ._laws import AbstractContactLaw as AbstractContactLaw
from ._laws import FloresEtAl as FloresEtAl
from ._laws import GharibHurmuzlu as GharibHurmuzlu
from ._laws import GonthierEtAl as GonthierEtAl
from ._laws import HerbertMcWhannell as HerbertMcWhannell
from ._laws import HuGuo as HuGuo
from ._laws import HuntCrossley as HuntCrossley
from ._laws import LankaraniNikravesh as LankaraniNikravesh
from ._laws import LeeWang as LeeWang
from ._laws import ZhiyingQishao as ZhiyingQishao
from ._laws import get_law as get_law
from ._laws import hysteresis_factor as hysteresis_factor
from ._restitution import single_impact as single_impact
from ._smooth import LATCH_FLOOR as LATCH_FLOOR
from ._smooth import PENETRATION_SMOOTHING as PENETRATION_SMOOTHING
from ._smooth import latch_rate as latch_rate
from ._smooth import sigmoid as sigmoid
from ._smooth import smooth_contact_force as smooth_contact_force
from ._smooth import smooth_power as smooth_power
from ._smooth import softplus as softplus
from ._smooth import stribeck_friction as stribeck_friction
