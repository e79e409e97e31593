"""Batch over a folder of jobs: every G-code file, in parallel processes; one failure never
stops the others; Ctrl-C or SIGTERM stops the workers at once and leaves no half-written file
(each write is temp + os.replace, the temp removed on any exception or SIGTERM), starts no
queued job, and the table still says which files were done."""

from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, field

from ..errors import FeedOptError
from ..gcode.reader import IDENT_PREFIX
from ..outputs import make_output_folder, write_text
from ..pipeline import Options, optimize_file, run_settings
from ..procs import acknowledge, worker_pool
from ..profile import load_profile
from ..report import hms

SUFFIXES = (".gcode", ".gco", ".g")


@dataclass
class JobResult:
    file: str
    status: str  # ok | kept (our plan was slower: the input kept) | skipped | failed | interrupted
    input_time_s: float | None = None
    output_time_s: float | None = None
    message: str = ""
    #: the notes the main command's summary would show for this file (report.notes)
    notes: list = field(default_factory=list)

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


def recorded_settings(path: pathlib.Path) -> str | None:
    """The run settings on a processed file's ident line (pipeline.run_settings), or None."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    i = head.find(IDENT_PREFIX)
    if i < 0:
        return None
    line = head[i:head.find(b"\n", i) if b"\n" in head[i:] else len(head)]
    a, b = line.find(b" ["), line.rfind(b"]")
    return line[a + 2:b].decode("latin-1") if 0 <= a < b else None


def run_one(src: str, dst: str, machine: str, opts_dict: dict,
            report: str | None = None) -> JobResult:
    """One job, in a worker process. Never raises for a bad file: returns its status.
    ``report``: where its JSON report goes (written when the file was processed)."""
    src_p, dst_p = pathlib.Path(src), pathlib.Path(dst)
    try:
        if already_processed(src_p) and not opts_dict.get("force"):
            return JobResult(src_p.name, "skipped", message="already processed")
        profile = load_profile(machine)
        opts = Options(**opts_dict)
        # an output made from this input with the same settings is up to date; another
        # machine, method, tolerance, ... makes it again
        if dst_p != src_p and dst_p.exists() and dst_p.stat().st_mtime >= src_p.stat().st_mtime \
                and recorded_settings(dst_p) == run_settings(profile, opts) \
                and not opts_dict.get("force"):
            return JobResult(src_p.name, "skipped", message="output up to date")
        rep = optimize_file(src_p, dst_p, profile, opts)
        if report:
            write_text(report, rep.to_json() + "\n", "--report")
        kept = rep.extra.get("kept_input")
        # the table's status says a file was kept; every other note as the summary has it
        notes = [n for n in rep.notes if not n.startswith("kept the input")]
        if kept:
            slower = 100.0 * (kept["plan_output_time_s"] / rep.input_time_s - 1.0)
            return JobResult(src_p.name, "kept", rep.input_time_s, rep.output_time_s,
                             message=f"our plan {slower:.1f} % slower; --allow-slower writes it",
                             notes=notes)
        return JobResult(src_p.name, "ok", rep.input_time_s, rep.output_time_s, notes=notes)
    except FeedOptError as exc:
        return JobResult(src_p.name, "failed", message=str(exc))
    except Exception as exc:  # a bug must not stop the other jobs; report it as such
        return JobResult(src_p.name, "failed", message=f"internal error: {exc!r}")


def _written_since(dst: pathlib.Path, before) -> bool:
    """Did a job replace ``dst`` with a processed file after ``before`` (its stat or None)?"""
    try:
        st = dst.stat()
    except OSError:
        return False
    if before is not None and (st.st_ino, st.st_mtime_ns) == (before.st_ino, before.st_mtime_ns):
        return False
    try:
        return already_processed(dst)
    except OSError:
        return False


def run_batch(folder: pathlib.Path, outdir: pathlib.Path | None, machine: str, opts_dict: dict,
              jobs: int, progress=None, *,
              report_dir: pathlib.Path | None = None) -> tuple[list[JobResult], int | None]:
    """Process every G-code file in ``folder``. Returns the results in file order and, when
    Ctrl-C or SIGTERM stopped the batch, the signal number (else None): the workers are then
    stopped at once (a file being written keeps its old content, no temporary file is left),
    nothing queued starts, and each file not finished is marked ``interrupted``."""
    files = find_jobs(folder)
    if report_dir is not None and not report_dir.parent.is_dir():
        make_output_folder(report_dir, "--report")  # its one-line error, before anything is made
    if outdir is not None:
        make_output_folder(outdir, "-o")  # the output folder itself; its parent must exist
    if report_dir is not None:
        make_output_folder(report_dir, "--report")
    results: dict[str, JobResult] = {}
    dsts = {f.name: (outdir or folder) / f.name for f in files}
    before = {}
    for name, dst in dsts.items():
        try:
            before[name] = dst.stat()
        except OSError:
            before[name] = None
    # the jobs are the parallelism: a twin method inside a job plans in one process unless
    # the user set GCODE_FEEDOPT_JOBS (optimize/parallel.py)
    if jobs > 1:
        os.environ.setdefault("GCODE_FEEDOPT_JOBS", "1")
    signum = None
    try:
        with worker_pool(max(1, jobs)) as pool:
            futs = {pool.submit(run_one, str(f), str(dsts[f.name]), machine, opts_dict,
                                None if report_dir is None
                                else str(report_dir / (f.stem + ".json"))): f
                    for f in files}
            for fut in pool.as_completed(futs):
                r = fut.result()
                results[futs[fut].name] = r
                if progress is not None:
                    progress(r)
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM (procs.Interrupted): workers stopped
        acknowledge()
        signum = getattr(exc, "signum", 2)
    out = []
    for f in files:
        r = results.get(f.name)
        if r is None:
            if _written_since(dsts[f.name], before[f.name]):
                r = JobResult(f.name, "ok", message="written; figures lost to the interrupt")
            else:
                r = JobResult(f.name, "interrupted", message="not written")
        out.append(r)
    return out, signum


def table(results: list[JobResult]) -> str:
    """The summary table: file, time before/after, saved %, status."""
    rows = [("file", "before", "after", "saved", "status")]
    for r in results:
        def t(v):
            return "-" if v is None else hms(v)
        sp = r.saved_pct
        rows.append((r.file, t(r.input_time_s), t(r.output_time_s),
                     "-" if sp is None else f"{sp:+.1f} %",
                     r.status + (f": {r.message}" if r.message else "")))
    w = [max(len(row[i]) for row in rows) for i in range(4)]
    return "\n".join(f"{a:<{w[0]}}  {b:>{w[1]}}  {c:>{w[2]}}  {d:>{w[3]}}  {e}"
                     for a, b, c, d, e in rows)


def notes_text(results: list[JobResult]) -> str:
    """The main command's notes for each file, below the table: ``note: a.gcode: ...``; a note
    every file shares (e.g. --mode sampled above the line budget) once, for ``all N files``."""
    by_note: dict[str, list[str]] = {}
    for r in results:
        for n in r.notes:
            by_note.setdefault(n, []).append(r.file)
    out = []
    for n, files in by_note.items():
        who = (f"all {len(files)} files" if len(files) > 1 and len(files) == len(results)
               else ", ".join(files))
        out.append(f"note: {who}: {n}")
    return "\n".join(out)
