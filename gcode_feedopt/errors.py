"""The exception hierarchy. Every error a user can cause derives from FeedOptError and
carries a one-line message that says what, where, the value, the limit and the fix, e.g.
``part.gcode:1432: G20 (inches) is not supported; re-slice in millimetres (G21)``.
The CLI turns these into one line on stderr and a non-zero exit in one place."""


class FeedOptError(Exception):
    """Base of every error gcode-feedopt raises on purpose."""

    exit_code = 2


class GCodeError(FeedOptError):
    """The G-code input cannot be processed (binary, inches, malformed motion, ...)."""


class AlreadyProcessedError(GCodeError):
    """The file already carries our ident line; rerun with --force to process it again."""


class ProfileError(FeedOptError):
    """A machine profile is missing, malformed or out of bounds."""


class LogError(FeedOptError):
    """A sensor log is malformed, truncated, from another machine, or has no motion."""


class VerifyError(FeedOptError):
    """The output failed a safety check; nothing was written."""


class SolverError(FeedOptError):
    """A numerical solver failed in a way no fallback could absorb."""

    exit_code = 3


class ModelWarning(UserWarning):
    """Data the model takes but explains badly (an FRF the modal fit misses, repeats that
    disagree, a mode at the edge of the band). The CLI prints each as one line on stderr."""


class LogWarning(ModelWarning):
    """A log used with a caveat: it starts mid-motion (a warm-up is left out), ends mid-motion,
    or moves too briefly to identify much. The CLI prints each as one line on stderr."""
