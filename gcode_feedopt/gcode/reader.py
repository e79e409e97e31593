"""G-code reader: bytes in, a Program out. The only module that imports pygcode.

Every line is kept exactly as it is in the file, with its own line ending and any byte that
is not UTF-8 (comments are decoded as latin-1 only to find the words; the bytes are never
re-encoded). Motion lines are parsed into :class:`Move` records in absolute machine
coordinates, with the modal state resolved:

- G90/G91 (XYZ absolute/relative) and, per firmware flavour, whether they also switch E
  (Marlin: G90/G91 set E too until the next M82/M83; Klipper: E is relative if either G91 or
  M83 is in force); M82/M83; G92 X Y Z E (offsets, so the path has no jumps); G20 refused.
- G0/G1 with modal F; G2/G3 with I/J or with R, kept as exact arcs (XY plane, helical Z).
- G10/G11 firmware retraction, G4 dwells, waits, homing, tool changes: *events* that force an
  exact stop (and take time) but move nothing we re-time.
- Klipper extended commands (``NAME KEY=VALUE``), ``N`` line numbers with ``*`` checksums and
  unknown codes pass through untouched; a numbered motion line is tracked but never re-timed.

Plain ``G0/G1 X.. Y.. Z.. E.. F..`` lines (nearly every line of a slicer's file) are split into
words by a regular expression that accepts only what pygcode reads the same way; every other
line goes through pygcode (``tests/gcode/test_reader_fast.py`` checks the two agree).
"""

from __future__ import annotations

import contextlib
import gc
import math
import re
from dataclasses import dataclass, field, fields

from pygcode.exceptions import GCodeWordStrError
from pygcode.words import text2words

from ..errors import GCodeError
from .features import canonical, tag_of

#: Move kinds.
EXTRUDE, TRAVEL, RETRACT, UNRETRACT, ZHOP, E_ONLY = "extrude", "travel", "retract", "unretract", "zhop", "e-only"

#: Extrusion below this (mm of filament) counts as none; far below any slicer's 5-decimal E.
E_EPS_MM = 1e-9
#: XYZ travel below this counts as no motion, mm.
D_EPS_MM = 1e-9

#: M-codes that make the firmware wait until the planner queue is empty (exact stop).
SYNC_MCODES = {0, 1, 109, 190, 191, 400, 600, 226, 25, 24, 112, 81, 80}
#: M-codes that are queued without stopping motion (fan, progress, temperatures without wait,
#: limits that take effect on later moves, flow and speed factors, messages).
NOSYNC_MCODES = {73, 82, 83, 104, 105, 106, 107, 117, 118, 140, 141, 201, 203, 204, 205, 220,
                 221, 290, 900, 300, 115, 17, 572, 593, 486, 862}
#: Klipper extended commands that only set limits or report (no stop).
NOSYNC_EXTENDED = {"SET_VELOCITY_LIMIT", "M117", "SET_PRESSURE_ADVANCE", "EXCLUDE_OBJECT_DEFINE",
                   "EXCLUDE_OBJECT_START", "EXCLUDE_OBJECT_END", "SET_PRINT_STATS_INFO",
                   "SET_FAN_SPEED", "SET_DISPLAY_TEXT", "RESPOND", "SET_HEATER_TEMPERATURE",
                   "SET_INPUT_SHAPER"}

_EXTENDED = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)(?=\s|$)")
_LINE_NO = re.compile(r"^\s*[Nn]\s*\d+")
_CHECKSUM = re.compile(r"\*\s*\d+\s*$")
_KEYVAL = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)=(\"[^\"]*\"|'[^']*'|\S+)")


@dataclass(frozen=True)
class Arc:
    """An exact arc in the XY plane. ``center_mm`` in machine coordinates; ``cw`` for G2."""

    center_mm: tuple[float, float]
    cw: bool
    #: signed sweep, rad (+CCW); a full circle is ±2π.
    sweep_rad: float
    radius_mm: float


@dataclass(frozen=True)
class Move:
    """One motion line (G0/G1/G2/G3) as the firmware will see it.

    Positions are absolute machine coordinates (G92 offsets and G91 resolved), mm.
    ``e_start_mm``/``e_end_mm`` are the absolute filament position in machine terms (a G92 E
    reset does not make them jump)."""

    line_no: int
    code: str
    start_mm: tuple[float, float, float]
    end_mm: tuple[float, float, float]
    e_start_mm: float
    e_end_mm: float
    feed_mm_s: float
    arc: Arc | None
    kind: str
    layer: int
    e_relative: bool
    xyz_relative: bool
    #: logical = machine - offset, per axis X, Y, Z, E at the time of the move.
    offset_mm: tuple[float, float, float, float]
    #: True when the line carries an N number or checksum, or the writer must not touch it.
    fixed: bool
    #: the words as written (letter -> text of the value), for exact reproduction.
    words: dict = field(default_factory=dict, compare=False, repr=False)
    #: canonical feature (gcode.features.FEATURES) from the slicer's last ``;TYPE:`` tag;
    #: ``travel`` for a move that does not extrude; "" for an untagged extruding move.
    feature: str = ""

    @property
    def de_mm(self) -> float:
        return self.e_end_mm - self.e_start_mm

    @property
    def xyz_length_mm(self) -> float:
        if self.arc is not None:
            planar = abs(self.arc.sweep_rad) * self.arc.radius_mm
            return math.hypot(planar, self.end_mm[2] - self.start_mm[2])
        return math.dist(self.start_mm, self.end_mm)


@dataclass(frozen=True)
class Event:
    """A non-motion line a firmware model must honour, in file order.

    ``name`` is e.g. ``"M204"``, ``"G4"``, ``"SET_VELOCITY_LIMIT"``, ``"T"``; ``params`` holds
    the parsed values (floats; letters upper case for G/M codes, KEY upper case for extended
    commands). ``stop`` is True when the firmware empties its queue there; ``dwell_s`` is the
    time the machine stands still (dwell, firmware retraction), when known.
    ``move_index`` is the number of moves read before this event."""

    line_no: int
    name: str
    params: dict
    stop: bool
    dwell_s: float
    move_index: int
    de_mm: float = 0.0


@dataclass
class Program:
    """A G-code file as read. ``lines`` are the raw bytes of each line, endings included."""

    name: str
    lines: list[bytes]
    moves: list[Move]
    events: list[Event]
    flavour: str
    #: index into ``lines`` of our ident line if the file was processed before, else None.
    processed_line: int | None = None

    @property
    def data(self) -> bytes:
        return b"".join(self.lines)


@dataclass
class _State:
    pos: list  # machine XYZ
    e: float  # machine E
    off: list  # logical = machine - off (X, Y, Z, E)
    xyz_rel: bool = False
    e_rel_m83: bool = False  # M83 in force (Klipper semantics) / explicit E mode (Marlin)
    e_mode_explicit: bool | None = None  # Marlin: None -> follow G90/G91
    feed_mm_s: float = 0.0
    layer: int = -1
    layer_z: float = -math.inf
    retracted: float = 0.0


IDENT_PREFIX = b"; processed by gcode-feedopt"


def split_lines(data: bytes) -> list[bytes]:
    """Split ``data`` into lines that keep their endings (LF, CRLF or a final line without)."""
    lines = data.split(b"\n")
    out = [ln + b"\n" for ln in lines[:-1]]
    if lines[-1]:
        out.append(lines[-1])
    return out


def check_binary(data: bytes, name: str) -> None:
    """Refuse binary G-code and other binary files with a message that says how to fix it."""
    if data[:4] == b"GCDE":
        raise GCodeError(
            f"{name}: binary G-code (.bgcode, magic 'GCDE') is not supported; export text G-code "
            "instead (PrusaSlicer: Printer Settings > General > Firmware > uncheck 'Supports binary "
            "G-code', or convert with `bgcode --decode`)")
    head = data[:65536]
    if b"\x00" in head:
        raise GCodeError(f"{name}: contains NUL bytes, so it is not a text G-code file; "
                         "pass the slicer's .gcode output")
    if b"\n" not in data and b"\r" in data.rstrip(b"\r"):
        raise GCodeError(f"{name}: lines end in CR only (classic Mac OS); no firmware reads "
                         "that; convert the line ends to LF (e.g. `tr '\\r' '\\n'`)")


def _strip(text: str) -> tuple[str, bool]:
    """Return the code part of a line (comments, line number and checksum removed) and whether
    the line carried an N number or a checksum."""
    code = text.split(";", 1)[0]
    if "(" in code:
        code = re.sub(r"\([^)]*\)", " ", code)
    numbered = False
    if _CHECKSUM.search(code):
        code = _CHECKSUM.sub("", code)
        numbered = True
    m = _LINE_NO.match(code)
    if m:
        code = code[m.end():]
        numbered = True
    return code.strip(), numbered


#: A number as the firmware reads it: digits with at most one point, no exponent. Marlin's
#: ``value_float`` cuts a value at ``E`` and Klipper splits a line at every letter, so
#: ``X1e9`` is X1 and E9 to both (and to pygcode), as ``G1X10E1`` is X10 and E1.
_DECIMAL = r"(?:\d+\.?\d*|\.\d+)"
#: One word of a line pygcode refuses: a letter and a plain number.
_PLAIN_WORD = re.compile(r"\s*([A-Za-z])\s*([-+]?" + _DECIMAL + r")\s*")


def _words(code: str, name: str, line_no: int) -> list[tuple[str, str]] | None:
    """Split a G/M-code line into (LETTER, value text) with pygcode; None if neither pygcode
    nor the plain reading below can parse it (the line then passes through untouched).

    pygcode reads L, N and T as integers and refuses ``M204 P1500 T1500.5`` ("block code
    remaining '.5'"); a firmware reads every parameter as a number. A line made only of
    letter–number words is read as written when pygcode refuses it: before, the line became an
    unknown command that stops the planner, and its accelerations were lost (the writer's own
    ``M204 P0.25 T0.25`` ran at the file's acceleration in the Marlin model)."""
    try:
        words = list(text2words(code))
    except (GCodeWordStrError, ValueError, TypeError):
        return _plain_words(code)
    out = []
    for w in words:
        out.append((w.letter.upper(), w.value_str if hasattr(w, "value_str") else str(w.value)))
    return out


def _plain_words(code: str) -> list[tuple[str, str]] | None:
    """``code`` as (LETTER, value text) words if it is nothing but letter–number words."""
    out, pos = [], 0
    while pos < len(code):
        m = _PLAIN_WORD.match(code, pos)
        if m is None:
            return None
        out.append((m.group(1).upper(), m.group(2)))
        pos = m.end()
    return out or None


_NUM = re.compile(r"([A-Za-z])\s*([-+]?" + _DECIMAL + ")")


#: A plain G0/G1 line: upper-case words separated by spaces, numbers as pygcode reads them
#: (no sign +, no exponent), an optional ``;`` comment, the line's ending. Anything else goes
#: through pygcode.
_FAST_MOTION = re.compile(r"G0?([01])((?: +[XYZEF]-?" + _DECIMAL
                          + r")*) *(?:;[^\r\n]*)?(?:\r?\n)?\Z")
_FAST_WORD = re.compile(r"([XYZEF])(-?" + _DECIMAL + ")")


def _raw_values(code: str) -> dict[str, str]:
    """The value texts as written (pygcode normalises numbers; we need them verbatim so an
    original end point can be reproduced exactly)."""
    return {m.group(1).upper(): m.group(2) for m in _NUM.finditer(code)}


#: Slowest feed accepted, mm/min (slicers' cooling slow-downs go to tens of mm/min).
MIN_FEED_MM_MIN = 0.1


def _f(text: str, name: str, line_no: int, letter: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise GCodeError(f"{name}:{line_no + 1}: {letter}{text!r} is not a number; fix the line "
                         "or remove it") from None
    if not math.isfinite(v):
        raise GCodeError(f"{name}:{line_no + 1}: {letter}{text} is not finite; fix the line")
    return v


def _tokenize(text: str, name: str, i: int, events: list, n_moves: int):
    """The words of one line by pygcode: (code, numbered, gcodes, mcodes, tcodes, params), or
    None when the line needs no further work (comment, unknown code, Klipper command, a line
    pygcode cannot read; events are appended to ``events``)."""
    stripped = text.lstrip()
    if not stripped or stripped[0] == ";":
        return None
    code, numbered = _strip(text)
    if not code:
        return None
    first = code[0].upper()
    ext = _EXTENDED.match(code)
    if ext and not re.match(r"^[A-Za-z]\s*[-+.\d]", code):
        # Klipper extended command / macro: NAME KEY=VALUE ...
        cmd = ext.group(1).upper()
        params = {k.upper(): v.strip("\"'") for k, v in _KEYVAL.findall(code[ext.end():])}
        numeric = {}
        for k, v in params.items():
            try:
                numeric[k] = float(v)
            except ValueError:
                numeric[k] = v
        events.append(Event(i, cmd, numeric, stop=cmd not in NOSYNC_EXTENDED, dwell_s=0.0,
                            move_index=n_moves))
        return None
    if first not in "GMT":
        return None  # unknown code: passes through untouched
    words = _words(code, name, i)
    if words is None and re.match(r"^[Gg]0*[0-3](?![0-9.])", code):
        # a motion the firmware will run but we cannot read: refuse rather than lose track
        raise GCodeError(f"{name}:{i + 1}: cannot read the motion line {code!r} (a word "
                         "without a value?); fix the line, e.g. 'G1 X10 F1200'")
    if words is None:
        events.append(Event(i, code.split()[0].upper(), {}, stop=True, dwell_s=0.0,
                            move_index=n_moves))
        return None
    raw_vals = _raw_values(code)
    gcodes = [v for (L, v) in words if L == "G"]
    mcodes = [v for (L, v) in words if L == "M"]
    tcodes = [v for (L, v) in words if L == "T"]
    params = {}
    for L, v in words:
        if L in "GMN" or (L == "T" and not (gcodes or mcodes)):
            continue
        if L in params and (gcodes or any(_m_number(m) in READ_MCODES for m in mcodes)):
            _refuse_twice(L, code, name, i)
        params[L] = raw_vals.get(L, v)
    if gcodes or mcodes:
        tcodes = []  # "M204 P500 T500", "M104 T1 S200": T is a parameter there
    if any(v in ("", None) for v in params.values()):
        raise GCodeError(f"{name}:{i + 1}: a word has no value in {code!r}; give each "
                         "word a number or remove it")
    return code, numbered, gcodes, mcodes, tcodes, params


#: M codes whose parameters the reader or the firmware models use: a word given twice there
#: is refused (as on every G line).
READ_MCODES = {82, 83, 201, 203, 204, 205, 220, 221, 593}


def _m_number(m: str) -> int:
    """An M word's number: ``_words`` gives only decimal values ("M204.0" is M204)."""
    return int(float(m))


def _first_repeat(words) -> str:
    """The first letter of (letter, value) ``words`` that was given before."""
    seen = set()
    for L, _ in words:
        if L in seen:
            return L
        seen.add(L)
    raise ValueError("no letter repeats")


def _refuse_twice(letter: str, code: str, name: str, i: int) -> None:
    """A line that gives one word twice: Marlin and Klipper need not take the same one, and a
    number written with an exponent reads as two words (``E1e10`` is E1 and E10)."""
    hint = (" (a number with an exponent? firmware reads 1e10 as 1 and a new E word)"
            if re.search(r"\d[eE][-+]?\d", code) else "")
    raise GCodeError(f"{name}:{i + 1}: {letter} appears twice in {code!r}{hint}; give each word "
                     "once, numbers written out in full")


#: Coordinates beyond this are refused as absurd (no machine is 100 m long), mm.
ABSURD_MM = 1e5
#: (index, letter) of the axes, for the loop over a move's words
_AXES = ((0, "X"), (1, "Y"), (2, "Z"))


def read_program(data: bytes, name: str = "<input>", *, flavour: str = "marlin",
                 g91_relative_e: bool = True, retract_mm: float = 0.0,
                 retract_speed_mm_s: float = 0.0, e_feed_mm_s: float = 25.0,
                 fast: bool = True) -> Program:
    """Parse G-code bytes into a Program.

    Args:
        data: the whole file, bytes.
        name: file name used in error messages.
        flavour: ``"marlin"`` or ``"klipper"`` (E-mode semantics of G90/G91).
        g91_relative_e: Marlin semantics (G90/G91 also set E until the next M82/M83).
        retract_mm, retract_speed_mm_s: firmware retraction (G10/G11) length and speed, so the
            dwell they cause can be estimated.
        e_feed_mm_s: default extruder speed for E-only moves without F.
        fast: read plain ``G0/G1 X.. Y.. Z.. E.. F..`` lines with a regular expression instead
            of pygcode (same words, same Program; ``False`` only to test that).
    """
    with gc_paused():
        return _read_program(data, name, flavour=flavour, g91_relative_e=g91_relative_e,
                             retract_mm=retract_mm, retract_speed_mm_s=retract_speed_mm_s,
                             e_feed_mm_s=e_feed_mm_s, fast=fast)


@contextlib.contextmanager
def gc_paused():
    """No cyclic garbage collection inside the block (restored after, also on error).

    Reading a file allocates about ten objects per line (a Move, its tuples and word dict),
    none of them in a reference cycle; the collector would still walk the whole growing heap
    again and again, which took about half of the Benchy's read time (1.9 -> 1.0 s). Reference
    counting frees everything as usual."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def _read_program(data: bytes, name: str, *, flavour: str, g91_relative_e: bool,
                  retract_mm: float, retract_speed_mm_s: float, e_feed_mm_s: float,
                  fast: bool) -> Program:
    """:func:`read_program` with the collector paused."""
    check_binary(data, name)
    if not data.strip():
        raise GCodeError(f"{name}: file is empty; nothing to optimize (pass the slicer's G-code)")
    lines = split_lines(data)
    rd = _Reader(name, flavour, g91_relative_e, retract_mm, retract_speed_mm_s)
    rd.read(lines, fast)
    moves, events = rd.moves, rd.events
    if not moves:
        raise GCodeError(f"{name}: no G0/G1/G2/G3 moves found; nothing to re-time "
                         "(is this a G-code file?)")
    for mv in moves:
        if mv.feed_mm_s <= 0:
            raise GCodeError(f"{name}:{mv.line_no + 1}: move without any feed rate (no F before "
                             "it); add an F word to the first move")
    check_limit_events(events, name)
    return Program(name=name, lines=lines, moves=moves, events=events, flavour=flavour,
                   processed_line=rd.processed)


class _Reader:
    """One read of a file, line by line: the modal state, the moves and events so far, and
    the line of our ident if the file was processed before."""

    def __init__(self, name: str, flavour: str, g91_relative_e: bool, retract_mm: float,
                 retract_speed_mm_s: float):
        self.name = name
        self.klipper = flavour == "klipper"
        self.g91_relative_e = g91_relative_e
        self.retract_mm = retract_mm
        self.retract_speed_mm_s = retract_speed_mm_s
        self.st = _State(pos=[0.0, 0.0, 0.0], e=0.0, off=[0.0, 0.0, 0.0, 0.0])
        self.moves: list[Move] = []
        self.events: list[Event] = []
        self.processed: int | None = None

    def read(self, lines: list[bytes], fast: bool) -> None:
        """The line loop: words of every line (the fast regular expression or pygcode), its
        G/M/T codes (:meth:`commands`), the modal feed, and its move (:meth:`move`)."""
        name, st, events, moves = self.name, self.st, self.events, self.moves
        # bound once: looked up on each of a million lines otherwise
        fast_match, fast_words, move = _FAST_MOTION.match, _FAST_WORD.findall, self.move
        tag = ""
        for i, raw in enumerate(lines):
            if raw.startswith(IDENT_PREFIX):
                self.processed = i
                continue
            text = raw.decode("latin-1")  # every byte a character: only to find the words
            if text[:1] == ";":
                t = tag_of(text)
                if t is not None:
                    tag = t
            fm = fast_match(text) if fast else None
            if fm is not None:
                # the common `G0/G1 X.. Y.. E.. F..` line: the same words pygcode would give
                code = fm.group(0).split(";", 1)[0].strip()
                numbered = False
                # its one G code is the motion (what the loop over gcodes would find)
                motion = 1 if fm.group(1) == "1" else 0
                gcodes = mcodes = tcodes = ()
                words = fast_words(fm.group(2))
                params = dict(words)
                if len(params) != len(words):
                    _refuse_twice(_first_repeat(words), code, name, i)
            else:
                tok = _tokenize(text, name, i, events, len(moves))
                if tok is None:
                    continue
                code, numbered, gcodes, mcodes, tcodes, params = tok
                motion = self.commands(i, gcodes, mcodes, tcodes, params)
            # F is modal for every code
            feed_txt = params.get("F")
            if feed_txt is not None:
                fv = _f(feed_txt, name, i, "F")
                if fv < MIN_FEED_MM_MIN:
                    _refuse_feed(feed_txt, fv, name, i)
                st.feed_mm_s = fv / 60.0
            if motion is None:
                if mcodes or gcodes or tcodes:
                    continue
                if not any(L in params for L in "XYZE"):
                    continue
                # axis words without a G code: modal motion is not supported
                raise GCodeError(f"{name}:{i + 1}: axis words without G0/G1/G2/G3 ({code!r}); "
                                 "write the motion code on every move")
            if mcodes:
                raise GCodeError(f"{name}:{i + 1}: a motion and an M-code on one line ({code!r}); "
                                 "put them on separate lines")
            has_axis = "X" in params or "Y" in params or "Z" in params or "E" in params
            if motion in (0, 1) and not has_axis:
                continue  # G1 F... : modal feed only
            move(i, motion, params, numbered, tag)

    def commands(self, i: int, gcodes, mcodes, tcodes, params: dict) -> int | None:
        """The G, M and T codes of line ``i`` (modes, offsets, events); returns its motion
        code (0–3), or None."""
        motion = None
        for g in gcodes:
            gv = float(g)
            if gv in (0, 1, 2, 3):
                motion = int(gv)
            else:
                self.g_code(i, g, gv, params)
        if not (mcodes or tcodes):
            return motion
        events, n_moves = self.events, len(self.moves)
        for m in mcodes:
            mv = _m_number(m)
            if mv == 82:
                self.st.e_rel_m83 = False
                self.st.e_mode_explicit = False
            elif mv == 83:
                self.st.e_rel_m83 = True
                self.st.e_mode_explicit = True
            vals = {}
            for L, v in params.items():
                try:
                    vals[L] = float(v)
                except ValueError:
                    pass
            stop = mv in SYNC_MCODES or (mv not in NOSYNC_MCODES)
            events.append(Event(i, f"M{mv}", vals, stop=stop, dwell_s=0.0, move_index=n_moves))
        for t in tcodes:
            events.append(Event(i, "T", {"T": float(t)}, stop=True, dwell_s=0.0,
                                move_index=n_moves))
        return motion

    def g_code(self, i: int, g: str, gv: float, params: dict) -> None:
        """A G code other than a motion (0–3) on line ``i``."""
        name, st, events = self.name, self.st, self.events
        if gv == 20:
            raise GCodeError(f"{name}:{i + 1}: G20 (inches) is not supported; re-slice in "
                             "millimetres (G21)")
        if gv in (90, 91):
            st.xyz_rel = gv == 91
            if not self.klipper and self.g91_relative_e:
                st.e_mode_explicit = None
        elif gv == 92:
            for k, L in enumerate("XYZ"):
                if L in params:
                    st.off[k] = st.pos[k] - _f(params[L], name, i, L)
            if "E" in params:
                st.off[3] = st.e - _f(params["E"], name, i, "E")
            if not any(L in params for L in "XYZE"):
                st.off = [st.pos[0], st.pos[1], st.pos[2], st.e]
        elif gv == 28:
            homed = [L for L in "XYZ" if L in params] or list("XYZ")
            for k, L in enumerate("XYZ"):
                if L in homed:
                    st.pos[k] = 0.0
                    st.off[k] = 0.0
            events.append(Event(i, "G28", {}, stop=True, dwell_s=0.0, move_index=len(self.moves)))
        elif gv == 4:
            dwell = 0.0
            if "P" in params:
                dwell = _f(params["P"], name, i, "P") / 1000.0
            if "S" in params:
                dwell = _f(params["S"], name, i, "S")
            events.append(Event(i, "G4", {}, stop=True, dwell_s=max(dwell, 0.0),
                                move_index=len(self.moves)))
        elif gv in (10, 11) and not any(L in params for L in "PLR"):
            # firmware retraction / recover
            de = -self.retract_mm if gv == 10 else self.retract_mm
            sp = self.retract_speed_mm_s
            dwell = abs(de) / sp if sp > 0 else 0.0
            events.append(Event(i, f"G{int(gv)}", {}, stop=True, dwell_s=dwell,
                                move_index=len(self.moves), de_mm=de))
        elif gv in (17, 21, 94, 54, 80, 49, 40):
            pass
        elif gv in (18, 19):
            raise GCodeError(f"{name}:{i + 1}: G{int(gv)} selects an arc plane other than XY, "
                             "which is not supported; use G17 (XY) arcs or linear moves")
        else:
            events.append(Event(i, f"G{g}", {}, stop=True, dwell_s=0.0,
                                move_index=len(self.moves)))

    def move(self, i: int, motion: int, params: dict, numbered: bool, tag: str) -> None:
        """The move of motion line ``i`` (G``motion``, its words ``params``, the feature
        ``tag`` in force): its end points in machine coordinates, kind and layer."""
        name, st = self.name, self.st
        start = tuple(st.pos)
        target = list(st.pos)
        for k, L in _AXES:
            if L in params:
                v = _f(params[L], name, i, L)
                target[k] = st.pos[k] + v if st.xyz_rel else v + st.off[k]
                if abs(target[k]) > ABSURD_MM:
                    raise GCodeError(f"{name}:{i + 1}: {L}{params[L]} is beyond ±{ABSURD_MM:g} mm; "
                                     "check the units and coordinates")
        e0 = st.e
        if self.klipper or not self.g91_relative_e:
            erel = st.e_rel_m83 or st.xyz_rel if self.klipper else st.e_rel_m83
        elif st.e_mode_explicit is not None:
            erel = st.e_mode_explicit
        else:
            erel = st.xyz_rel
        if "E" in params:
            v = _f(params["E"], name, i, "E")
            e1 = e0 + v if erel else v + st.off[3]
            if abs(e1 - e0) > ABSURD_MM:  # G92 E1e10 then E2: an E-only move of 1e10 mm
                raise GCodeError(f"{name}:{i + 1}: E{params['E']} moves {e1 - e0:.6g} mm of "
                                 f"filament in one move, beyond ±{ABSURD_MM:g} mm; check E and "
                                 "G92 E")
        else:
            e1 = e0
        feed = 0.0 if st.feed_mm_s <= 0 else st.feed_mm_s
        arc = None
        if motion in (2, 3):
            arc = _arc(start, target, params, motion == 2, name, i)
        de = e1 - e0
        d_xyz = math.dist(start, target) if arc is None else (abs(arc.sweep_rad) * arc.radius_mm)
        if d_xyz <= D_EPS_MM and arc is None:
            kind = E_ONLY if abs(de) > E_EPS_MM else TRAVEL
            if de < -E_EPS_MM:
                kind = RETRACT
            elif de > E_EPS_MM:
                kind = UNRETRACT
        elif de > E_EPS_MM:
            kind = EXTRUDE
        else:
            dxy = math.hypot(target[0] - start[0], target[1] - start[1]) if arc is None else d_xyz
            kind = ZHOP if dxy <= D_EPS_MM else TRAVEL
        if kind == EXTRUDE and target[2] > st.layer_z + 1e-6:
            st.layer += 1
            st.layer_z = target[2]
        elif kind == EXTRUDE and st.layer < 0:
            st.layer = 0
        self.moves.append(_new_move(
            i, f"G{motion}", start, tuple(target), e0, e1, feed, arc, kind, max(st.layer, 0),
            erel, st.xyz_rel, tuple(st.off), numbered, dict(params),
            "travel" if kind != EXTRUDE else canonical(tag)))
        st.pos = target
        st.e = e1


def _refuse_feed(feed_txt: str, fv: float, name: str, i: int) -> None:
    """Refuse the F word of line ``i`` (``fv`` mm/min, below MIN_FEED_MM_MIN): not positive,
    or slower than any machine moves."""
    if fv <= 0:
        raise GCodeError(f"{name}:{i + 1}: F{feed_txt} must be positive; fix the feed")
    if fv < MIN_FEED_MM_MIN:
        # F1e-30 planned a move of millions of years: the trapezoid's arrays could not
        # be allocated (or exhausted the memory) instead of a one-line error
        raise GCodeError(f"{name}:{i + 1}: F{feed_txt} is below {MIN_FEED_MM_MIN:g} "
                         "mm/min, slower than any machine moves; fix the feed")


#: limit-setting commands: parameter -> (lowest, highest) accepted value. An acceleration or
#: feed limit of 0 stalls a firmware and divided by zero in the firmware model (M204 S0 ran
#: into NaN); negative jerk or junction deviation means nothing.
LIMIT_PARAMS = {
    "M201": ({"X", "Y", "Z", "E"}, 1e-3, 1e7),
    "M203": ({"X", "Y", "Z", "E"}, 1e-3, 1e6),
    "M204": ({"S", "P", "T", "R"}, 1e-3, 1e7),
    "M205": ({"X", "Y", "Z", "E", "J"}, 0.0, 1e4),
    "SET_VELOCITY_LIMIT": ({"VELOCITY", "ACCEL", "ACCEL_TO_DECEL"}, 1e-3, 1e7),
}
#: longest G4 dwell accepted, s (the time estimates sample the whole print)
MAX_DWELL_S = 86_400.0


def check_limit_events(events, name: str) -> None:
    """Refuse limit commands the firmware cannot run (M204 S0, M205 X-1, SET_VELOCITY_LIMIT
    ACCEL=0, ...) and dwells longer than a day, naming the line."""
    for ev in events:
        if ev.name == "G4" and ev.dwell_s > MAX_DWELL_S:
            raise GCodeError(f"{name}:{ev.line_no + 1}: G4 dwell of {ev.dwell_s:.6g} s is longer "
                             f"than {MAX_DWELL_S:g} s (a day); fix the line")
        spec = LIMIT_PARAMS.get(ev.name)
        if spec is None:
            continue
        keys, lo, hi = spec
        for k, v in ev.params.items():
            if k in keys and isinstance(v, float) and not (lo <= v <= hi):
                raise GCodeError(f"{name}:{ev.line_no + 1}: {ev.name} {k}{'=' if '_' in ev.name else ''}"
                                 f"{v:g} is outside {lo:g} to {hi:g}; no firmware runs that, fix "
                                 "the line")


_MOVE_FIELDS = tuple(f.name for f in fields(Move))
_object_new = object.__new__


def _new_move(*values) -> Move:
    """``Move(*values)`` (every field, in order) without the frozen dataclass's ``__init__``,
    which sets each field through ``object.__setattr__``: 5 µs a move, half a second for each
    read of the Benchy (the file is read twice: as input and, by verify, as output). The
    instance is the same: same fields, equality, hash and immutability
    (tests/gcode/test_reader_fast.py)."""
    mv = _object_new(Move)
    mv.__dict__.update(zip(_MOVE_FIELDS, values))
    return mv


def _arc(start, target, params, cw: bool, name: str, i: int) -> Arc:
    """Centre, radius and signed sweep of a G2/G3 arc from I/J or R (XY plane)."""
    x0, y0 = start[0], start[1]
    x1, y1 = target[0], target[1]
    if "R" in params:
        r = _f(params["R"], name, i, "R")
        dx, dy = x1 - x0, y1 - y0
        d = math.hypot(dx, dy)
        if d <= D_EPS_MM:
            raise GCodeError(f"{name}:{i + 1}: an R-form arc cannot be a full circle; use I/J")
        if abs(r) < d / 2 - 1e-6:
            raise GCodeError(f"{name}:{i + 1}: arc radius R{params['R']} is smaller than half the "
                             f"chord ({d / 2:.4f} mm); fix R or use I/J")
        h = math.sqrt(max(r * r - d * d / 4, 0.0))
        # centre to the right of the chord for CW with R>0 (the short arc), left for CCW
        sgn = 1.0 if (cw ^ (r < 0)) else -1.0
        mx, my = x0 + dx / 2, y0 + dy / 2
        cx = mx + sgn * h * dy / d
        cy = my - sgn * h * dx / d
    else:
        if "I" not in params and "J" not in params:
            raise GCodeError(f"{name}:{i + 1}: G{2 if cw else 3} needs I/J or R; add the centre "
                             "offset")
        cx = x0 + _f(params.get("I", "0"), name, i, "I")
        cy = y0 + _f(params.get("J", "0"), name, i, "J")
    r0 = math.hypot(x0 - cx, y0 - cy)
    r1 = math.hypot(x1 - cx, y1 - cy)
    if r0 <= D_EPS_MM:
        raise GCodeError(f"{name}:{i + 1}: arc centre coincides with its start point; fix I/J")
    if abs(r0 - r1) > max(0.002, 1e-3 * r0):
        raise GCodeError(f"{name}:{i + 1}: arc end point is not on the circle (radius {r0:.4f} vs "
                         f"{r1:.4f} mm); fix I/J or the end point")
    a0 = math.atan2(y0 - cy, x0 - cx)
    a1 = math.atan2(y1 - cy, x1 - cx)
    sweep = a1 - a0
    if cw:
        while sweep >= -1e-12:
            sweep -= 2 * math.pi
        if math.hypot(x1 - x0, y1 - y0) > D_EPS_MM and sweep < -2 * math.pi + 1e-12:
            sweep += 2 * math.pi
    else:
        while sweep <= 1e-12:
            sweep += 2 * math.pi
        if math.hypot(x1 - x0, y1 - y0) > D_EPS_MM and sweep > 2 * math.pi - 1e-12:
            sweep -= 2 * math.pi
    if r0 > ABSURD_MM:
        raise GCodeError(f"{name}:{i + 1}: arc radius {r0:.6g} mm is beyond {ABSURD_MM:g} mm; "
                         "check I/J/R and the units")
    return Arc(center_mm=(cx, cy), cw=cw, sweep_rad=sweep, radius_mm=r0)


def read_file(path, **kwargs) -> Program:
    """Read a G-code file from disk (see :func:`read_program`)."""
    import pathlib

    p = pathlib.Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise GCodeError(f"{p}: no such file; check the path") from None
    except IsADirectoryError:
        raise GCodeError(f"{p}: is a directory; pass a G-code file (or use `batch`)") from None
    except PermissionError:
        raise GCodeError(f"{p}: permission denied; check the file's permissions") from None
    return read_program(data, str(p), **kwargs)
