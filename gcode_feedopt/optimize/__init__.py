"""Twin-driven receding-window feedrate optimizer (paper Section 4, Appendix C).

window.py: the window problem (pure); mpc.py: the receding-window driver; predictors.py:
what predicts the actual position over a horizon (known FIR plant / the twin / the plant);
methods.py: kinematic | conservative | pb | dd | pidd | oracle.
"""

from .methods import METHODS, plan_schedule
from .mpc import MpcSettings

__all__ = ["METHODS", "MpcSettings", "plan_schedule"]
