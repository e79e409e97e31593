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

__version__ = "0.1.0"
