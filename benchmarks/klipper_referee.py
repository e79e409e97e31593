"""Real Klipper as the referee of the Klipper firmware model (issue 20, point 4).

Seven cases: the first 20,000 lines of three real files (prepared: heaters, fans, homing,
levelling and motors-off lines dropped, as batch-mode Klipper cannot run them), each as sliced
and as our kinematic output for the referee's printer (tests/vm/data/klipper_referee/
klipper300.yaml, the same machine as the referee's printer.cfg, plus ``[gcode_arcs]``), and an
ArcWelder file's arcs as sliced. Klipper's planner times each file in batch mode
(../shared/tools/klipper-referee/); our firmware model (vm.firmware.estimate_time_s) times the
same bytes.

    # a Klipper tree built by the harness (setup.sh: linux-process MCU dictionary, klippy's
    # python, the timing probe), e.g. from the fetched mirror:
    ../shared/tools/klipper-referee/setup.sh KLIPPER_GIT_DIR /tmp/kl
    python benchmarks/klipper_referee.py --klipper /tmp/kl/klipper --python /tmp/kl/venv/bin/python
    python benchmarks/klipper_referee.py ... --record     # rewrite the reference data
    python benchmarks/klipper_referee.py                  # the model against the recorded times

``--record`` regenerates tests/vm/data/klipper_referee/: referee.json (Klipper commit, the
printer.cfg, per case the input's SHA-256, the referee's time and the model's at recording)
and our outputs (``*.out.gcode.xz``: the bytes Klipper timed, so the test needs no Klipper and
stays valid when later plans write different files). tests/vm/test_klipper_referee.py holds
the model to 0.5 % of the recorded times. Without --klipper the script prints the model's
times against the recorded ones.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import lzma
import os
import pathlib
import subprocess
import sys
import tempfile

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gcode_feedopt.gcode.reader import read_program  # noqa: E402
from gcode_feedopt.profile import load_profile  # noqa: E402
from gcode_feedopt.vm.firmware import estimate_time_s  # noqa: E402

SHARED = REPO.parent / "shared"
HARNESS = SHARED / "tools" / "klipper-referee"
DATA_DIR = REPO / "tests" / "vm" / "data" / "klipper_referee"
PROFILE = DATA_DIR / "klipper300.yaml"
RECORD = DATA_DIR / "referee.json"
LINES = 20000
#: name -> source file
SOURCES = {
    "cura_benchy": SHARED / "data" / "gcode" / "cura-4.11_ender3_3dbenchy.gcode",
    "prusa_mini_benchy": SHARED / "data" / "gcode" / "prusaslicer-2.6.1_mini_3dbenchy.gcode",
    "butterfly": REPO / "sample_gcode" / "butterfly.gcode",
    "arcwelder_benchy": SHARED / "data" / "gcode" / "slic3rpe-arcwelder_3dbenchy-arcs.gcode",
}
#: the sources whose kinematic output is refereed too (the outputs are stored: issue 20's three)
WITH_OUTPUT = ("cura_benchy", "prusa_mini_benchy", "butterfly")
#: added to the harness's printer.cfg: G2/G3 as chords of 1 mm (profile: mm_per_arc_segment)
ARCS_CFG = "\n[gcode_arcs]\nresolution: 1.0\n"
#: what batch-mode Klipper cannot run (the harness's prep.py drops the same words)
STRIP = {"M104", "M109", "M140", "M190", "M105", "M106", "M107", "G28", "G29", "M84"}


def prepare(src: pathlib.Path, nlines: int = LINES) -> bytes:
    """The first ``nlines`` lines of ``src`` without the lines whose first word is in STRIP;
    every line ends with a newline."""
    out = []
    for i, raw in enumerate(src.read_bytes().splitlines(keepends=True)):
        if i >= nlines:
            break
        code = raw.decode("utf-8", "replace").split(";", 1)[0].strip()
        word = code.split()[0].upper() if code else ""
        if word in STRIP:
            continue
        out.append(raw if raw.endswith(b"\n") else raw + b"\n")
    return b"".join(out)


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def model_time_s(data: bytes, profile) -> float:
    """Our firmware model's time for ``data`` (the pipeline's reader settings)."""
    fw = profile.firmware
    prog = read_program(data, "referee.gcode", flavour=fw.flavour,
                        g91_relative_e=fw.g91_relative_e, retract_mm=fw.retract_mm,
                        retract_speed_mm_s=fw.retract_speed_mm_s,
                        e_feed_mm_s=fw.max_feed_mm_s["e"])
    return estimate_time_s(prog, profile)


def our_output(data: bytes, workdir: pathlib.Path, name: str) -> bytes:
    """``gcode-feedopt IN -o OUT --machine klipper300.yaml --method kinematic``."""
    src = workdir / f"{name}.gcode"
    dst = workdir / f"{name}.out.gcode"
    src.write_bytes(data)
    subprocess.run([sys.executable, "-m", "gcode_feedopt", "optimize", str(src), "-o", str(dst),
                    "--machine", str(PROFILE), "--method", "kinematic", "-q"],
                   check=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    return dst.read_bytes()


def referee_time_s(data: bytes, workdir: pathlib.Path, name: str, klipper: str, python: str,
                   cfg: pathlib.Path) -> dict:
    """Klipper's batch-mode time of ``data`` (the harness's klipper_time.py, --json)."""
    path = workdir / f"{name}.klipper.gcode"
    path.write_bytes(data)
    res = subprocess.run([sys.executable, str(HARNESS / "klipper_time.py"), "--klipper", klipper,
                          "--python", python, "--cfg", str(cfg), "--workdir", str(workdir),
                          "--json", str(path)], check=True, capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def klipper_commit(klipper: str) -> str:
    """The commit of the Klipper tree: its git HEAD, or (a tree exported by the harness's
    setup.sh has no .git) what --commit says."""
    try:
        return subprocess.run(["git", "-C", klipper, "rev-parse", "HEAD"], check=True,
                              capture_output=True, text=True).stdout.strip()
    except (subprocess.CalledProcessError, FileNotFoundError):
        return ""


def cases(workdir: pathlib.Path | None, only: str | None = None):
    """(case name, bytes) of the six cases (those whose name contains ``only``): inputs
    prepared from the sources; outputs made by our optimizer (``workdir`` given) or read from
    the recorded ``.xz`` files."""
    for name, src in SOURCES.items():
        data = prepare(src)
        if not only or only in f"{name}/original":
            yield f"{name}/original", data
        if name not in WITH_OUTPUT or (only and only not in f"{name}/output"):
            continue
        if workdir is not None:
            yield f"{name}/output", our_output(data, workdir, name)
        else:
            yield f"{name}/output", lzma.decompress((DATA_DIR / f"{name}.out.gcode.xz")
                                                    .read_bytes())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--klipper", help="Klipper tree built by the harness's setup.sh")
    ap.add_argument("--python", help="klippy's python (setup.sh: DEST/venv/bin/python)")
    ap.add_argument("--commit", default="", help="Klipper commit, if the tree has no .git")
    ap.add_argument("--cfg", default=str(HARNESS / "printer.cfg.in"),
                    help="the harness's printer.cfg template ([gcode_arcs] is added)")
    ap.add_argument("--record", action="store_true", help="rewrite the reference data")
    ap.add_argument("--only", help="only the cases whose name contains this")
    a = ap.parse_args(argv)
    profile = load_profile(PROFILE)
    live = a.klipper is not None
    if live and not a.python:
        ap.error("--klipper needs --python")
    recorded = json.loads(RECORD.read_text()) if RECORD.exists() else {"cases": {}}
    rows = {}
    with tempfile.TemporaryDirectory(prefix="referee_") as tmp:
        work = pathlib.Path(tmp)
        cfg_text = pathlib.Path(a.cfg).read_text() + ARCS_CFG
        cfg = work / "printer.cfg.in"
        cfg.write_text(cfg_text)
        for case, data in cases(work if live else None, a.only):
            model = model_time_s(data, profile)
            if live:
                ref = referee_time_s(data, work, case.replace("/", "_"), a.klipper, a.python,
                                     cfg)["elapsed_s"]
            else:
                ref = recorded["cases"].get(case, {}).get("referee_s", float("nan"))
            rows[case] = {"sha256": sha256(data), "lines": data.count(b"\n"),
                          "referee_s": round(ref, 6), "model_s": round(model, 6)}
            rec = recorded["cases"].get(case, {})
            note = ("" if rec.get("sha256") in (None, rows[case]["sha256"])
                    else "  (not the recorded bytes: --record to update)")
            print(f"{case:28s} referee {ref:12.6f} s  model {model:12.6f} s  "
                  f"{100 * (model / ref - 1):+8.4f} %{note}", flush=True)
            if live and a.record and case.endswith("/output"):
                name = case.split("/")[0]
                (DATA_DIR / f"{name}.out.gcode.xz").write_bytes(
                    lzma.compress(data, preset=9 | lzma.PRESET_EXTREME))
    if a.record:
        if not live:
            ap.error("--record needs --klipper and --python")
        doc = {
            "what": "Klipper batch-mode planner times (referee) of seven G-code cases, and our "
                    "Klipper firmware model's times when recorded; benchmarks/klipper_referee.py",
            "klipper_commit": a.commit or klipper_commit(a.klipper),
            "harness": "../shared/tools/klipper-referee (klipper_time.py, timing_probe.py "
                       "with suppress_batch_runout)",
            "printer_cfg": cfg_text,
            "profile": str(PROFILE.relative_to(REPO)),
            "lines": LINES,
            "strip": sorted(STRIP),
            "output_command": "gcode-feedopt optimize IN -o OUT --machine "
                              f"{PROFILE.relative_to(REPO)} --method kinematic",
            "cases": {k: {**recorded["cases"].get(k, {}), **v} for k, v in rows.items()},
        }
        RECORD.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {RECORD}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
