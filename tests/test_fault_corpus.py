"""The bad-input and fault corpus of issue 18, every sub-command: each case ends in exit 2
with one line of at most 300 characters on stderr (or in the stated correct result); the
input and every file that existed before are byte-identical with the same mode and inode
type; no temporary or partial file is left. (tests/test_bad_input.py holds the reader cases
of the main command; tests/test_option_limits.py every numeric option; tests/test_signals.py
the signals.)"""

from __future__ import annotations

import fnmatch
import os
import pathlib
import stat
from dataclasses import dataclass, field

import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli

from .conftest import DATA, GCODE_DIR, INDEPENDENT_DIR, MEASURED_DIR

REPO = pathlib.Path(__file__).resolve().parents[1]
GOOD = b"G1 X10 Y10 F3000\nG1 X50 Y10 E2 F1200\nG1 X50 Y50 E4\n"
FRF_OK = (REPO / "gcode_feedopt" / "profiles" / "ender3pro" / "x_01.csv").read_bytes()
FRF_HEAD = b"freq_hz,real,imag\n"
LOG_HEAD = b"t,x_cmd,y_cmd,x,y\n"
YAML_OK = (REPO / "gcode_feedopt" / "profiles" / "ender3pro.yaml").read_bytes()
#: a profile file with its FRF folder, as a user keeps one
PROFILE = {"p.yaml": YAML_OK, **{f"ender3pro/{f.name}": f.read_bytes() for f in
                                 (REPO / "gcode_feedopt" / "profiles" / "ender3pro").iterdir()}}


def log_rows(n: int = 40, bad_row: bytes | None = None, at: int = 5) -> bytes:
    rows = [b"%.6f,%.6f,0.000000,%.6f,0.000000\n" % (k * 0.002, k * 0.01, k * 0.01)
            for k in range(n)]
    if bad_row is not None:
        rows[at] = bad_row
    return LOG_HEAD + b"".join(rows)


def real(path: pathlib.Path, n_lines: int | None = None) -> bytes:
    if not path.is_file():
        pytest.skip(f"{path} missing")
    data = path.read_bytes()
    if n_lines is not None:
        data = b"".join(data.splitlines(keepends=True)[:n_lines])
    return data


# special file contents, made by ``make``
FIFO, DIR = "<fifo>", "<dir>"


@dataclass
class Case:
    argv: list
    files: dict = field(default_factory=dict)
    match: str = ""            # a fragment of the one-line error (lower case compare)
    code: int = 2              # expected exit code
    creates: tuple = ()        # files a successful run may create (fnmatch patterns)
    lines: int = 1             # lines on stderr (warnings before the error line)
    check: object = None       # extra check(tmp_path, result)

    @property
    def ok(self) -> bool:
        return self.code != 2


def make(folder: pathlib.Path, files: dict) -> None:
    for name, content in files.items():
        p = folder / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if content is FIFO:
            os.mkfifo(p)
        elif content is DIR:
            p.mkdir()
        elif isinstance(content, tuple) and content[0] == "symlink":
            p.symlink_to(content[1])
        elif isinstance(content, tuple) and content[0] == "mode":
            p.write_bytes(content[2])
            os.chmod(p, content[1])
        else:
            p.write_bytes(content() if callable(content) else content)


def snapshot(folder: pathlib.Path) -> dict:
    """path -> (inode type, mode, content or link target) of every entry, links not followed."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for n in dirs + files:
            p = pathlib.Path(root) / n
            st = os.lstat(p)
            kind = stat.S_IFMT(st.st_mode)
            if stat.S_ISREG(st.st_mode):
                body = p.read_bytes()
            elif stat.S_ISLNK(st.st_mode):
                body = os.readlink(p)
            else:
                body = None
            out[str(p.relative_to(folder))] = (kind, stat.S_IMODE(st.st_mode), body)
    return out


DEVICES = ("/dev/null", "/dev/full")


def device_state():
    return {d: stat.S_IFMT(os.lstat(d).st_mode) for d in DEVICES if os.path.exists(d)}


# ---------------------------------------------------------------- the cases, per sub-command
OPT = ["-m", "ender3pro", "--method", "kinematic", "-q"]
G = {"in.gcode": GOOD}

CASES: dict[str, Case] = {}


def add(name: str, case: Case) -> None:
    assert name not in CASES, name
    CASES[name] = case


# optimize: outputs
add("opt -o /dev/null", Case(["in.gcode", "-o", "/dev/null", *OPT], G, "character device"))
add("opt -o /dev/full", Case(["in.gcode", "-o", "/dev/full", *OPT], G, "character device"))
add("opt -o missing folder", Case(["in.gcode", "-o", "nodir/out.gcode", *OPT], G, "does not exist"))
add("opt -o missing folders", Case(["in.gcode", "-o", "nodir/sub/out.gcode", *OPT], G,
                                    "does not exist"))
add("opt -o a folder", Case(["in.gcode", "-o", "d", *OPT], {**G, "d": DIR}, "is a directory"))
add("opt -o trailing slash", Case(["in.gcode", "-o", "d/", *OPT], {**G, "d": DIR}, "directory"))
add("opt -o fifo", Case(["in.gcode", "-o", "p", *OPT], {**G, "p": FIFO}, "fifo"))
add("opt -o under a file", Case(["in.gcode", "-o", "f/out.gcode", *OPT], {**G, "f": b"x"},
                                "not a folder"))
add("opt -o name too long", Case(["in.gcode", "-o", "o" * 300 + ".gcode", *OPT], G,
                                 "longer than"))
add("opt -o symlink loop", Case(["in.gcode", "-o", "loop", *OPT],
                                {**G, "loop": ("symlink", "loop")}, "symbolic links"))
add("opt in place --trajectory missing folder", Case(["in.gcode", "--trajectory", "nodir/t.csv",
                                                      *OPT], G, "does not exist"))
add("opt in place --report missing folder", Case(["in.gcode", "--report", "nodir/r.json", *OPT],
                                                 G, "does not exist"))
add("opt in place --plot missing folder", Case(["in.gcode", "--plot", "nodir/p.png", *OPT], G,
                                               "does not exist"))
add("opt --plot unknown type", Case(["in.gcode", "-o", "o.gcode", "--plot", "p.xyz", *OPT], G,
                                    "unsupported file type"))
add("opt --plot stdout", Case(["in.gcode", "-o", "o.gcode", "--plot", "-", *OPT], G, "stdout"))
add("opt --report is the input", Case(["in.gcode", "-o", "o.gcode", "--report", "in.gcode", *OPT],
                                      G, "is the input file"))
add("opt --trajectory is the input", Case(["in.gcode", "--trajectory", "in.gcode", *OPT], G,
                                          "is the input file"))
add("opt --report via symlink to input", Case(
    ["in.gcode", "-o", "o.gcode", "--report", "r.json", *OPT],
    {**G, "r.json": ("symlink", "in.gcode")}, "is the input file"))
add("opt --report hard link to input", Case(
    ["in.gcode", "-o", "o.gcode", "--report", "h.json", *OPT],
    {**G, "h.json": ("hardlink", "in.gcode")}, "is the input file"))
add("opt --report is the profile", Case(
    ["in.gcode", "-o", "o.gcode", "-m", "p.yaml", "--report", "p.yaml", "-q"],
    {**G, **PROFILE}, "is the input file"))
add("opt -o and --report one file", Case(["in.gcode", "-o", "o.gcode", "--report", "o.gcode",
                                          *OPT], G, "both write"))
add("opt --report and --trajectory one file", Case(
    ["in.gcode", "-o", "o.gcode", "--report", "r", "--trajectory", "./r", *OPT], G, "both write"))
add("opt two outputs on stdout", Case(["in.gcode", "-o", "o.gcode", "--report", "-",
                                       "--trajectory", "-", *OPT], G, "stdout"))
add("opt --dry-run -o /dev/null runs", Case(["in.gcode", "-o", "/dev/null", "--dry-run", *OPT],
                                            G, code=0))
add("opt -o new file is 0644", Case(["in.gcode", "-o", "o.gcode", *OPT], G, code=0,
                                    creates=("o.gcode",),
                                    check=lambda d, r: stat.S_IMODE(os.stat(d / "o.gcode")
                                                                    .st_mode) == 0o644))
add("opt -o over 0640 file keeps mode", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                             {**G, "o.gcode": ("mode", 0o640, b"old")}, code=0,
                                             creates=("o.gcode",),
                                             check=lambda d, r: stat.S_IMODE(
                                                 os.stat(d / "o.gcode").st_mode) == 0o640))
add("opt in place through a symlink", Case(
    ["l.gcode", *OPT], {"r.gcode": GOOD, "l.gcode": ("symlink", "r.gcode")}, code=0,
    creates=("r.gcode",),
    check=lambda d, r: (d / "l.gcode").is_symlink()
    and b"processed by gcode-feedopt" in (d / "r.gcode").read_bytes()))
add("opt in place 251-char name", Case(
    ["a" * 245 + ".gcode", *OPT], {"a" * 245 + ".gcode": GOOD}, code=0,
    creates=("a" * 245 + ".gcode",)))
add("opt -o - writes stdout", Case(["in.gcode", "-o", "-", *OPT], G, code=0,
                                   check=lambda d, r: "processed by gcode-feedopt" in r.stdout))
add("opt --report - writes stdout", Case(["in.gcode", "-o", "o.gcode", "--report", "-", *OPT], G,
                                         code=0, creates=("o.gcode",),
                                         check=lambda d, r: '"moves"' in r.stdout))
# optimize: inputs
add("opt input fifo", Case(["p", "-o", "o.gcode", *OPT], {"p": FIFO}, "fifo"))
add("opt input folder", Case(["d", "-o", "o.gcode", *OPT], {"d": DIR}, "directory"))
add("opt input missing", Case(["nope.gcode", "-o", "o.gcode", *OPT], {}, "no such file"))
add("opt input dangling symlink", Case(["l.gcode", "-o", "o.gcode", *OPT],
                                       {"l.gcode": ("symlink", "nope.gcode")}, "no such file"))
add("opt input /dev/null", Case(["/dev/null", "-o", "o.gcode", *OPT], {}, "character device"))
add("opt input already processed", Case(
    ["in.gcode", "-o", "o.gcode", *OPT],
    {"in.gcode": b"; processed by gcode-feedopt 0.1.0 (kinematic)\n" + GOOD}, "--force"))
add("opt CR-only line ends", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                  {"in.gcode": GOOD.replace(b"\n", b"\r")}, "cr only"))
add("opt 10 MB number", Case(["in.gcode", "-o", "o.gcode", *OPT],
                             {"in.gcode": lambda: b"G1 X1" + b"1" * 10_000_000 + b" F300\n" + GOOD},
                             "not finite"))
add("opt UTF-16 file", Case(["in.gcode", "-o", "o.gcode", *OPT],
                            {"in.gcode": GOOD.decode().encode("utf-16")}, "nul"))
add("opt only comments", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"; a\n; b\n"},
                              "no g0/g1"))
add("opt G4 a million years", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                   {"in.gcode": GOOD + b"G4 S1000000000000\n" + GOOD},
                                   "longer than"))
add("opt M204 S0", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"M204 S0\n" + GOOD},
                        "m204 s0"))
add("opt M201 X0", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"M201 X0 Y0\n" + GOOD},
                        "m201 x0"))
add("opt M203 X0", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"M203 X0\n" + GOOD},
                        "m203 x0"))
add("opt M205 negative", Case(["in.gcode", "-o", "o.gcode", *OPT],
                              {"in.gcode": b"M205 X-1\n" + GOOD}, "m205 x-1"))
add("opt SET_VELOCITY_LIMIT ACCEL=0", Case(
    ["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"SET_VELOCITY_LIMIT ACCEL=0\n" + GOOD},
    "accel=0"))
add("opt G92 E1e10 written out", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                      {"in.gcode": b"G92 E10000000000\n" + GOOD}, "filament"))
add("opt exponent", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"G92 E1e10\n" + GOOD},
                         "e appears twice"))
add("opt E1e12", Case(["in.gcode", "-o", "o.gcode", *OPT],
                      {"in.gcode": b"G1 X5 E1000000000000 F300\n" + GOOD}, "filament"))
add("opt arc radius 1e9", Case(["in.gcode", "-o", "o.gcode", *OPT],
                               {"in.gcode": b"G1 X0 Y0 F600\nG2 X1 Y0 I0.5 J1000000000\n" + GOOD},
                               "radius"))
add("opt Xinf", Case(["in.gcode", "-o", "o.gcode", *OPT], {"in.gcode": b"G1 Xinf F300\n" + GOOD},
                     "cannot read"))
add("opt negative feed", Case(["in.gcode", "-o", "o.gcode", *OPT],
                              {"in.gcode": b"G1 X1 F-100\n" + GOOD}, "positive"))
add("opt cut mid-line notes it", Case(["in.gcode", "-o", "o.gcode", "-m", "ender3pro",
                                       "--method", "kinematic"],
                                      {"in.gcode": GOOD + b"G1 X60 Y6"}, code=0,
                                      creates=("o.gcode",),
                                      check=lambda d, r: "no line end" in r.stderr))
add("opt UTF-8 BOM passes", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                 {"in.gcode": b"\xef\xbb\xbf; bom\n" + GOOD}, code=0,
                                 creates=("o.gcode",)))
add("opt lower-case words", Case(["in.gcode", "-o", "o.gcode", *OPT],
                                 {"in.gcode": b"g1 x10 y10 f3000\ng1 x50 e2\n"}, code=0,
                                 creates=("o.gcode",)))
add("opt NUL after 64 KiB passes through", Case(
    ["in.gcode", "-o", "o.gcode", *OPT],
    {"in.gcode": b"; " + b"x" * 70_000 + b"\n" + GOOD + b"; \x00\n"}, code=0,
    creates=("o.gcode",), check=lambda d, r: b"; \x00\n" in (d / "o.gcode").read_bytes()))
# optimize: profiles
add("opt -m missing yaml", Case(["in.gcode", "-o", "o.gcode", "-m", "nope.yaml"], G, "not found"))
add("opt -m binary yaml", Case(["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
                               {**G, "p.yaml": b"\xff\xfe\x00\x01" * 10}, "binary"))
add("opt -m latin-1 yaml", Case(["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
                                {**G, "p.yaml": b"name: caf\xe9\n"}, "not utf-8"))
add("opt -m yaml nan limit", Case(
    ["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
    {**G, "p.yaml": YAML_OK.replace(b"vmax_mm_s: ", b"vmax_mm_s: .nan #", 1)}, "vmax_mm_s"))
add("opt -m yaml syntax", Case(["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
                               {**G, "p.yaml": b"limits: [\n"}, "yaml"))
add("opt -m yaml list", Case(["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
                             {**G, "p.yaml": b"- 1\n- 2\n"}, "p.yaml"))
add("opt -m yaml empty", Case(["in.gcode", "-o", "o.gcode", "-m", "p.yaml"],
                              {**G, "p.yaml": b""}, "p.yaml"))
add("opt -m unknown name", Case(["in.gcode", "-o", "o.gcode", "-m", "ender3"], G, "did you mean"))
add("opt --method unknown", Case(["in.gcode", "-o", "o.gcode", "-m", "ender3pro", "--method",
                                  "fast"], G, "--method"))
add("opt unknown option", Case(["in.gcode", "--bogus", *OPT], G, "--bogus"))
add("opt --machine missing", Case(["in.gcode", "-o", "o.gcode"], G, "--machine"))
add("opt --mode unknown", Case(["in.gcode", "-o", "o.gcode", *OPT, "--mode", "x"], G, "--mode"))
add("opt --vmax 0.1 on a long file", Case(
    ["big.gcode", "-o", "o.gcode", "-m", "ender3pro", "--vmax", "0.1", "-q"],
    {"big.gcode": GOOD * 2000}, "above the limit"))

# simulate
S = ["-m", "ender3pro", "-q"]
add("sim --log is the input", Case(["simulate", "in.gcode", *S, "--log", "in.gcode"], G,
                                   "is the input file"))
add("sim --log missing folder", Case(["simulate", "in.gcode", *S, "--log", "no/l.csv"], G,
                                     "does not exist"))
add("sim --log /dev/null", Case(["simulate", "in.gcode", *S, "--log", "/dev/null"], G,
                                "character device"))
add("sim --log /dev/full", Case(["simulate", "in.gcode", *S, "--log", "/dev/full"], G,
                                "character device"))
add("sim --log a folder", Case(["simulate", "in.gcode", *S, "--log", "d"], {**G, "d": DIR},
                               "directory"))
add("sim --report missing folder", Case(["simulate", "in.gcode", *S, "--report", "no/r.json"], G,
                                        "does not exist"))
add("sim --report is the input", Case(["simulate", "in.gcode", *S, "--report", "in.gcode"], G,
                                      "is the input file"))
add("sim --log and --report one file", Case(["simulate", "in.gcode", *S, "--log", "x",
                                             "--report", "x"], G, "both write"))
add("sim --log and --report both stdout", Case(["simulate", "in.gcode", *S, "--log", "-",
                                                "--report", "-"], G, "stdout"))
add("sim input fifo", Case(["simulate", "p", *S], {"p": FIFO}, "fifo"))
add("sim input missing", Case(["simulate", "nope.gcode", *S], {}, "nope.gcode"))
add("sim input binary", Case(["simulate", "in.gcode", *S], {"in.gcode": b"\x00\x01" * 50}, "nul"))
add("sim input CR only", Case(["simulate", "in.gcode", *S],
                              {"in.gcode": GOOD.replace(b"\n", b"\r")}, "cr only"))
add("sim --effect unknown kind", Case(["simulate", "in.gcode", *S, "--effect", "bogus:axis=x"],
                                      G, "--effect"))
add("sim --effect bad axis", Case(["simulate", "in.gcode", *S, "--effect",
                                   "backlash:axis=q,magnitude_mm=0.1"], G, "--effect"))
add("sim --effect nan amplitude", Case(["simulate", "in.gcode", *S, "--effect",
                                        "sinusoid:axis=x,amp_mm=nan,freq_hz=10"], G, "--effect"))
add("sim --effect huge amplitude", Case(["simulate", "in.gcode", *S, "--effect",
                                         "sinusoid:axis=x,amp_mm=1e308,freq_hz=10"], G,
                                        "--effect"))
add("sim --contour-on unknown", Case(["simulate", "in.gcode", *S, "--contour-on", "z"], G,
                                     "--contour-on"))
add("sim --seed 1.5", Case(["simulate", "in.gcode", *S, "--seed", "1.5"], G, "--seed"))
add("sim --log - writes stdout", Case(["simulate", "in.gcode", *S, "--log", "-"], G, code=0,
                                      check=lambda d, r: r.stdout.startswith("t,x_cmd")))
add("sim --log creates 0644", Case(["simulate", "in.gcode", *S, "--log", "l.csv"], G, code=0,
                                   creates=("l.csv",),
                                   check=lambda d, r: stat.S_IMODE(os.stat(d / "l.csv").st_mode)
                                   == 0o644))

# predict
P = ["-m", "ender3pro"]
L = {"log.csv": log_rows()}
add("predict -o is the log", Case(["predict", "log.csv", *P, "-o", "log.csv"], L,
                                  "is the input file"))
add("predict -o missing folder", Case(["predict", "log.csv", *P, "-o", "no/p.csv"], L,
                                      "does not exist"))
add("predict -o /dev/full", Case(["predict", "log.csv", *P, "-o", "/dev/full"], L,
                                 "character device"))
add("predict -o a folder", Case(["predict", "log.csv", *P, "-o", "d"], {**L, "d": DIR},
                                "directory"))
add("predict log binary", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                               {"log.csv": LOG_HEAD + b"\x00\x01\x02\n"}, "binary"))
add("predict log latin-1", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                {"log.csv": LOG_HEAD + b"0,\xe9\n"}, "not utf-8"))
add("predict log 1e308", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                              {"log.csv": log_rows(bad_row=b"0.010000,1e308,0,0,0\n")}, "beyond"))
add("predict log nan", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                            {"log.csv": log_rows(bad_row=b"0.010000,nan,0,0,0\n")}, "finite"))
add("predict log text cell", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                  {"log.csv": log_rows(bad_row=b"0.010000,abc,0,0,0\n")},
                                  "numbers"))
add("predict log short row", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                  {"log.csv": log_rows(bad_row=b"0.010000,1\n")}, "log.csv"))
add("predict log header only", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                    {"log.csv": LOG_HEAD}, "log.csv"))
add("predict log empty", Case(["predict", "log.csv", *P, "-o", "p.csv"], {"log.csv": b""},
                              "column"))
add("predict log without x_cmd", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                      {"log.csv": b"t,a,b\n" + b"0,0,0\n" * 20}, "x_cmd"))
add("predict log too short", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                  {"log.csv": log_rows(5)}, "rows"))
add("predict log non-uniform", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                    {"log.csv": log_rows(bad_row=b"0.0105,0,0,0,0\n")},
                                    "uniform"))
add("predict log other Ts", Case(["predict", "log.csv", *P, "-o", "p.csv"],
                                 {"log.csv": LOG_HEAD + b"".join(b"%.3f,0,0,0,0\n" % (k * 0.004)
                                                                 for k in range(40))}, code=0,
                                 creates=("p.csv",)))
add("predict log fifo", Case(["predict", "log.csv", *P, "-o", "p.csv"], {"log.csv": FIFO}, "fifo"))
add("predict log missing", Case(["predict", "nope.csv", *P, "-o", "p.csv"], {}, "no such file"))
add("predict log is G-code", Case(["predict", "in.gcode", *P, "-o", "p.csv"], G, "column"))
add("predict works", Case(["predict", "log.csv", *P, "-o", "p.csv"], L, code=0,
                          creates=("p.csv",),
                          check=lambda d, r: (d / "p.csv").read_text().startswith("t,x_mean")))

# compare
C = ["compare", "in.gcode", "-m", "ender3pro", "--methods", "kinematic"]
add("compare --json is the input", Case([*C, "--json", "in.gcode"], G, "is the input file"))
add("compare --json missing folder", Case([*C, "--json", "no/c.json"], G, "does not exist"))
add("compare --json /dev/full", Case([*C, "--json", "/dev/full"], G, "character device"))
add("compare --plot unknown type", Case([*C, "--plot", "c.xyz"], G, "unsupported file type"))
add("compare --plot missing folder", Case([*C, "--plot", "no/c.png"], G, "does not exist"))
add("compare --json and --plot one file", Case([*C, "--json", "c.png", "--plot", "c.png"], G,
                                               "both write"))
add("compare --methods empty", Case([*C[:4], "--methods", ""], G, "--methods"))
add("compare --methods comma", Case([*C[:4], "--methods", ","], G, "--methods"))
add("compare --methods unknown", Case([*C[:4], "--methods", "fast,pb"], G, "unknown fast"))
add("compare input binary", Case([*C], {"in.gcode": b"\x00" * 100}, "nul"))
add("compare input missing", Case(["compare", "nope.gcode", "-m", "ender3pro"], {}, "nope.gcode"))
add("compare input fifo", Case(["compare", "p", "-m", "ender3pro"], {"p": FIFO}, "fifo"))
add("compare --effect bad", Case([*C, "--effect", "x"], G, "--effect"))
add("compare -m unknown", Case(["compare", "in.gcode", "-m", "nope"], G, "unknown machine"))
add("compare --json - writes stdout", Case([*C, "--json", "-"], G, code=0,
                                           check=lambda d, r: r.stdout.lstrip().startswith("{")))

# diagnose (logs from the independent benchA, read at test time)
D = ["diagnose", "log.csv", "-m", "ender3pro"]


def bench_log():
    return real(INDEPENDENT_DIR / "logs" / "log_01.csv", 1500)


DL = {"log.csv": bench_log}
add("diagnose --json missing folder", Case([*D, "--json", "no/d.json"], DL, "does not exist"))
add("diagnose --json is the log", Case([*D, "--json", "log.csv"], DL, "is the input file"))
add("diagnose --json /dev/full", Case([*D, "--json", "/dev/full"], DL, "character device"))
add("diagnose --plot unknown type", Case([*D, "--plot", "d.jpg"], DL, "unsupported file type"))
add("diagnose --plot missing folder", Case([*D, "--plot", "no/d.png"], DL, "does not exist"))
add("diagnose -o missing folder", Case([*D, "-o", "no/e.yaml"], DL, "does not exist"))
add("diagnose -o not yaml", Case([*D, "-o", "e.txt"], DL, "unsupported file type"))
add("diagnose -o is the profile", Case(["diagnose", "log.csv", "-m", "p.yaml", "-o", "p.yaml"],
                                       {**DL, **PROFILE}, "is the input file"))
add("diagnose --json and --plot one file", Case([*D, "--json", "x.png", "--plot", "x.png"], DL,
                                                "both write"))
add("diagnose log binary", Case(D, {"log.csv": LOG_HEAD + b"\x00\x01\n"}, "log.csv"))
add("diagnose log missing", Case(["diagnose", "nope.csv", "-m", "ender3pro"], {}, "nope.csv"))
add("diagnose log fifo", Case(D, {"log.csv": FIFO}, "fifo"))
add("diagnose log is G-code", Case(D, {"log.csv": GOOD}, "log.csv"))
add("diagnose log empty", Case(D, {"log.csv": b""}, "log.csv"))
add("diagnose --raw-axis z", Case([*D, "--raw-axis", "z"], DL, "--raw-axis"))

# learn
LN = ["learn", "log.csv", "-m", "ender3pro"]
add("learn -o missing folder", Case([*LN, "-o", "no/u.yaml"], DL, "does not exist"))
add("learn -o not yaml", Case([*LN, "-o", "u.csv"], DL, "unsupported file type"))
add("learn -o is the profile", Case(["learn", "log.csv", "-m", "p.yaml", "-o", "p.yaml"],
                                    {**DL, **PROFILE}, "is the input file"))
add("learn -o FRF folder is a file", Case([*LN, "-o", "u.yaml"], {**DL, "u": b"x"},
                                          "not a folder"))
add("learn log binary", Case([*LN, "-o", "u.yaml"], {"log.csv": LOG_HEAD + b"\x00\n"}, "log.csv"))
add("learn log missing", Case(["learn", "nope.csv", "-m", "ender3pro", "-o", "u.yaml"], {},
                              "nope.csv"))
add("learn log fifo", Case([*LN, "-o", "u.yaml"], {"log.csv": FIFO}, "fifo"))
add("learn --skip-bad with only bad logs", Case([*LN, "-o", "u.yaml", "--skip-bad"],
                                                {"log.csv": b"junk\n"}, "no log was learned",
                                                lines=2))
add("learn no -o", Case(LN, DL, "-o"))

# identify
I = ["identify", "--x", "x.csv", "--modes", "1"]
FX = {"x.csv": FRF_OK}
add("identify -o missing folder", Case([*I, "-o", "no/m.yaml"], FX, "does not exist"))
add("identify -o not yaml", Case([*I, "-o", "m.txt"], FX, "unsupported file type"))
add("identify -o /dev/null", Case([*I, "-o", "/dev/null"], FX, "unsupported file type"))
add("identify -o FRF folder is a file", Case([*I, "-o", "m.yaml"], {**FX, "m": b"x"},
                                             "not a folder"))
add("identify -o FRF folder holds the input", Case(["identify", "--x", "m/x.csv", "-o", "m.yaml"],
                                                   {"m/x.csv": FRF_OK}, "where the input"))
add("identify --plot unknown type", Case([*I, "-o", "m.yaml", "--plot", "f.xyz"], FX,
                                         "unsupported file type"))
add("identify --plot missing folder", Case([*I, "-o", "m.yaml", "--plot", "no/f.png"], FX,
                                           "does not exist"))
add("identify --x binary", Case([*I, "-o", "m.yaml"],
                                {"x.csv": FRF_HEAD + b"10,1,0\n\x00\x01\xff,1,0\n"}, "binary"))
add("identify --x latin-1", Case([*I, "-o", "m.yaml"], {"x.csv": FRF_HEAD + b"10,1,\xe9\n"},
                                 "not utf-8"))
add("identify --x 1e308", Case([*I, "-o", "m.yaml"],
                               {"x.csv": FRF_HEAD + b"10,1,0\n20,1e308,0\n30,1,0\n40,1,0\n"},
                               "beyond"))
add("identify --x nan", Case([*I, "-o", "m.yaml"],
                             {"x.csv": FRF_HEAD + b"10,1,0\n20,nan,0\n30,1,0\n40,1,0\n"},
                             "not a number"))
add("identify --x text cell", Case([*I, "-o", "m.yaml"],
                                   {"x.csv": FRF_HEAD + b"10,1,0\n20,abc,0\n30,1,0\n"}, "x.csv"))
add("identify --x header only", Case([*I, "-o", "m.yaml"], {"x.csv": FRF_HEAD}, "no data rows"))
add("identify --x unknown header", Case([*I, "-o", "m.yaml"], {"x.csv": b"a,b,c\n1,2,3\n"},
                                        "unknown file kind"))
add("identify --x is G-code", Case([*I, "-o", "m.yaml"], {"x.csv": GOOD}, "unknown file kind"))
add("identify --x fifo", Case([*I, "-o", "m.yaml"], {"x.csv": FIFO}, "fifo"))
add("identify --x missing", Case([*I, "-o", "m.yaml"], {}, "x.csv"))
add("identify spectra binary", Case([*I, "-o", "m.yaml"],
                                    {"x.csv": b"freq,psd_x,psd_y,psd_z,psd_xyz\n\x00\n"},
                                    "binary"))
add("identify raw 1e308", Case([*I, "-o", "m.yaml"],
                               {"x.csv": b"#time,accel_x,accel_y,accel_z\n0,1,1,1\n0.001,1e308,1,1\n"},
                               "beyond"))
add("identify raw text", Case([*I, "-o", "m.yaml"],
                              {"x.csv": b"#time,accel_x,accel_y,accel_z\n0,1,1,1\n0.001,a,1,1\n"},
                              "x.csv"))
add("identify no files", Case(["identify", "-o", "m.yaml"], {}, "--x"))
add("identify --modes 5", Case(["identify", "--x", "x.csv", "--modes", "5", "-o", "m.yaml"], FX,
                               "--modes"))
add("identify --segments 1", Case(["identify", "--x", "x.csv", "--segments", "1", "-o", "m.yaml"],
                                  FX, "--segments"))
add("identify overrides without --excitation", Case([*I, "-o", "m.yaml", "--freq-start", "5"],
                                                    FX, "--excitation"))
add("identify --base unknown", Case([*I, "-o", "m.yaml", "--base", "nope"], FX,
                                    "unknown machine"))
add("identify works", Case([*I, "-o", "m.yaml"], FX, code=0, creates=("m.yaml", "m", "m/*.csv")))

# profile build / show / check
B = ["profile", "build", "--frf-x", "x.csv"]
add("build -o missing folder", Case([*B, "-o", "no/p.yaml"], FX, "does not exist"))
add("build -o not yaml", Case([*B, "-o", "p.json"], FX, "unsupported file type"))
add("build -o FRF folder holds the input", Case(["profile", "build", "--frf-x", "p/x.csv", "-o",
                                                 "p.yaml"], {"p/x.csv": FRF_OK},
                                                "where the input"))
add("build --frf-x binary", Case([*B, "-o", "p.yaml"], {"x.csv": FRF_HEAD + b"\x00\n"}, "binary"))
add("build --frf-x 1e308", Case([*B, "-o", "p.yaml"],
                                {"x.csv": FRF_HEAD + b"10,1,0\n20,1e308,0\n30,1,0\n40,1,0\n"},
                                "beyond"))
add("build --frf-x nan", Case([*B, "-o", "p.yaml"],
                              {"x.csv": FRF_HEAD + b"10,1,0\n20,nan,0\n30,1,0\n40,1,0\n"},
                              "non-finite"))
add("build --frf-x bad header", Case([*B, "-o", "p.yaml"], {"x.csv": b"f,r,i\n1,2,3\n"},
                                     "header"))
add("build --frf-x decreasing freq", Case(
    [*B, "-o", "p.yaml"], {"x.csv": FRF_HEAD + b"40,1,0\n30,1,0\n20,1,0\n10,1,0\n"},
    "increasing"))
add("build --frf-x missing", Case([*B, "-o", "p.yaml"], {}, "no such frf file"))
add("build no files", Case(["profile", "build", "-o", "p.yaml"], {}, "--frf-x"))
add("build no -o", Case(B, FX, "-o"))
add("build unknown option", Case([*B, "--bogus", "-o", "p.yaml"], FX, "--bogus"))
add("build --base unknown", Case([*B, "--base", "nope", "-o", "p.yaml"], FX, "unknown machine"))
add("show binary yaml", Case(["profile", "show", "p.yaml"], {"p.yaml": b"\x00\x01"}, "binary"))
add("check missing", Case(["profile", "check", "nope.yaml"], {}, "not found"))
add("check fifo", Case(["profile", "check", "p.yaml"], {"p.yaml": FIFO}, "fifo"))
add("check unknown key", Case(["profile", "check", "p.yaml"],
                              {"p.yaml": YAML_OK.replace(b"limits:", b"limitz:", 1)}, "limitz"))

# batch
BA = ["batch", "jobs", "-m", "ender3pro", "--method", "kinematic", "-j", "1"]
J = {"jobs/a.gcode": GOOD}
add("batch -o missing parent", Case([*BA, "-o", "no/out"], J, "does not exist"))
add("batch -o is a file", Case([*BA, "-o", "f"], {**J, "f": b"x"}, "is a file"))
add("batch folder missing", Case(["batch", "nope", "-m", "ender3pro"], {}, "nope"))
add("batch folder is a file", Case(["batch", "f", "-m", "ender3pro"], {"f": b"x"}, "f"))
add("batch -j 0", Case([*BA, "-j", "0"], J, "--jobs"))
add("batch --machine unknown", Case(["batch", "jobs", "-m", "nope"], J, "unknown machine"))
add("batch bad file fails alone", Case(
    [*BA, "-o", "out"], {"jobs/a.gcode": GOOD, "jobs/b.gcode": b"\x00\x01"}, code=1,
    creates=("out", "out/a.gcode"),
    check=lambda d, r: "failed" in r.stdout and "ok" in r.stdout))
add("batch empty folder", Case([*BA], {"jobs": DIR}, code=0))

# the command line itself
add("no arguments shows help", Case([], {}, "usage", code=2))
add("unknown sub-command is a G-code path", Case(["frobnicate"], {}, "--machine"))
add("--version", Case(["--version"], {}, code=0))


@pytest.mark.parametrize("name", sorted(CASES))
def test_fault_corpus(name, tmp_path, monkeypatch):
    case = CASES[name]
    files = dict(case.files)
    links = {k: v for k, v in files.items() if isinstance(v, tuple) and v[0] == "hardlink"}
    for k in links:
        del files[k]
    try:
        make(tmp_path, files)
    except pytest.skip.Exception:
        raise
    for k, (_, target) in links.items():
        os.link(tmp_path / target, tmp_path / k)
    before = snapshot(tmp_path)
    devices = device_state()
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(cli, case.argv)
    # never a traceback
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in res.output
    assert res.exit_code == case.code, (res.exit_code, res.output[-2000:])
    after = snapshot(tmp_path)
    assert device_state() == devices  # /dev/null is still a device
    # no temporary file, anywhere
    assert not [p for p in after if ".tmp" in p or p.endswith(".part")], sorted(after)
    if case.code == 2:
        if case.argv:  # (bare `gcode-feedopt` prints the help)
            out = res.stderr.strip().splitlines()
            assert len(out) == case.lines, res.stderr
            line = out[-1]
            assert 0 < len(line) <= 300, res.stderr
            assert line.startswith("gcode-feedopt: error:"), line
            assert case.match.lower() in line.lower(), line
        assert after == before, "a file changed, appeared or vanished"
    else:
        changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)}
        allowed = {k for k in changed if any(fnmatch.fnmatch(k, c) for c in case.creates)}
        assert changed == allowed, sorted(changed - allowed)
        if case.check is not None:
            assert case.check(tmp_path, res), res.output[-2000:]


def test_corpus_size():
    """Issue 18 asks for at least 150 cases, every sub-command covered (with test_bad_input's
    reader cases, test_option_limits' numeric options and test_signals' faults)."""
    from . import test_bad_input

    assert len(CASES) + len(test_bad_input.CASES) >= 150
    words = {c.argv[0] if c.argv and not c.argv[0].endswith((".gcode", "p", "d")) else "optimize"
             for c in CASES.values()}
    for sub in ("optimize", "simulate", "predict", "compare", "diagnose", "learn", "identify",
                "profile", "batch"):
        assert sub in words, sub


def test_a_long_path_is_shortened_before_the_fix_is_cut():
    """An error about a file deep in folders (a logger's, pytest's workers'): the line keeps
    what, the file with its folder, and the fix; only a message still too long is cut in the
    middle."""
    from gcode_feedopt.cli import MAX_ERROR_CHARS, one_line

    deep = "/home/maker/printers/ender/2026-11/logs_of_the_week/" * 3
    msg = (f"{deep}day3/log.csv: t steps by 2 per row: is t in milliseconds? a log's t is in "
           "seconds (a 2 ms logger steps by 0.002): divide the column by 1000; in seconds, the "
           "log is too coarse to show a printer's motion (log at 1–10 ms)")
    assert len(msg) > MAX_ERROR_CHARS
    got = one_line(msg)
    assert len(got) <= MAX_ERROR_CHARS
    assert got.startswith(".../day3/log.csv: t steps by 2 per row")
    assert "divide the column by 1000" in got and " ... " not in got
    assert one_line("see https://example.com/" + "a/" * 200).count(" ... ") == 1
    assert one_line("short /a/b/c.csv") == "short /a/b/c.csv"
