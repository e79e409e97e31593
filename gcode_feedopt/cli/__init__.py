"""Command-line entry point: ``gcode-feedopt``.

``gcode-feedopt in.gcode -o out.gcode --machine ender3pro`` optimizes a file (the default
command, ``optimize``); PrusaSlicer calls ``gcode-feedopt --machine ender3pro PATH`` with the
path last and expects the file edited in place. Sub-commands (``simulate``, ``predict``,
``profile``, ...) live one per module in this package and are imported lazily, so that
``gcode-feedopt --help`` stays fast and a broken optional stage cannot break the main job.

This is the only layer that imports click. Library errors (FeedOptError) become one line
on stderr and a non-zero exit here, in one place.
"""

from __future__ import annotations

import importlib
import os
import re
import sys
import warnings

import click

from .. import __version__
from ..errors import FeedOptError

#: sub-command name -> "module:attribute" (a click.Command), imported on first use.
COMMANDS: dict[str, str] = {
    "optimize": "gcode_feedopt.cli.optimize:optimize",
    "profile": "gcode_feedopt.cli.profile:profile",
    "predict": "gcode_feedopt.cli.predict:predict",
    "simulate": "gcode_feedopt.cli.simulate:simulate",
    "compare": "gcode_feedopt.cli.compare:compare",
    "identify": "gcode_feedopt.cli.identify:identify",
    "learn": "gcode_feedopt.cli.learn:learn",
    "diagnose": "gcode_feedopt.cli.diagnose:diagnose",
    "batch": "gcode_feedopt.cli.batch:batch",
}
DEFAULT_COMMAND = "optimize"


class FeedOptGroup(click.Group):
    """A group whose first argument may be a G-code path instead of a sub-command:
    anything that is not a known sub-command (or --help/--version) is handed to
    ``optimize``."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        target = COMMANDS.get(name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:  # a stage not installed in this build
            if exc.name == module_name:
                return None
            raise
        return getattr(module, attr)

    def parse_args(self, ctx, args):
        if args and args[0] not in COMMANDS and args[0] not in ("--help", "-h", "--version"):
            args = [DEFAULT_COMMAND, *args]
        return super().parse_args(ctx, args)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """click's main, with every error as one line ``gcode-feedopt: error: ...`` (usage
        errors too, with where to find help) and exit code 2 for bad usage."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # bare `gcode-feedopt`: the help
                exc.show()
                sys.exit(exc.exit_code)
            msg = exc.format_message()
            if exc.ctx is not None:
                msg = f"{msg.rstrip('.')}; see '{exc.ctx.command_path} --help'"
            _error(msg)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            _error(exc.format_message())
            sys.exit(exc.exit_code)
        except click.Abort as exc:  # Ctrl-C outside a command (while parsing)
            signum = getattr(exc.__cause__, "signum", 2)
            click.echo(f"gcode-feedopt: stopped by signal {signum}", err=True)
            sys.exit(128 + signum)
        except BrokenPipeError:  # `... --report - | head`: the reader went away
            sys.stdout = open(os.devnull, "w")
            sys.exit(141)
        sys.exit(rv if isinstance(rv, int) else 0)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except FeedOptError as exc:
            _error(str(exc))
            ctx.exit(exc.exit_code)
        except (click.exceptions.Exit, click.ClickException, click.Abort, BrokenPipeError):
            raise  # BrokenPipeError: the reader of stdout went away (main exits quietly)
        except MemoryError:
            _error("out of memory; the file is too long for this machine's memory: split it, "
                   "or use --method kinematic (the smallest plan)")
            ctx.exit(INTERNAL_EXIT)
        except Exception as exc:  # a bug: one line and a way to see more, never a traceback
            if os.environ.get("GCODE_FEEDOPT_TRACEBACK"):
                raise
            where = ""
            tb = exc.__traceback__
            while tb is not None:
                where = f"{tb.tb_frame.f_code.co_filename.rsplit(os.sep, 1)[-1]}:{tb.tb_lineno}"
                tb = tb.tb_next
            _error(f"internal error ({type(exc).__name__} at {where}: {exc}); this is a bug: "
                   "please report it with the command; GCODE_FEEDOPT_TRACEBACK=1 shows the "
                   "traceback")
            ctx.exit(INTERNAL_EXIT)
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP (procs.install_handlers)
            # on use, like main's: `import gcode_feedopt.cli` stays light (procs, outputs: ~17 ms)
            from ..outputs import remove_temps
            from ..procs import acknowledge, signal_name

            acknowledge()
            remove_temps()
            signum = getattr(exc, "signum", 2)
            click.echo(f"gcode-feedopt: stopped by {signal_name(signum)}; files not yet "
                       "written are untouched, no temporary file is left", err=True)
            ctx.exit(128 + signum)


#: exit code of an internal error (a bug; BSD's EX_SOFTWARE), apart from bad input's 2
INTERNAL_EXIT = 70
#: longest error line; a longer message (a 10 MB token quoted back) keeps its start and end
MAX_ERROR_CHARS = 300


#: a path with at least two directories: its directories, then its last part
_PATH = re.compile(r"(?<![^\s(\"'])((?:[^\s/]*/){2,})([^\s/]*)")


def _short_path(m: re.Match) -> str:
    """``.../folder/name`` for a path whose directories are long (a URL is kept whole)."""
    if "://" in m.group(0) or len(m.group(1)) <= 24:
        return m.group(0)
    return ".../" + m.group(1).rstrip("/").rsplit("/", 1)[-1] + "/" + m.group(2)


def one_line(message: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``message`` on one line of at most ``limit`` characters. Too long, the files it names
    lose their directories but the last first (``.../logs/log.csv``: a user's path is often
    longer than the message, and cutting the middle took the fix with it — "divi ... lumn by
    1000" for a log under pytest's worker folders); still too long (a 10 MB token quoted
    back), the middle is cut out: the start says what and where, the end the fix."""
    text = " ".join(str(message).split())
    if len(text) > limit:
        text = _PATH.sub(_short_path, text)
    if len(text) <= limit:
        return text
    head = (limit - 5) * 2 // 3
    return f"{text[:head]} ... {text[-(limit - 5 - head):]}"


def _error(message: str) -> None:
    prefix = "gcode-feedopt: error: "
    click.echo(prefix + one_line(message, MAX_ERROR_CHARS - len(prefix)), err=True)


@click.group(cls=FeedOptGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="gcode-feedopt")
def cli():
    """Re-time G-code so the machine finishes faster within a contour-error tolerance.

    \b
    gcode-feedopt in.gcode -o out.gcode --machine ender3pro
    gcode-feedopt --machine ender3pro in.gcode          (edits in place; PrusaSlicer)
    gcode-feedopt COMMAND --help                         (the other commands)
    """


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Our own warnings (ModelWarning, ...) as one line on stderr, without the source line."""
    text = str(message).replace("\n", " ")
    click.echo(f"gcode-feedopt: warning: {text}", err=True)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    warnings.showwarning = _show_warning
    from ..procs import install_handlers  # on use: see invoke

    install_handlers()
    cli.main(args=argv if argv is not None else sys.argv[1:], prog_name="gcode-feedopt")
