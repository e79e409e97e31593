"""The one short function that runs the stages in order:

    read (Program) -> build_path (Path) -> plan (Schedule) -> write (bytes) -> verify -> replace
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib
import time
from dataclasses import dataclass

import numpy as np

from .errors import AlreadyProcessedError, FeedOptError, GCodeError, UsageError
from .gcode.features import FEATURES, present, segment_features, segment_tolerance
from .gcode.metadata import rescale_times
from .gcode.path import build_path
from .gcode.reader import gc_paused, read_file
from .gcode.verify import verify
from .gcode.writer import write, write_trajectory_csv
from .plan.kinematic import effective_limits, plan_kinematic, plan_trapezoids, writer_accel
from .plan.request import PlanRequest
from .plan.speed import planning_path
from .inputs import check_input
from .outputs import check_outputs, output_file, output_path, write_bytes
from .plot import plot_run
from .report import Report
from . import firmware
from .vm.firmware import estimate_time_s, execute
from .vm.metrics import evaluate
from .vm.plant import Plant

METHODS = ("kinematic", "conservative", "pb", "dd", "pidd", "oracle")
#: an output is "slower" when the firmware model runs it this much longer than the input
SLOWER_TOLERANCE = 1e-3
#: file types --plot can write (matplotlib's format from the suffix)
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


@dataclass
class Options:
    method: str = "pidd"
    tolerance_mm: float | None = None
    stringency: float | None = None
    vmax_mm_s: float | None = None
    amax_mm_s2: float | None = None
    mode: str = "refeed"
    #: plan.speed.SPEEDS: ``slicer`` (every move at most its sliced F) or ``machine``
    speed: str = "slicer"
    #: firmware.ACCELS: ``plan`` (the plan's accelerations override lower ones the file
    #: sets) or ``file`` (the file's own kept)
    accel: str = "plan"
    #: write the output even when it runs slower than the input
    allow_slower: bool = False
    force: bool = False
    dry_run: bool = False
    trajectory: str | None = None
    plot: str | None = None
    #: E_max per feature (gcode.features), over the profile's limits.feature_tolerance_mm;
    #: None: the profile's; an empty dict: one tolerance (per feature off)
    feature_tolerance: dict | None = None


def tolerance_for(path, program, req: PlanRequest):
    """The tolerance the planner gets: the scalar E_max when no feature has its own (the
    single-tolerance path, unchanged), else (N,) one per segment from each move's feature
    (``req``: plan.request.PlanRequest). Returns (tolerance, per-segment features, notes)."""
    scalar = req.tolerance_mm
    table = req.feature_tolerance_mm
    feats = segment_features(path, program)
    if not table:
        return scalar, feats, []
    have = present(feats)
    notes = []
    if not (have - {"travel", ""}):
        notes.append(f"no slicer feature tags (;TYPE:) in the file: one tolerance {scalar:g} mm "
                     f"for every move; --feature-tolerance not applied")
        return scalar, feats, notes
    missing = sorted(set(table) - have)
    if missing:
        notes.append(f"feature tolerance for {', '.join(missing)}: the file has no such "
                     f"moves (it has {', '.join(sorted(have - {''}))})")
    if "" in have:
        notes.append(f"{int(np.sum(feats == ''))} untagged segments keep {scalar:g} mm")
    return segment_tolerance(feats, table, scalar), feats, notes


def read_for(path, profile):
    """Read a G-code file with the profile's firmware semantics."""
    fw = profile.firmware
    return read_file(path, flavour=fw.flavour, g91_relative_e=fw.g91_relative_e,
                     retract_mm=fw.retract_mm, retract_speed_mm_s=fw.retract_speed_mm_s,
                     e_feed_mm_s=fw.max_feed_mm_s["e"])


def path_for(program, profile, fw_limits=None):
    """The Path of a program. E-only moves (retractions, primes) are not re-timed: they last
    what the firmware gives them (``fw_limits``: firmware.MoveLimits of the program, found
    when not given; the firmware variant's e_only_caps), so the plan's time is the
    firmware's."""
    if fw_limits is None:
        fw_limits = firmware.move_limits(program, profile)
    return build_path(program, **firmware.firmware_for(profile).e_only_caps(program, fw_limits))


def plan(path, profile, req: PlanRequest, fw_limits=None, tolerance=None):
    """The Schedule of the request's method (plan.request.PlanRequest), under its speed
    policy (plan.speed): the planners see the path with each move's ceiling as its feed.
    ``tolerance``: scalar or (N,) per segment (:func:`tolerance_for`); None: the scalar
    E_max."""
    path = planning_path(path, req.speed, profile, req.vmax_mm_s)
    if req.method == "kinematic":
        return plan_kinematic(path, profile, use_slicer_feed=req.use_slicer_feed,
                              vmax_mm_s=req.plan_vmax_mm_s, amax_mm_s2=req.amax_mm_s2,
                              fw_limits=fw_limits)
    try:  # on use: a build without the optimizer's solvers still plans kinematic
        from .optimize.methods import plan_request
    except ImportError:
        raise FeedOptError(f"method '{req.method}' is not available in this build; use "
                           "--method kinematic") from None
    return plan_request(req, path, profile, tolerance, fw_limits=fw_limits)


def input_time_s(path, profile, req: PlanRequest, fw_limits=None) -> float:
    """Time the original file takes under the same limits: the firmware plans it at the
    slicer's feeds (capped by the plan's V_max, plan.speed.plan_vmax)."""
    vmax, axis_v, axis_a = effective_limits(profile, req.plan_vmax_mm_s, req.amax_mm_s2)
    tr = plan_trapezoids(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=axis_a,
                         firmware=profile.firmware, use_slicer_feed=True, fw_limits=fw_limits)
    return tr.duration_s


#: most samples a plan may have when --vmax/--amax lower the limits: every method keeps
#: several arrays per Ts sample (the kinematic plan ~100 bytes a sample, measured on the
#: Cura Benchy: 465 MB at 1.2 M samples, 1.04 GB at 6.2 M), so 3e7 (16.7 h at Ts = 2 ms) is
#: ~3 GB. A file that is this long at the profile's own limits is planned as it is.
MAX_PLAN_SAMPLES = 30_000_000


def check_plan_size(path, profile, vmax_mm_s=None, amax_mm_s2=None, use_slicer_feed=False,
                    fw_limits=None, where: str = "") -> float:
    """Refuse --vmax/--amax values that would make the plan absurdly large (``--vmax 1e-6``
    asked for 667 GiB): the time of the fastest plan under the lowered limits (firmware
    trapezoids), in samples of Ts, must stay within MAX_PLAN_SAMPLES. Returns that time, s."""
    if vmax_mm_s is None and amax_mm_s2 is None:
        return float("nan")
    vmax, axis_v, axis_a = effective_limits(profile, vmax_mm_s, amax_mm_s2)
    tr = plan_trapezoids(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=axis_a,
                         firmware=profile.firmware, use_slicer_feed=use_slicer_feed,
                         fw_limits=fw_limits)
    n = tr.duration_s / profile.ts_s
    if n > MAX_PLAN_SAMPLES:
        given = [(k, v) for k, v in (("--vmax", vmax_mm_s), ("--amax", amax_mm_s2))
                 if v is not None]
        opts = " and ".join(f"{k} {v:g}" for k, v in given)
        raise UsageError(f"{where}: with {opts} the plan would last {tr.duration_s / 3600:.3g} h "
                         f"= {n:.3g} samples of {profile.ts_s * 1000:g} ms, above the limit of "
                         f"{MAX_PLAN_SAMPLES:.3g} (about 3 GB); raise "
                         f"{' or '.join(k for k, _ in given)}")
    return tr.duration_s


def execute_check(out_program, profile, tol_mm: float, replay=None) -> dict:
    """End to end: the written G-code run by the firmware model and the profile's nominal
    plant (no unknown effects): executed time and contour error, to set against the plan's
    time and predicted contour error in the report. ``replay``: the output's settings
    replayed for ``profile`` (firmware.Replay), made when not given."""
    tr = execute(out_program, profile, replay)
    out = Plant(profile, seed=0, nominal=True).simulate(tr)
    # every figure over the samples the metric judges (extruding ones), like the plan's
    m = evaluate(tr, out.actual_mm, tol_mm)
    return {"plant": "nominal", "time_s": round(tr.duration_s, 4),
            "within_fraction": round(m.within_fraction, 5),
            "max_contour_error_mm": round(m.max_contour_error_mm, 5),
            "p95_contour_error_mm": round(m.p95_contour_error_mm, 5),
            "rms_gamma_mm": round(m.rms_gamma_mm, 6)}


def run_settings(profile, opts: Options, req: PlanRequest | None = None) -> str:
    """The settings a written file was made with, as its ident line records them: the
    machine (and a digest of its profile file), method, speed policy, tolerance, stringency,
    the limits given and the mode. ``batch`` compares them to re-process what changed.
    ``req``: the run's PlanRequest (made from ``opts`` when not given)."""
    req = req or PlanRequest.from_options(profile, opts)

    digest = "builtin"
    if profile.source_path:
        try:
            digest = hashlib.sha256(pathlib.Path(profile.source_path).read_bytes()).hexdigest()[:8]
        except OSError:
            digest = "?"
    g = (lambda v: "-" if v is None else f"{v:g}")
    return (f"machine {profile.name}@{digest}, method {req.method}, speed {req.speed}, "
            f"tolerance {g(req.tolerance_mm)}, stringency {g(req.stringency)}, "
            f"vmax {g(req.vmax_mm_s)}, amax {g(req.amax_mm_s2)}, mode {opts.mode}"
            # outputs made before --accel kept the file's accelerations: no word is ``file``
            + (f", accel {opts.accel}" if opts.accel != "file" else "")
            + "".join(f", {k} {g(v)}" for k, v in req.feature_tolerance_mm.items()))


def check_run_outputs(in_path, out_path, opts: Options, extra: dict | None = None,
                      inputs=()) -> dict:
    """Check the input and every output of a run before anything is read or written
    (outputs.check_outputs); ``extra``: more option -> path (e.g. ``--report``)."""
    in_path = check_input(in_path, "input")
    # an in-place edit (no -o) names no option in its messages
    key = "-o" if out_path is not None and pathlib.Path(out_path) != in_path else "output"
    out_path = pathlib.Path(out_path) if out_path is not None else in_path
    outs = {key: None if opts.dry_run else out_path,
            "--trajectory": None if opts.dry_run else opts.trajectory,
            "--plot": opts.plot, **(extra or {})}
    targets = check_outputs(outs, inputs=[in_path, *inputs], in_place=[key],
                            suffixes={"--plot": PLOT_SUFFIXES})
    if key in targets:
        targets["-o"] = targets.pop(key)
    return targets


def optimize_file(in_path, out_path, profile, opts: Options, progress=None) -> Report:
    """Optimize ``in_path`` and write ``out_path`` (may be the same file: in place).
    ``progress``: called with the name of each stage as it starts (the CLI shows it on a
    terminal; results do not depend on it)."""
    say = progress or (lambda stage: None)
    in_path = pathlib.Path(in_path)
    out_path = pathlib.Path(out_path) if out_path is not None else in_path
    if opts.accel == "file":
        # the file's own settings: its accelerations, and the firmware's and its own junctions
        profile = firmware.firmware_junctions(profile)
    run = _Run(in_path=in_path, out_path=out_path, profile=profile, opts=opts,
               req=PlanRequest.from_options(profile, opts),
               targets=check_run_outputs(in_path, out_path, opts))
    _read(run, say)
    _plan(run, say)
    # write, verify and time: a few hundred thousand short-lived objects each and no reference
    # cycle; with the two programs alive, every pass of the cyclic collector walks millions of
    # objects (gc_paused)
    with gc_paused():
        _write(run, say)
        _time_both(run, say)
    if run.sched.method != "kinematic":
        t0 = time.perf_counter()
        say("executing the output on the firmware model and plant")
        run.executed = execute_check(run.out_program, run.configured, run.req.tolerance_mm,
                                     run.out_replay)
        run.wall["execute"] = time.perf_counter() - t0
    _save(run)
    rep = _report(run)
    _notes(run, rep)
    return rep


@dataclass
class _Run:
    """One ``optimize_file`` run: its inputs, then what each stage made (None until then)."""

    in_path: pathlib.Path
    out_path: pathlib.Path
    profile: object
    opts: Options
    req: PlanRequest
    targets: dict
    wall: dict = dataclasses.field(default_factory=dict)
    program: object = None
    file_replay: object = None      # the file's settings replayed (firmware.Replay)
    override: object = None         # --accel plan's (firmware.accel_override) or None
    replay: object = None           # file_replay with the override
    fw_limits: object = None
    path: object = None
    tol: object = None
    seg_feats: object = None
    tol_notes: list = dataclasses.field(default_factory=list)
    sched: object = None
    t_in: float = 0.0
    result: object = None
    out_program: object = None
    configured: object = None       # the profile as its owner configured the firmware
    out_replay: object = None
    fw_in: float = 0.0
    fw_out: float = 0.0
    fw_in_raised: float = 0.0
    fw_in_plan: float = 0.0
    fw_in_accel: float = 0.0
    executed: dict | None = None
    keep: bool = False


def _read(run: _Run, say) -> None:
    """Read the file, replay its firmware settings once, build its path."""
    profile, opts, in_path = run.profile, run.opts, run.in_path
    t0 = time.perf_counter()
    say("reading")
    program = run.program = read_for(in_path, profile)
    run.wall["parse"] = time.perf_counter() - t0
    if program.processed_line is not None and not opts.force:
        raise AlreadyProcessedError(
            f"{in_path}:{program.processed_line + 1}: already processed by gcode-feedopt; "
            "pass --force to process it again (re-slice for the best result)")
    t0 = time.perf_counter()
    # the file's settings, replayed once; --accel plan: the plan's accelerations where the
    # file's lines lower them (the writer adds a line after each such line); the planner, the
    # clamp and the slowed stretches' restores see the plan's values (``replay``)
    run.file_replay = firmware.Replay(program, profile)
    run.override = firmware.accel_override(program, profile, opts.accel, run.file_replay)
    run.replay = run.file_replay.overridden(run.override)
    run.fw_limits = run.replay.move_limits()
    with gc_paused():
        run.path = path_for(program, profile, run.fw_limits)
    if run.path.n_segments == 0:
        raise GCodeError(f"{in_path}: no move travels in X, Y or Z; nothing to re-time")
    run.wall["path"] = time.perf_counter() - t0


def _plan(run: _Run, say) -> None:
    """Plan the path (and time the input at the same limits)."""
    path, profile, req, fw_limits = run.path, run.profile, run.req, run.fw_limits
    t0 = time.perf_counter()
    check_plan_size(path, profile, req.vmax_mm_s, req.amax_mm_s2, req.speed == "slicer",
                    fw_limits, where=str(run.in_path))
    say(f"planning {path.n_segments:,} moves ({req.method})")
    run.tol, run.seg_feats, run.tol_notes = tolerance_for(path, run.program, req)
    run.sched = plan(path, profile, req, fw_limits, run.tol)
    run.t_in = input_time_s(path, profile, req, fw_limits)
    run.wall["plan"] = time.perf_counter() - t0


def _write(run: _Run, say) -> None:
    """Write the schedule into the file's lines and read the result back (verify)."""
    path, profile, req, opts, sched = run.path, run.profile, run.req, run.opts, run.sched
    t0 = time.perf_counter()
    say("writing")
    cells = sched.cells
    # the X/Y acceleration the plan chose (optimize.methods.search_acceleration) is written
    # as --amax would be: the file's own settings clamped to it, M201 before the first move
    amax_w = sched.info.get("accel_chosen_mm_s2") or opts.amax_mm_s2
    axis_a = effective_limits(profile, opts.vmax_mm_s, amax_w)[2]
    clamp = run.replay.accel_clamp(axis_a)
    run.result = write(run.program, path, sched, profile, mode=opts.mode,
                       override=run.override,
                       accel_mm_s2=writer_accel(path, profile, run.fw_limits, amax_w),
                       cells=cells, clamp=clamp,
                       feed_cap_mm_s=planning_path(path, req.speed, profile,
                                                   req.vmax_mm_s).feed_mm_s,
                       run_settings=run_settings(profile, opts, req),
                       settings=None if cells is None and not firmware.raises_configured(profile)
                       else run.replay.accel_settings(clamp))
    run.wall["write"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fw = profile.firmware
    run.out_program = verify(run.program, run.result, flavour=fw.flavour,
                             g91_relative_e=fw.g91_relative_e, name=str(run.out_path))
    run.wall["verify"] = time.perf_counter() - t0


def _time_both(run: _Run, say) -> None:
    """Time the input and the output on the firmware model."""
    profile, program = run.profile, run.program
    t0 = time.perf_counter()
    # the printer as its owner configured it runs both files (the output sets the plan's
    # limits itself, gcode.firmware_lines._PlanLimits); the input also at the profile's values,
    # to tell the saving from raised limits apart from the plan's
    configured = run.configured = firmware.as_configured(profile)
    say("timing both files on the firmware model")
    run.fw_in = estimate_time_s(program, configured,
                                replay=run.file_replay if configured is profile else None)
    run.out_replay = firmware.Replay(run.out_program, configured)
    run.fw_out = estimate_time_s(run.out_program, configured, replay=run.out_replay)
    run.fw_in_raised = (run.fw_in if configured is profile
                        else estimate_time_s(program, profile, replay=run.file_replay))
    # ... and at the plan's accelerations and junctions over the file's own (--accel plan)
    run.fw_in_plan = (run.fw_in_raised if run.override is None
                      else estimate_time_s(program, profile, replay=run.replay))
    # ... and at the plan's accelerations with the firmware's and the file's own junctions
    # (the time split's share of each)
    run.fw_in_accel = run.fw_in_plan
    own = firmware.firmware_junctions(profile)
    if own is not profile:
        raw = firmware.Replay(program, own)
        run.fw_in_accel = estimate_time_s(
            program, own, replay=raw.overridden(firmware.accel_override(program, own,
                                                                        run.opts.accel, raw)))
    run.wall["firmware"] = time.perf_counter() - t0


def _save(run: _Run) -> None:
    """Plot if asked; write the output (or keep the input where ours runs slower)."""
    opts, sched, in_path, out_path = run.opts, run.sched, run.in_path, run.out_path
    if opts.plot:
        with output_path(run.targets["--plot"]) as tmp:
            plot_run(run.path, sched, tmp,
                     title=f"{in_path.name}: {sched.method} on {run.profile.name}",
                     tolerance_mm=run.req.tolerance_mm,
                     predicted_error_mm=sched.info.get("predicted_bound_mm"))
    # an output that runs slower than the input is not written unless asked (--allow-slower):
    # in place the file stays as it was, with -o the input goes there unchanged
    run.keep = run.fw_out > run.fw_in * (1.0 + SLOWER_TOLERANCE) and not opts.allow_slower
    # the time lines the slicer wrote (;TIME:, M73, estimated printing time) carry the time the
    # summary reports: the firmware model's of this very file, not the plan's
    run.result = dataclasses.replace(run.result, data=rescale_times(run.result.data,
                                                                    sched.duration_s, run.fw_out))
    if not opts.dry_run:
        t0 = time.perf_counter()
        if run.keep:
            if out_path.resolve() != in_path.resolve():
                write_bytes(run.targets["-o"], in_path.read_bytes())
        else:
            if opts.trajectory:  # first: the G-code is the last file replaced
                with output_file(run.targets["--trajectory"]) as fh:
                    write_trajectory_csv(fh, sched, run.path)
            write_bytes(run.targets["-o"], run.result.data)
        run.wall["save"] = time.perf_counter() - t0


def _report(run: _Run) -> Report:
    """The run's report: times, counts and the optimizer's figures."""
    opts, req, sched, result, program = run.opts, run.req, run.sched, run.result, run.program
    profile, keep, info = run.profile, run.keep, run.sched.info
    fw_in, fw_out = run.fw_in, run.fw_out
    rep = Report(
        input=str(run.in_path), output=None if opts.dry_run else str(run.out_path),
        machine=profile.name, method=sched.method, mode=opts.mode, speed=req.speed,
        accel=opts.accel,
        tolerance_mm=req.tolerance_mm, stringency=req.stringency,
        moves=len(program.moves), moves_changed=0 if keep else result.moves_changed,
        lines_in=len(program.lines),
        lines_written=len(program.lines) if keep else result.lines_written,
        input_time_s=fw_in, output_time_s=fw_in if keep else fw_out,
        plan_time_s=sched.duration_s,
        time_source=f"{profile.firmware.flavour} firmware model"
                    + (" as configured" if run.configured is not profile else ""),
        dry_run=opts.dry_run,
        predicted_max_contour_error_mm=info.get("predicted_max_contour_error_mm"),
        predicted_p95_contour_error_mm=info.get("predicted_p95_contour_error_mm"),
        predicted_within_fraction=info.get("predicted_within_fraction"),
        stage_wall_s={k: round(v, 4) for k, v in run.wall.items()},
        extra={"input_time_same_limits_s": run.t_in,
               "input_time_profile_limits_s": run.fw_in_raised,
               "input_time_plan_accel_s": run.fw_in_plan,
               "input_time_plan_accel_own_junctions_s": run.fw_in_accel,
               "accel_lines": result.accel_lines, "accel_override_lines": result.override_lines,
               **({"executed": run.executed} if run.executed is not None else {}),
               **{k: info[k] for k in ("optimizer", "window_status", "fallback_windows",
                                        "relaxed_windows", "relaxed_samples",
                                        "relaxed_at_rest_samples", "rest_uncertainty_mm",
                                        "budget_samples",
                                        "rounds", "whole_file_checks", "samples_evaluated",
                                        "slowed_length_fraction", "predicted_rms_gamma_mm",
                                        "compute_s", "solver_s", "accel_chosen_mm_s2")
                  if k in info},
               **({"accel_search": [{"accel_mm_s2": a, "plan_time_s": t}
                                    for a, t in info["accel_search"]]}
                  if info.get("accel_search") else {})})
    rep.extra["time_split_s"] = time_split(
        fw_in=fw_in, fw_in_raised=run.fw_in_accel, fw_in_junctions=run.fw_in_plan, t_in=run.t_in,
        fw_out=fw_in if keep else fw_out, plan_s=sched.duration_s,
        kinematic_s=_kinematic_time(sched, run.path, profile, req, run.fw_limits), keep=keep)
    return rep


def _notes(run: _Run, rep: Report) -> None:
    """What the user should know about the run, as the report's notes (and the features)."""
    opts, sched, result, program = run.opts, run.sched, run.result, run.program
    profile, keep, info, override = run.profile, run.keep, run.sched.info, run.override
    fw_in, fw_out = run.fw_in, run.fw_out
    if info.get("accel_chosen_mm_s2") and not keep:
        tried = info["accel_search"]
        rep.notes.append(
            f"X/Y acceleration lowered to {info['accel_chosen_mm_s2']:.0f} mm/s² (from "
            f"{tried[0][0]:.0f}): the twin predicts the ringing after each acceleration step "
            f"breaks the tolerance, and the plan at the lower acceleration is faster than the "
            f"one that slows down around it ({tried[0][1]:.1f} s at {tried[0][0]:.0f}, "
            f"{sched.duration_s:.1f} s at {info['accel_chosen_mm_s2']:.0f}); the file sets it "
            "(M201/M204 or SET_VELOCITY_LIMIT) so the firmware runs it")
    short = _short_of_stringency(info, run.req, profile.ts_s)
    if short:
        rep.notes.append(short)
    if result.plan_limit_lines and not keep:
        fw_c = profile.firmware
        conf = ", ".join(f"{k} {v:g}" for k, v in (
            [("accel", fw_c.configured_accel_mm_s2)] if fw_c.configured_accel_mm_s2 else []) + (
            [(f"max {a}", fw_c.configured_max_accel_mm_s2[a]) for a in "xy"]
            if fw_c.configured_max_accel_mm_s2 and run.replay.firmware.axis_max_accel else []))
        conf = [f"{conf} mm/s²"] if conf else []
        if any(ln.startswith("M205 J") for ln in result.plan_limit_lines):
            conf.append(f"junction deviation {fw_c.junction_deviation_mm:g} mm")
        if any("SQUARE_CORNER_VELOCITY" in ln for ln in result.plan_limit_lines):
            conf.append(f"square corner velocity {fw_c.square_corner_velocity_mm_s:g} mm/s")
        rep.notes.append(f"the file sets {' and '.join(result.plan_limit_lines)} before its first "
                         f"move (the plan's limits; {profile.name}'s firmware is configured to "
                         f"{', '.join(conf)}) and the configured values again after its last; "
                         f"the input alone would take {run.fw_in_raised:.1f} s at those limits, "
                         f"{fw_in:.1f} s as configured")
    if override is not None and not keep:
        kinds = sorted({name for _, name in override.sources})
        n_src = len(override.sources)
        rep.notes.append(
            f"--accel plan: {n_src} line{'s' if n_src != 1 else ''} of the file set "
            f"accelerations{' or junctions' if override.junction else ''} below the plan's "
            f"({', '.join(kinds)}); after each (after the homing "
            f"that follows it, if any) the file sets the plan's again "
            f"({run.replay.firmware.describe_accels(override)}; {result.override_lines} lines, "
            f"{'' if override.junction else 'junction settings and '}retraction accelerations "
            f"kept), and the file's own after the last "
            f"move; the input alone would take {run.fw_in_plan:.1f} s at the plan's "
            f"accelerations{' and junctions' if override.junction else ''}; --accel file "
            "keeps the file's")
        tower = next((i for i, ln in enumerate(program.lines)
                      if ln.lstrip()[:12].upper() == b"TUNING_TOWER"), None)
        if tower is not None:
            # a calibration print measures something at the accelerations it was sliced with
            # (the Cura square tower: pressure advance at ACCEL=500)
            rep.notes.append(
                f"{run.in_path}:{tower + 1}: the file runs TUNING_TOWER, a calibration print, and "
                "its accelerations were overridden; what it calibrates (e.g. pressure advance) "
                "depends on them: run it with --accel file to calibrate at the sliced ones")
    # the reader's events (non-move commands), not a scan of every line
    shaping = next((e.line_no for e in program.events
                    if e.name in ("SET_INPUT_SHAPER", "M593")), None)
    if shaping is not None:
        # the twin's input is the plan through the profile's shaper (twin.physics)
        have = "; ".join(f"{a} {sh.describe()}" for a, sh in profile.firmware.input_shaper.items())
        text = program.lines[shaping].strip().decode("ascii", "replace")
        rep.notes.append(
            f"{run.in_path}:{shaping + 1}: the file sets the input shaper ({text}); the twin "
            f"planned with {profile.name}'s ({have or 'none'}, firmware.input_shaper): if the "
            "printer runs another, state it there and plan again")
    rate = 1.0 / profile.ts_s
    if opts.mode == "sampled" and rate > profile.firmware.max_lines_per_s and not keep:
        rep.notes.append(
            f"--mode sampled writes one motion line per {1000 * profile.ts_s:g} ms, {rate:.0f} "
            f"lines/s while moving, above {profile.name}'s max_lines_per_s "
            f"{profile.firmware.max_lines_per_s:g} (what its serial link and planner buffer "
            "carry): the printer may pause between lines and blob; use --mode refeed (the "
            "default), or raise firmware.max_lines_per_s if your host streams faster")
    if program.lines and not program.lines[-1].endswith(b"\n"):
        rep.notes.append(f"the last line ({len(program.lines)}) has no line end: if the file was "
                         "cut short (an interrupted upload or copy), the print is incomplete; "
                         "check its end")
    if keep:
        why = ("the twin slows it down where it predicts the tolerance would be broken"
               if info.get("slowed_length_fraction") else
               "at the file's own speeds and accelerations our plan is no faster than the "
               "firmware's own")
        rep.extra["kept_input"] = {"plan_output_time_s": fw_out, "why": why}
        rep.notes.append(
            f"kept the input as it was: our plan would run {fw_out:.1f} s, "
            f"{100 * (fw_out / fw_in - 1):.1f} % slower than the file's {fw_in:.1f} s ({why}); "
            "--allow-slower writes it" + ("" if opts.trajectory is None else
                                          "; no trajectory written"))
    elif fw_out > fw_in:
        rep.notes.append("the firmware runs the original faster than our output: the slicer's "
                         "feeds exceed the profile's limits somewhere (see --vmax)")
    feats_rep = feature_breakdown(run.path, sched, run.seg_feats, run.tol, profile.ts_s)
    if feats_rep:
        rep.extra["features"] = feats_rep
        rep.extra["feature_tolerance_mm"] = {k: (None if v == float("inf") else v) for k, v in
                                             run.req.feature_tolerance_mm.items()}
    rep.notes.extend(run.tol_notes)


#: a plan is noted as short of the stringency η when the twin expects more than this share
#: of the allowed 1 − η beyond it (``_short_of_stringency``)
SHORT_OF_STRINGENCY = 0.05


def _short_of_stringency(info: dict, req: PlanRequest, ts_s: float) -> str | None:
    """The note for a plan the twin itself expects to fall short of the stringency asked
    (``predicted_within_fraction`` below η by more than ``SHORT_OF_STRINGENCY`` of 1 − η), or
    None.

    The slow-down gives up on samples whose chance bound stays over the tolerance with their
    cause window at its floor (optimize.slowdown): a disturbance at rest that no speed
    changes, or an uncertainty so wide that no speed it may choose brings the bound within.
    Those stretches run as slowly as the plan may (where standing still would not help, at the
    firmware's speed: optimize.slowdown), and the file keeps nothing of the promise:
    on a servo measured with 2.7 % noise from 1 Hz (tests/foreign, seed 334, before one of its
    members was fitted again in the band: twin.modal.fit_modal) the plan gave up 2,692
    samples, expected 32 % of samples within, and ran 223 µm RMS γ on the machine (2.5
    allowed) without a word."""
    p = info.get("predicted_within_fraction")
    eta = req.stringency
    # the stringency's budget stops at η itself (slowdown.budget): a shortfall of a few
    # parts in a million there is rounding, not news
    if p is None or eta is None or p >= eta - SHORT_OF_STRINGENCY * (1.0 - eta):
        return None
    n = int(info.get("relaxed_samples", 0))
    rest = min(int(info.get("relaxed_at_rest_samples", 0)), n)
    rms = info.get("predicted_rms_gamma_mm")
    if rest == 0:
        how = "they run at the slowest speed it may choose"
    elif rest == n:
        how = "they run at the firmware's speed: standing still would not help them"
    else:
        how = (f"{n - rest} run at the slowest speed it may choose, {rest} at the firmware's "
               "speed, where standing still would not help")
    return (f"the twin expects only {100 * p:.2f} % of samples within tolerance where "
            f"{100 * eta:g} % were asked"
            + (f" (RMS contour error {1000 * rms:.1f} µm)" if rms is not None else "")
            + (f": {n} samples ({n * ts_s:.1f} s of motion) stay over it however far it "
               f"slows them ({how})" if n else "")
            + "; what it does not know about this machine is too wide for the tolerance "
            + (_rest_share(info) or "(profile FRFs measured with little noise from a few Hz, "
               "or `gcode-feedopt learn` on a log of this print, narrow it)"))


#: the twin's uncertainty at rest is named as the cause of a shortfall when it takes at least
#: this share of the tolerance (``_short_of_stringency``)
REST_SHARE = 0.5


def _rest_share(info: dict) -> str | None:
    """The clause naming the twin's uncertainty at rest (its noise level σ_ε and bias, which
    no speed changes) where it takes ``REST_SHARE`` of the tolerance or more, else None.
    Seen on a foreign belt + frame printer at E_max 0.02 mm, η 0.95 (tests/foreign, seed 411):
    the prior noise level of 0.01 mm (the paper's σ_ε, ``twin.sigma_eps_mm``) took 16.4 µm of
    the 20 µm at rest, the twin's mean erred 0.3 µm, and the first print took 2.3 times as long
    as a plan tuned on the machine."""
    u0, tol = info.get("rest_uncertainty_mm"), info.get("tolerance_mm")
    if not u0 or not tol or not np.isscalar(tol) or u0 < REST_SHARE * float(tol):
        return None
    return (f"(most of it is its uncertainty at rest, which no speed changes: {1000 * u0:.1f} "
            f"µm of the {1000 * float(tol):g} µm at this stringency, its noise level "
            "`twin.sigma_eps_mm` and bias as the profile assumes them until a log says "
            "otherwise: `gcode-feedopt learn` on a log of this print measures them)")


def _kinematic_time(sched, path, profile, req: PlanRequest, fw_limits) -> float:
    """The firmware's own plan of the path under the run's speed policy and limits, s: the
    plan itself for ``kinematic``, what the offline optimizer measured it at, else planned."""
    if sched.method == "kinematic":
        return sched.duration_s
    if sched.info.get("kinematic_time_s") is not None:
        return float(sched.info["kinematic_time_s"])
    vmax = req.plan_vmax_mm_s
    _, axis_v, axis_a = effective_limits(profile, vmax, req.amax_mm_s2)
    return plan_trapezoids(planning_path(path, req.speed, profile, req.vmax_mm_s),
                           vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=axis_a,
                           firmware=profile.firmware, use_slicer_feed=req.use_slicer_feed,
                           fw_limits=fw_limits).duration_s


def time_split(*, fw_in: float, fw_in_raised: float, fw_in_junctions: float, t_in: float,
               fw_out: float, plan_s: float, kinematic_s: float, keep: bool) -> dict:
    """Where the time went, s (negative: saved), summing to output − input exactly:

    - ``limits``: the original run at the plan's limits instead of as the printer is
      configured (the acceleration and maxima our file sets before its first move) and, under
      ``--accel plan``, at the plan's accelerations instead of the file's own lower ones
      (``fw_in_raised``: the input timed so, with the firmware's and the file's own
      junction settings);
    - ``junctions``: the original run at the plan's junction settings (firmware.plan_junction:
      the hardware's speed step; ``fw_in_junctions``: the input timed at the plan's
      accelerations and junctions) instead of the file's and the firmware's own (0 where the
      profile states no hardware limit: the firmware's rule is kept, lowered only where a
      stretch is slowed);
    - ``feed``: the firmware's plan under the speed policy against the slicer's feeds (0 under
      ``--speed slicer``, where no move is faster than sliced);
    - ``twin``: the optimizer's plan against the firmware's own at those limits (its slow-downs
      and lower acceleration where the twin predicts the tolerance would break: ≥ 0);
    - ``firmware_vs_plan``: what the firmware model adds to the plans (the original's and
      ours): junction and look-ahead details, the lines written.
    A kept input (slower output not written) is all zeros."""
    if keep:
        return {k: 0.0 for k in ("limits", "feed", "junctions", "twin", "firmware_vs_plan")}
    return {"limits": fw_in_raised - fw_in, "feed": kinematic_s - t_in,
            "junctions": fw_in_junctions - fw_in_raised, "twin": plan_s - kinematic_s,
            "firmware_vs_plan": (t_in - fw_in_junctions) + (fw_out - plan_s)}


def feature_breakdown(path, sched, seg_feats, tolerance, ts_s: float) -> dict:
    """{feature: plan time s, predicted worst / 95th percentile contour error mm, tolerance}
    of a planned (non-kinematic) schedule on a file with feature tags; {} otherwise."""
    bound = sched.info.get("predicted_bound_mm")
    if bound is None or not (set(np.unique(seg_feats.astype(str))) - {"", "travel"}):
        return {}
    s = np.asarray(sched.s_mm)
    bound = np.asarray(bound)
    n = min(s.size, bound.size)
    seg = path.segment_at(s[:n])
    moving = np.diff(s[:n], prepend=s[0]) > 0
    f_k = seg_feats[seg]
    tol_k = (np.full(n, float(tolerance)) if np.ndim(tolerance) == 0
             else np.asarray(tolerance)[seg])
    out = {}
    for f in sorted(set(f_k[moving].astype(str)), key=_feature_order):
        m = (f_k == f) & moving
        on = m & (bound[:n] > 0)
        t = float(np.isfinite(tol_k[m]).any() and np.max(tol_k[m][np.isfinite(tol_k[m])]))
        out[f or "untagged"] = {
            "plan_time_s": round(float(np.sum(m)) * ts_s, 3),
            "predicted_max_contour_error_mm":
                round(float(np.max(bound[:n][on])), 4) if on.any() else 0.0,
            "predicted_p95_contour_error_mm":
                round(float(np.quantile(bound[:n][on], 0.95)), 4) if on.any() else 0.0,
            "tolerance_mm": t if t else None}
    return out


def _feature_order(f: str) -> int:
    return FEATURES.index(f) if f in FEATURES else len(FEATURES)
