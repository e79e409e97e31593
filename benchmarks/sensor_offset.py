"""Does reading a log take a machine's own behaviour for a sensor offset? (closedloop.logs,
*The sensor's zero*)

Every log of benchA and of the foreign machines of tests/foreign/machines.py (seeds given) is
read as ``learn`` / ``diagnose`` read it (``load_log``, profile built from the machine's own
FRFs); printed: the logs whose measured positions had an offset subtracted (none of these
machines has one: each is a false alarm) and those said to hold a constant the log cannot tell
from a gain.

    python benchmarks/sensor_offset.py                      # benchA + seeds 0–7, ~30 s
    python benchmarks/sensor_offset.py --seeds $(seq 0 67)  # ~4 min

The other direction (offsets put in, what is subtracted and what the diagnosis names):
``python benchmarks/independent.py --sensor-offset 0.05 -0.03``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import warnings

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from independent import DATA, bench_a_profile  # noqa: E402
from tests.foreign.machines import make_machine, write_dataset  # noqa: E402

from gcode_feedopt.closedloop.logs import load_log  # noqa: E402


def judge(data: pathlib.Path, name: str):
    """[(log file, truth kinds, subtracted {axis: mm}, "cannot tell" warnings)] of a data set."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof = bench_a_profile(data, name)
    labels = json.loads((data / "labels.json").read_text())
    rows = []
    for e in labels["logs"]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            log = load_log(data / e["file"], prof)
        said = [str(w.message) for w in caught if "cannot tell" in str(w.message)]
        kinds = ", ".join(f"{x['kind']} {x['axis'] or ''}".strip() for x in e["effects"])
        rows.append((e["file"], kinds, log.info.get("sensor_offset_mm", {}), said))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=list(range(8)))
    args = ap.parse_args()
    base = pathlib.Path(tempfile.mkdtemp(prefix="sensor-offset-"))
    sets = [("benchA", DATA)] if DATA.is_dir() else []
    n_logs = n_sub = n_either = 0
    print("| data set | log | truth | subtracted | cannot tell |")
    print("| --- | --- | --- | --- | --- |")
    for seed in [None] + args.seeds:
        if seed is None:
            if not sets:
                continue
            tag, data = sets[0]
        else:
            tag, data = f"seed {seed}", base / f"foreign-{seed}"
            write_dataset(make_machine(seed), data)
        for file, kinds, sub, said in judge(data, tag.replace(" ", "")):
            n_logs += 1
            n_sub += bool(sub)
            n_either += bool(said)
            if sub or said:
                print(f"| {tag} | {file} | {kinds} | "
                      f"{', '.join(f'{a} {o:+.4f} mm' for a, o in sub.items()) or '-'} | "
                      f"{'; '.join(s.split(': ', 1)[1][:90] for s in said) or '-'} |")
    print(f"\n{n_logs} logs: an offset subtracted from {n_sub}, \"cannot tell\" said on "
          f"{n_either} (none of these machines' sensors has an offset)")


if __name__ == "__main__":
    main()
