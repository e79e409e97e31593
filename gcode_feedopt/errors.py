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


class InputError(FeedOptError):
    """An input file is missing, not a regular file, unreadable, or binary where text is due
    (gcode_feedopt.inputs)."""


class OutputError(FeedOptError):
    """An output cannot be written: missing folder, not a regular file, the input itself,
    read-only, full disk (gcode_feedopt.outputs)."""


class UsageError(FeedOptError):
    """An option value out of range or options that contradict each other."""


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived (gcode_feedopt.procs); a KeyboardInterrupt, so the
    same cleanup runs for all three and no ``except Exception`` swallows it. ``signum`` is the
    signal; the CLI exits 128 + signum."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


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
