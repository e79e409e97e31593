"""Every file gcode-feedopt writes goes through here: checked before any work, written to a
temporary file beside the target, fsynced and renamed over it (``os.replace``).

The rules, for every output (G-code, in-place edits, logs, CSVs, JSON, PNGs, profiles):

- **Checked first.** ``check_outputs`` runs before a command reads or plans anything, so a bad
  ``--report`` path cannot leave the G-code rewritten and the report missing.
- **Folders are not created.** The folder an output goes into must exist (a typo is an error,
  not a new folder tree). Only outputs that *are* folders are made: ``batch -o DIR`` (its
  parent must exist) and the FRF folder written beside a profile.
- **Regular files only.** A target that exists and is a device (``/dev/null``, ``/dev/full``),
  FIFO, socket or folder is refused; it is never replaced by a regular file.
- **Never over an input.** An output that is the same file as an input (after symlinks and
  hard links) is refused, except the G-code of an in-place edit; two outputs may not share a file.
- **Symlinks are followed.** Writing to a link writes the file it points to and keeps the link.
- **Modes.** A new file gets ``0666 & ~umask`` like any file the user creates; a replaced file
  keeps its mode, owner and group.
- **No debris.** The temporary file (``.NAME.XXXXXXXX.tmp``) is removed on any error, Ctrl-C or
  SIGTERM; a full disk or read-only file system is a one-line ``OutputError``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pathlib
import stat
import tempfile
from dataclasses import dataclass
from typing import Iterable, Iterator, Mapping

from .errors import OutputError

#: the name that means standard output
STDOUT = "-"

#: temporary files this process has open (removed by ``remove_temps`` on a fatal signal)
_ACTIVE_TEMPS: set[str] = set()

#: longest file-name part of the target kept in the temporary file's name (bytes)
_TEMP_NAME_KEEP = 60

_KIND_NAMES = {stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
               stat.S_IFIFO: "a FIFO (named pipe)", stat.S_IFSOCK: "a socket",
               stat.S_IFDIR: "a folder"}


@dataclass(frozen=True)
class Target:
    """An output checked by ``check_output``.

    Attributes:
        path: the path as the user gave it (used in messages).
        real: the file written: ``path`` with symlinks resolved.
        option: the option it came from (``-o``, ``--report``, ...), used in messages.
    """

    path: pathlib.Path
    real: pathlib.Path
    option: str = "output"

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __str__(self) -> str:
        return os.fspath(self.path)


def _label(option: str) -> str:
    return f"{option}: " if option and option not in ("output", "input") else ""


def _kind(mode: int) -> str:
    return _KIND_NAMES.get(stat.S_IFMT(mode), "not a regular file")


def _name_max(folder: pathlib.Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        return 255


def _read_only_fs(folder: pathlib.Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        return False


def _same(st: os.stat_result, other: os.stat_result) -> bool:
    return (st.st_dev, st.st_ino) == (other.st_dev, other.st_ino)


def check_output(path, option: str = "output", *, inputs: Iterable = (),
                 in_place: bool = False, suffixes: Iterable[str] | None = None) -> Target:
    """Check that ``path`` can be written as the rules above say; nothing is written.

    ``inputs``: files the command reads (an output equal to one is refused unless
    ``in_place``); ``suffixes``: allowed file-name endings (e.g. (".png",)), lower case.
    Raises OutputError naming the option, the path, what is wrong and the fix."""
    lab = _label(option)
    raw = os.fspath(path)
    if raw == "":
        raise OutputError(f"{option}: empty path; give a file name")
    path = pathlib.Path(raw)
    if raw.endswith(os.sep) or path.name in ("", ".", ".."):
        raise OutputError(f"{lab}{path}: is a folder; give a file name")
    if suffixes is not None:
        suffixes = tuple(suffixes)
        if path.suffix.lower() not in suffixes:
            raise OutputError(f"{lab}{path}: unsupported file type '{path.suffix}'; use a name "
                              f"ending in {' or '.join(suffixes)}")
    try:
        real = pathlib.Path(os.path.realpath(path))
    except OSError as exc:  # pragma: no cover - realpath is non-strict
        raise OutputError(f"{lab}{path}: {exc.strerror}; check the path") from None
    folder = real.parent
    try:
        fst = os.stat(folder)
    except FileNotFoundError:
        raise OutputError(f"{lab}{path}: folder {path.parent} does not exist; create it first "
                          "(output folders are never created)") from None
    except OSError as exc:
        raise OutputError(f"{lab}{path}: folder {path.parent}: {exc.strerror}; check the path") \
            from None
    if not stat.S_ISDIR(fst.st_mode):
        raise OutputError(f"{lab}{path}: {path.parent} is not a folder; check the path")
    n = len(os.fsencode(real.name))
    limit = _name_max(folder)
    if n > limit:
        raise OutputError(f"{lab}{path}: file name is {n} bytes, longer than the file system's "
                          f"{limit}; use a shorter name")
    try:
        st = os.stat(real)
    except FileNotFoundError:
        st = None
    except OSError as exc:  # ELOOP (a symlink loop), EACCES, ...
        raise OutputError(f"{lab}{path}: {exc.strerror}; check the path") from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            raise OutputError(f"{lab}{path}: is {_kind(st.st_mode)}, not a regular file; give "
                              "the path of a file to write (--dry-run writes nothing)")
        for inp in inputs:
            if inp is None:
                continue
            try:
                ist = os.stat(inp)
            except OSError:
                continue
            if _same(st, ist) and not in_place:
                raise OutputError(f"{lab}{path}: is the input file {inp}; choose another "
                                  "file for this output")
    if _read_only_fs(folder):
        raise OutputError(f"{lab}{path}: read-only file system; write to another folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{lab}{path}: cannot create files in {path.parent} (permission "
                          "denied); write to another folder")
    if st is not None:
        if not os.access(real, os.W_OK):
            raise OutputError(f"{lab}{path}: file is read-only (mode "
                              f"{stat.S_IMODE(st.st_mode):04o}); make it writable or write "
                              "elsewhere")
        euid = os.geteuid() if hasattr(os, "geteuid") else 0
        if euid != 0 and st.st_uid != euid:
            raise OutputError(f"{lab}{path}: belongs to another user (uid {st.st_uid}); "
                              "replacing it would change its owner; run as that user or "
                              "write elsewhere")
        if euid != 0 and st.st_gid not in (os.getegid(), *os.getgroups()):
            raise OutputError(f"{lab}{path}: its group (gid {st.st_gid}) is not one of yours; "
                              "replacing it would change its group; write elsewhere")
    return Target(path=path, real=real, option=option)


def check_outputs(outputs: Mapping[str, object], *, inputs: Iterable = (),
                  in_place: Iterable[str] = (), suffixes: Mapping[str, Iterable[str]] | None = None
                  ) -> dict[str, Target]:
    """``check_output`` for each ``option -> path`` (None skipped), no two outputs on one
    file, at most one on stdout. ``-`` means stdout, except for options with ``suffixes``
    (PNGs, profiles: not text). Returns option -> Target (or ``"-"``)."""
    inputs = [i for i in inputs if i is not None]
    in_place = set(in_place)
    suffixes = suffixes or {}
    out: dict[str, Target] = {}
    for option, path in outputs.items():
        if path is None:
            continue
        if is_stdout(path):
            if option in suffixes:
                raise OutputError(f"{option}: '-' (stdout) is not possible for this output; "
                                  f"give a file name ending in {' or '.join(suffixes[option])}")
            continue
        out[option] = check_output(path, option, inputs=inputs, in_place=option in in_place,
                                   suffixes=suffixes.get(option))
    seen: dict[str, str] = {}
    for option, t in out.items():
        key = os.path.normcase(os.fspath(t.real))
        if key in seen:
            raise OutputError(f"{seen[key]} and {option} both write {t.path}; give each its own "
                              "file")
        seen[key] = option
    stdout = [o for o, p in outputs.items() if is_stdout(p)]
    if len(stdout) > 1:
        raise OutputError(f"{' and '.join(stdout)} both write to stdout ('-'); send one of them "
                          "to a file")
    for o in stdout:
        out[o] = STDOUT
    return out


def is_stdout(path) -> bool:
    """True for ``-`` (stdout)."""
    return path is not None and not isinstance(path, Target) and os.fspath(path) == STDOUT


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _temp_prefix(real: pathlib.Path) -> str:
    name = real.name
    if len(os.fsencode(name)) > _TEMP_NAME_KEEP:
        name = os.fsdecode(os.fsencode(name)[:_TEMP_NAME_KEEP]).rstrip("\udcff") or "out"
        # a cut multi-byte character becomes surrogates: keep the name printable
        name = "".join(c for c in name if not "\udc80" <= c <= "\udcff")
    return f".{name}."


def _fsync_dir(folder: pathlib.Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _unlink(tmp: str) -> None:
    try:
        os.unlink(tmp)
    except OSError:
        pass
    _ACTIVE_TEMPS.discard(tmp)


def remove_temps() -> None:
    """Remove every temporary file this process has open (a fatal signal's last act)."""
    for tmp in list(_ACTIVE_TEMPS):
        _unlink(tmp)


def _as_target(target, option: str) -> Target:
    if isinstance(target, Target):
        # re-check at write time: the file system may have changed since the first check
        return check_output(target.path, target.option, in_place=True)
    return check_output(target, option, in_place=True)


def _write_error(t: Target, exc: OSError) -> OutputError:
    what = exc.strerror or str(exc)
    fix = {errno.ENOSPC: "free some space or write elsewhere",
           errno.EDQUOT: "free some space or write elsewhere",
           errno.EROFS: "write to another folder",
           errno.EACCES: "check the permissions or write elsewhere",
           errno.EPERM: "check the permissions or write elsewhere",
           errno.EFBIG: "write to another file system"}.get(exc.errno, "check the path")
    return OutputError(f"{_label(t.option)}{t.path}: cannot write ({what}); {fix}; the file "
                       "is left as it was")


def _finish(tmp: str, t: Target) -> None:
    """Give the temporary file the target's mode and owner (or a new file's), then rename."""
    try:
        st = os.stat(t.real)
    except FileNotFoundError:
        st = None
    if st is None:
        os.chmod(tmp, 0o666 & ~_umask())
    else:
        if stat.S_ISREG(st.st_mode):
            tst = os.stat(tmp)
            if (tst.st_uid, tst.st_gid) != (st.st_uid, st.st_gid) and hasattr(os, "chown"):
                os.chown(tmp, st.st_uid, st.st_gid)
            os.chmod(tmp, stat.S_IMODE(st.st_mode))
        else:
            raise OutputError(f"{_label(t.option)}{t.path}: became {_kind(st.st_mode)} while "
                              "we worked; nothing was written")
    os.replace(tmp, t.real)
    _ACTIVE_TEMPS.discard(tmp)
    _fsync_dir(t.real.parent)


def _stdout(text: bool):
    import io
    import sys

    sys.stdout.flush()
    raw = sys.stdout.buffer
    fh = io.TextIOWrapper(raw, encoding="utf-8", newline="\n") if text else raw
    try:
        yield fh
    finally:
        if text:
            try:
                fh.flush()
            finally:
                fh.detach()  # never close stdout
        raw.flush()


@contextlib.contextmanager
def output_file(target, option: str = "output", *, text: bool = False) -> Iterator:
    """Open a temporary file for ``target`` (a path or a ``Target``); on a clean exit it is
    fsynced and renamed over the target, on any exception removed. Yields a binary file,
    or a UTF-8 text file with ``\\n`` line ends when ``text``. ``-`` writes to stdout."""
    if is_stdout(target):
        yield from _stdout(text)
        return
    t = _as_target(target, option)
    try:
        fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(t.real), suffix=".tmp", dir=t.real.parent)
    except OSError as exc:
        raise _write_error(t, exc) from None
    _ACTIVE_TEMPS.add(tmp)
    try:
        with os.fdopen(fd, "wb") as raw:
            if text:
                import io

                fh = io.TextIOWrapper(raw, encoding="utf-8", newline="\n")
                yield fh
                fh.flush()
                fh.detach()
            else:
                yield raw
            raw.flush()
            os.fsync(raw.fileno())
        _finish(tmp, t)
    except OSError as exc:
        _unlink(tmp)
        raise _write_error(t, exc) from None
    except BaseException:
        _unlink(tmp)
        raise


@contextlib.contextmanager
def output_path(target, option: str = "output") -> Iterator[str]:
    """For libraries that write by path (matplotlib): yields a temporary path beside the
    target with the target's suffix; the file written there is fsynced and renamed over the
    target on a clean exit, removed on any exception."""
    t = _as_target(target, option)
    try:
        fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(t.real), suffix=".tmp" + t.real.suffix,
                                   dir=t.real.parent)
    except OSError as exc:
        raise _write_error(t, exc) from None
    os.close(fd)
    _ACTIVE_TEMPS.add(tmp)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _finish(tmp, t)
    except OSError as exc:
        _unlink(tmp)
        raise _write_error(t, exc) from None
    except BaseException:
        _unlink(tmp)
        raise


def write_bytes(target, data: bytes, option: str = "output") -> None:
    """Write ``data`` to ``target`` through a temporary file (see ``output_file``)."""
    with output_file(target, option) as fh:
        fh.write(data)


def write_text(target, text: str, option: str = "output") -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``target`` through a temporary file."""
    write_bytes(target, text.encode("utf-8"), option)


def make_output_folder(path, option: str = "output folder") -> pathlib.Path:
    """Create the folder ``path`` if missing (its parent must exist); refuse a non-folder."""
    path = pathlib.Path(path)
    lab = _label(option)
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise OutputError(f"{lab}{path}: exists and is not a folder; give a folder path")
        return path
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"{lab}{path}: folder {parent} does not exist; create it first "
                          "(only the output folder itself is created)")
    try:
        path.mkdir()
    except OSError as exc:
        raise OutputError(f"{lab}{path}: cannot create the folder ({exc.strerror}); write "
                          "elsewhere") from None
    return path
