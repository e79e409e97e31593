"""Twin-driven feedrate optimization (paper Section 4, Appendix C).

Two optimizers of one problem (the shortest plan below the firmware's own plan F whose chance
bound on the contour error holds on every constrained sample):

- window.py + mpc.py: the paper's receding-window LP (pure window problem; the driver with
  the longer prediction horizon, terminal rest, re-linearisation and the safe fallback); the
  online method on the virtual machine, where the twin learns between windows;
- slowdown/: whole-file local slow-down of F verified by the whole-trajectory twin; the
  offline default for G-code files (cycle times within 1 % of the window LP's, 11-87x less
  compute; docs/optimizer.md §4).

predictors.py: what predicts the actual position (known FIR plant / the twin / the plant),
window by window or over a whole trajectory; free.py: F as a cap and the contour rules;
methods.py: kinematic | conservative | pb | dd | pidd | oracle; compare.py: the paper's Table 1.
"""

from .methods import METHODS, plan_schedule
from .mpc import MpcSettings

__all__ = ["METHODS", "MpcSettings", "plan_schedule"]
