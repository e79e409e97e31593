"""Batch over a folder of jobs: every G-code file, in parallel processes; one failure never
stops the others; Ctrl-C leaves no half-written file (each write is temp + os.replace, and the
temp is removed on any exception)."""

from __future__ import annotations

import concurrent.futures as cf
import os
import pathlib
from dataclasses import dataclass

from ..errors import FeedOptError
from ..gcode.reader import IDENT_PREFIX

SUFFIXES = (".gcode", ".gco", ".g")


@dataclass
class JobResult:
    file: str
    status: str  # ok | skipped | failed
    input_time_s: float | None = None
    output_time_s: float | None = None
    message: str = ""

    @property
    def saved_pct(self) -> float | None:
        if not self.input_time_s or self.output_time_s is None:
            return None
        return 100.0 * (self.input_time_s - self.output_time_s) / self.input_time_s


def find_jobs(folder: pathlib.Path) -> list[pathlib.Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES)


def already_processed(path: pathlib.Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(4096)
    return IDENT_PREFIX in head


def run_one(src: str, dst: str, machine: str, opts_dict: dict) -> JobResult:
    """One job, in a worker process. Never raises for a bad file: returns its status."""
    from ..pipeline import Options, optimize_file
    from ..profile import load_profile

    src_p, dst_p = pathlib.Path(src), pathlib.Path(dst)
    try:
        if already_processed(src_p) and not opts_dict.get("force"):
            return JobResult(src_p.name, "skipped", message="already processed")
        if dst_p != src_p and dst_p.exists() and dst_p.stat().st_mtime >= src_p.stat().st_mtime \
                and already_processed(dst_p) and not opts_dict.get("force"):
            return JobResult(src_p.name, "skipped", message="output up to date")
        rep = optimize_file(src_p, dst_p, load_profile(machine), Options(**opts_dict))
        return JobResult(src_p.name, "ok", rep.input_time_s, rep.output_time_s)
    except FeedOptError as exc:
        return JobResult(src_p.name, "failed", message=str(exc))
    except Exception as exc:  # a bug must not stop the other jobs; report it as such
        return JobResult(src_p.name, "failed", message=f"internal error: {exc!r}")


def run_batch(folder: pathlib.Path, outdir: pathlib.Path | None, machine: str, opts_dict: dict,
              jobs: int, progress=None) -> list[JobResult]:
    """Process every G-code file in ``folder``; results in file order."""
    files = find_jobs(folder)
    if outdir is not None:
        from ..outputs import make_output_folder

        make_output_folder(outdir, "-o")  # the output folder itself; its parent must exist
    results: dict[str, JobResult] = {}
    # the jobs are the parallelism: a twin method inside a job plans in one process unless
    # the user set GCODE_FEEDOPT_JOBS (optimize/parallel.py)
    if jobs > 1:
        os.environ.setdefault("GCODE_FEEDOPT_JOBS", "1")
    with cf.ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        futs = {pool.submit(run_one, str(f), str((outdir or folder) / f.name), machine,
                            opts_dict): f for f in files}
        try:
            for fut in cf.as_completed(futs):
                r = fut.result()
                results[futs[fut].name] = r
                if progress is not None:
                    progress(r)
        except KeyboardInterrupt:
            for fut in futs:
                fut.cancel()
            raise
    return [results[f.name] for f in files]


def table(results: list[JobResult]) -> str:
    """The summary table: file, time before/after, saved %, status."""
    rows = [("file", "before", "after", "saved", "status")]
    for r in results:
        def t(v):
            return "-" if v is None else f"{int(v // 60)}m{int(round(v % 60)):02d}s"
        sp = r.saved_pct
        rows.append((r.file, t(r.input_time_s), t(r.output_time_s),
                     "-" if sp is None else f"{sp:+.1f} %",
                     r.status + (f": {r.message}" if r.message else "")))
    w = [max(len(row[i]) for row in rows) for i in range(4)]
    return "\n".join(f"{a:<{w[0]}}  {b:>{w[1]}}  {c:>{w[2]}}  {d:>{w[3]}}  {e}"
                     for a, b, c, d, e in rows)
