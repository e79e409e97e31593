"""Input files: checked to be regular readable files before any work, and text inputs
(CSV tables: FRFs, spectra, recordings, logs) read as text with a one-line error for binary
data or bytes that are not UTF-8, instead of a UnicodeDecodeError traceback."""

from __future__ import annotations

import os
import pathlib
import stat

from .errors import InputError
from .outputs import _kind, _label


def check_input(path, option: str = "input") -> pathlib.Path:
    """A file to read: it exists and is a regular file (after symlinks). Returns the path."""
    path = pathlib.Path(path)
    lab = _label(option)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{lab}{path}: no such file; check the path") from None
    except OSError as exc:
        raise InputError(f"{lab}{path}: cannot read ({exc.strerror}); check the path") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{lab}{path}: is {_kind(st.st_mode)}, not a regular file; give the "
                          "path of a file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{lab}{path}: not readable (permission denied); check its mode")
    return path



def read_text(path, what: str = "a text file", error=InputError) -> str:
    """The text of ``path`` (UTF-8, BOM dropped). Binary data (a NUL byte) or bytes that are
    not UTF-8 raise ``error`` naming the line and the byte; ``what`` says what the file
    should be, with its article ("an FRF CSV", ...)."""
    path = check_input(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror}); check the path") from None
    nul = data.find(b"\0")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        raise error(f"{path}:{line}: binary data (a NUL byte), not {what}; pass the text "
                    "file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{path}:{line}: byte 0x{data[exc.start]:02x} is not UTF-8 text, so this is "
                    f"not {what}; re-export it as plain text") from None
