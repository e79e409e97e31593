"""gcode-feedopt: re-time G-code so each axis runs as fast as the machine allows while the
predicted contour error stays within a tolerance at a chosen stringency.

Pipeline (one module per stage, each stage's output is the next one's input)::

    gcode.reader  -> Program            (lines kept byte for byte, moves parsed)
    gcode.path    -> Path               (exact lines and arcs, arc length s in mm)
    plan.*        -> Schedule           (path coordinate s(t) sampled at Ts)
    gcode.writer  -> bytes              (re-feedrated or time-sampled G-code)

The digital twin (``twin``) predicts the actual axis positions for a commanded trajectory;
the virtual machine (``vm``) executes G-code through a firmware model and a plant.
"""

import os as _os

__version__ = "0.1.0"

# One BLAS thread per process, unless the user set otherwise. Our linear algebra is many small
# problems (window LPs, twin covariances, modal fits) and the planner already runs one worker
# process per core; OpenBLAS's own threads then cost more than they give: the whole Cura Benchy
# with pidd on 2 cores took 38.3 s with its default threads and 29.0 s with one
# (benchmarks/bench_pipeline.py --method pidd --cases benchy). Read when the BLAS library
# loads, so it must be set before numpy is imported (the CLI imports this package first).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
