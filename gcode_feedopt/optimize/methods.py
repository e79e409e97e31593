"""The methods of issue 5 / paper Sec. 5, one dispatch: kinematic | conservative | pb | dd |
pidd | oracle.

- ``kinematic``: plan.kinematic (time-optimal under feed, per-axis acceleration, junctions).
- ``conservative``: the same trapezoidal planner with V_max and A_max scaled down by one factor,
  found by bisection, until the virtual machine's RMS tolerance violation normalised by E_max is
  at most 1 − η (paper Sec. 5: "allowing up to (100 − η) % RMS violation").
- ``pb``: the twin with the known uncertainty only (physics prior, Σ_ψ from the FRF set),
  no learning.
- ``dd``: the twin without known uncertainty (zero prior mean, Σ_ψ = 0), learned online (Eq. 19).
- ``pidd``: the uncertainty-aware twin (physics prior + known uncertainty), learned online.
- ``oracle``: the virtual machine's true plant known exactly (the physical limit; comparison
  only).

Offline (no measurements): the twin predicts with its prior and its own predicted errors
(Eq. 5). Online (``plant`` given and ``online=True``, the paper's experiment): after each
window is committed the plant runs it, and the twin learns from the measured positions before
the next window is planned.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.stats import norm

from ..errors import FeedOptError
from ..gcode.schedule import Schedule, SegmentPlan, SlowdownCells
from ..plan.request import PlanRequest
from ..plan.kinematic import (effective_limits, plan_kinematic, plan_trapezoids, planner_limits,
                              segment_plan)
from ..twin.extensions import extra_variance_mm2, motion_offsets
from ..twin.model import (axis_noise_mm, axis_prior, axis_residual, learned_variance_terms,
                          twin_impulse)
from ..twin.physics import memory_time_s
from ..vm.metrics import evaluate
from ..vm.plant import Plant
from ..vm.trajectory import Trajectory
from .free import ContourRules, FreePlan
from . import parallel
from .mpc import OVERSHOOT_LAG_S, MpcPlanner, MpcResult, MpcSettings
from .predictors import PlantPredictor, TwinPredictor
from .slowdown import SlowdownSettings, plan_slowdown
from .slowdown.evaluators import PlantEvaluator, TwinEvaluator

METHODS = ("kinematic", "conservative", "pb", "dd", "pidd", "oracle")
#: how a twin-driven method finds its plan: ``slowdown`` (whole-file passes, the offline
#: default) or ``window`` (the receding-window LP of the paper, the full method, and the one
#: that learns online)
OPTIMIZERS = ("slowdown", "window")
TWIN_METHODS = ("pb", "dd", "pidd")
#: Bisection steps of the conservative scale factor (2⁻¹⁰ of the range).
CONSERVATIVE_STEPS = 10
CONSERVATIVE_MIN_SCALE = 0.02


def vm_trajectory(path, s_mm: np.ndarray, ts_s: float):
    """Trajectory (pos (K,3), e (K,)) of a schedule on a path (as the writer's CSV)."""
    s = np.asarray(s_mm, float)
    pos = path.position(s)
    k = path.segment_at(s)
    L = path.length_mm[k]
    u = np.where(L > 0, (s - path.s0_mm[k]) / np.where(L > 0, L, 1.0), 0.0)
    e_start = np.concatenate([[0.0], np.cumsum(path.de_mm)])[:-1]
    e = e_start[k] + path.de_mm[k] * np.clip(u, 0, 1)
    return Trajectory(ts_s=ts_s, pos_mm=pos, e_mm=e)


def rms_violation_ratio(path, s_mm, plant, tol_mm, ts_s) -> tuple[float, object]:
    """RMS γ / E_max of a schedule executed by ``plant`` (and its Metrics)."""
    tr = vm_trajectory(path, s_mm, ts_s)
    out = plant.simulate(tr)
    m = evaluate(tr, out.actual_mm, tol_mm)
    return m.rms_gamma_mm / tol_mm, m


def largest_passing_scale(run, budget: float, *, lo: float = CONSERVATIVE_MIN_SCALE,
                          steps: int = CONSERVATIVE_STEPS):
    """The largest scale of the limits whose ``run(scale)`` → (ratio, result) keeps ratio ≤
    ``budget``: 1 if it passes, else geometric bisection on [lo, 1] in ``steps`` (``lo`` when
    nothing passes). Returns (scale, ratio, result, trials [(scale, ratio)])."""
    r, res = run(1.0)
    trials = [(1.0, r)]
    if r <= budget:
        return 1.0, r, res, trials
    hi = 1.0
    r_lo, res_lo = run(lo)
    trials.append((lo, r_lo))
    best = (lo, r_lo, res_lo)
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        r_m, res_m = run(mid)
        trials.append((mid, r_m))
        if r_m <= budget:
            lo, best = mid, (mid, r_m, res_m)
        else:
            hi = mid
    return (*best, trials)


def plan_conservative(path, profile, req: PlanRequest, *, tolerance_mm: float, plant,
                      fw_limits=None):
    """Largest common scale of V_max and A_max (bisection) whose trapezoid plan keeps
    RMS γ / E_max ≤ 1 − η on ``plant`` (``tolerance_mm``: the scalar E_max)."""
    use_slicer_feed = req.use_slicer_feed
    vmax, _, axis_a = effective_limits(profile, req.plan_vmax_mm_s, req.amax_mm_s2)
    amax = min(axis_a["x"], axis_a["y"])
    budget = 1.0 - req.stringency
    t0 = time.perf_counter()

    def run(scale):
        sch = plan_kinematic(path, profile, vmax_mm_s=vmax * scale, amax_mm_s2=amax * scale,
                             fw_limits=fw_limits, use_slicer_feed=use_slicer_feed)
        return rms_violation_ratio(path, sch.s_mm, plant, tolerance_mm, profile.ts_s)[0], sch

    scale, r, sch, trials = largest_passing_scale(run, budget)
    info = dict(sch.info)
    info.update({"conservative_scale": scale, "vmax_mm_s": vmax * scale,
                 "amax_mm_s2": amax * scale, "rms_violation_ratio": r,
                 "violation_budget": budget, "tuning_trials": len(trials),
                 "compute_s": time.perf_counter() - t0})
    return Schedule(ts_s=sch.ts_s, s_mm=sch.s_mm, method="conservative", info=info,
                    segment_plan=sch.segment_plan)


def make_twin_predictor(profile, method: str, *, learn: bool):
    """TwinPredictor of a profile for pb | dd | pidd from what the twin itself is built of:
    the physics (twin.model.twin_impulse: the profile's FRF population, narrowed to this
    machine once ``learn`` has seen its logs), the weight prior (twin.model.axis_prior) and,
    per axis, the level of what the twin cannot predict (twin.model.axis_noise_mm: what
    ``learn`` measured on the machine's logs, the profile's σ_ε until then, plus the variance
    of a fan ``diagnose -o`` wrote as an extension, twin.extensions.extra_variance_mm2) and
    the parts of it that grow with the commanded speed (twin.model.learned_speed_noise_s) and
    with the predicted dynamic error (twin.model.learned_deviation_noise) or run through the
    filters of the command that ``learn`` found the twin to miss (twin.residual), which widen
    the chance constraint by what the twin cannot predict. (The extensions' deterministic terms,
    twin.extensions.mean_offsets, are not part of the predictor: the slow-down optimizer adds
    the cross-coupling's, twin.extensions.motion_offsets.)"""
    tw = profile.twin
    irs = [twin_impulse(profile, ax, method=method) for ax in ("x", "y")]
    priors = [axis_prior(profile, ax, method=method) for ax in ("x", "y")]
    s2 = [axis_noise_mm(profile, ax, method=method) ** 2
          + extra_variance_mm2(profile.axes[ax].effects) for ax in ("x", "y")]
    terms = [learned_variance_terms(profile, ax, method=method) for ax in ("x", "y")]
    return TwinPredictor(irs, tw.n2, tw.n3, s2, [p[0] for p in priors],
                         [p[1] for p in priors], use_feature_var=(method != "dd"),
                         learn=learn and method in ("dd", "pidd"),
                         speed_var=[t[0] for t in terms], deviation_var=[t[1] for t in terms],
                         residual=[axis_residual(profile, ax, method=method) for ax in ("x", "y")])


def _pieces(path, z_pieces: bool = True):
    """(s_end, dwell_samples_after, z_move) of the stretches between exact stops; with
    ``z_pieces`` a segment that moves Z is its own stretch (planned as a rest-to-rest
    trapezoid: the per-axis XY rows do not cover Z; the free plan's constraints do)."""
    out = []
    n = path.n_segments
    dz = np.abs(path.end_mm[:, 2] - path.start_mm[:, 2]) > 1e-9
    if not z_pieces:
        dz = np.zeros(n, bool)
    for i in range(n):
        boundary = path.stop_after[i] or i == n - 1 or dz[i] or (i + 1 < n and dz[i + 1])
        if boundary:
            out.append((float(path.s0_mm[i + 1]), float(path.dwell_after_s[i]), bool(dz[i])))
    return out


def _trapezoid_samples(s_a, s_b, vmax, amax, ts):
    """Rest-to-rest trapezoid from s_a to s_b sampled at ts (excludes s_a, ends at s_b)."""
    L = s_b - s_a
    if L <= 0:
        return np.zeros(0)
    v = min(vmax, math.sqrt(L * amax))
    t_acc = v / amax
    d_acc = 0.5 * amax * t_acc ** 2
    t_cru = (L - 2 * d_acc) / v
    T = 2 * t_acc + t_cru
    k = max(1, int(math.ceil(T / ts - 1e-9)))
    t = np.arange(1, k + 1) * ts * (T / (k * ts))  # stretch so the last sample lands at T
    s = np.where(t < t_acc, 0.5 * amax * t ** 2,
                 np.where(t < t_acc + t_cru, d_acc + v * (t - t_acc),
                          L - 0.5 * amax * np.maximum(T - t, 0.0) ** 2))
    s[-1] = L
    return s_a + np.maximum.accumulate(s)


def check_noise_floor(predictor, profile, tolerance_mm: float, stringency: float) -> None:
    """Refuse a tolerance below what the twin can promise at rest: noise and bias alone (the
    contour error of a machine standing still); below it every sample would be given up."""
    z = float(norm.ppf(stringency))
    floor = z * max(math.sqrt(s2 + float(c[0, 0])) for s2, c in zip(predictor.s2, predictor.cov))
    if tolerance_mm <= 1.05 * floor:
        raise FeedOptError(
            f"tolerance {tolerance_mm:g} mm is below what the twin can promise at stringency "
            f"{stringency:g}: {floor:.3f} mm even at rest (sensor noise σ_ε and bias of "
            f"{profile.name}); use --tolerance above {1.2 * floor:.3f} or a lower --stringency")


#: the acceleration search of the offline optimizer: F's X/Y acceleration times these, tried in
#: turn while the firmware's own plan at that acceleration could still beat the best plan found
ACCEL_SEARCH = (0.7, 0.5, 0.35, 0.25)
#: a lower acceleration is tried only when the firmware's own plan there wins back at least
#: this fraction of what the slow-down costs the best plan (measured: the Cura Benchy on
#: ender3pro loses 3.0 % to the slow-down at 3000 mm/s² and the firmware's plan at 2100 mm/s²
#: already 2.6 %, and a plan there is 1 % slower: not tried; benchA's butterfly loses 140 %
#: and 5 % respectively: tried, 41 % faster)
ACCEL_SEARCH_GAIN = 0.5
#: a candidate that gives up on more samples than the best plan (``relaxed_samples``) is
#: taken only if the plan as a whole, those samples included, still keeps the stringency's
#: budget in expectation under the twin (slowdown.budget: the expected share out and RMS γ
#: within ``budget_share`` of 1 − η and (1 − η)·E_max). Measured: a corexy whose learned twin
#: gave up 2 and 6 samples at 1500 and 1050 mm/s² where the plan giving up none ran 18 %
#: slower (tests/foreign seed 0, its fourth print), and, once the stringency was a share of
#: the samples, 10–24 at every acceleration of that print (bounds 0.9–1.3 µm RMS over the
#: tolerance; a rule of 0.1·(1 − η)·E_max of excess, 0.5 µm, kept 3000 mm/s² at 11.19 s
#: against 8.43 s at 1050, 0.99 expected within).


def search_acceleration(path, profile, first, plan_at, *, vmax, axis_v, axis_a, fw_limits,
                        use_slicer_feed: bool, factors=ACCEL_SEARCH, budget=(0.0, 0.0)):
    """The fastest slow-down plan over the X/Y acceleration: ``first`` (the plan at F's
    acceleration) or ``plan_at(axis_a')`` at F's acceleration times ``factors`` in turn.

    On a lightly damped machine the contour error is the ringing after each acceleration step
    (a step of Δa rings with an amplitude of about Δa/ω²): a slow-down that keeps F's
    acceleration slows long stretches to stay clear of it, where a lower acceleration
    everywhere costs little (measured on benchA's butterfly at η 0.95: 12.2 s at 5000 mm/s²,
    7.8 s at 1500; docs/optimizer.md). Every candidate is a plan the chance bound holds on, so
    the search only picks among valid plans. It stops as soon as the firmware's own plan at the
    next acceleration (its time a lower bound of any slow-down of it: the slow-down only ever
    lowers F's limits) does not win back ACCEL_SEARCH_GAIN of what the slow-down costs the best
    plan found, so where the tolerance binds little (most prints at their slicer's speeds) it
    costs one kinematic plan. A candidate that leaves F unchanged (the file's own M204 below
    it) is skipped; one that gives up on more samples than the best is taken only if the plan's
    expected share of samples out of tolerance and expected RMS γ (``predicted_within_fraction``,
    ``predicted_rms_gamma_mm``: those samples included) are within ``budget`` (share, mm). The
    best acceleration is then refined with the geometric midpoints to its neighbours.

    Returns (plan, acceleration chosen or None, [(acceleration, plan time s), …] tried; the
    first entry also carries the firmware's own plan time at F's acceleration when the first
    plan was slowed — else the first plan is that plan)."""
    ts = profile.ts_s

    def t_plan(r):
        return (r.s_mm.size - 1) * ts

    def t_kin(a_xy):
        lim = dict(axis_a, x=min(axis_a["x"], a_xy), y=min(axis_a["y"], a_xy))
        return plan_trapezoids(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=lim,
                               firmware=profile.firmware, use_slicer_feed=use_slicer_feed,
                               fw_limits=fw_limits).duration_s

    best, chosen = first, None
    a0 = min(axis_a["x"], axis_a["y"])
    tried = [(a0, t_plan(first))]
    if not first.info.get("slowed_length_fraction", 0.0) > 0.0:
        return best, chosen, tried
    t_prev = t_kin(a0)
    tried[0] = (a0, t_plan(first), t_prev)
    t_kin_best = t_prev

    def worth(tk):
        # the firmware's plan at an acceleration is a lower bound of any plan there; a
        # slow-down of it still costs something, so it must win back at least
        # ACCEL_SEARCH_GAIN of what the slow-down costs the best plan (its time over the
        # firmware's at its acceleration)
        return tk < t_plan(best) - ACCEL_SEARCH_GAIN * (t_plan(best) - t_kin_best)

    def attempt(a, tk):
        nonlocal best, chosen, t_kin_best
        res = plan_at(dict(axis_a, x=min(axis_a["x"], a), y=min(axis_a["y"], a)))
        tried.append((a, t_plan(res)))
        if (t_plan(res) < t_plan(best) * (1.0 - 1e-3)
                and (res.info["relaxed_samples"] <= best.info["relaxed_samples"]
                     or (1.0 - res.info.get("predicted_within_fraction", 0.0) <= budget[0]
                         and res.info.get("predicted_rms_gamma_mm", np.inf) <= budget[1]))):
            best, chosen, t_kin_best = res, a, tk

    for f in factors:
        a = a0 * f
        tk = t_kin(a)
        if not worth(tk):
            break
        if abs(tk - t_prev) <= 1e-9 * tk:
            continue
        t_prev = tk
        attempt(a, tk)
    if len(tried) > 1:
        # refine: the geometric midpoints between the best acceleration and its neighbours on
        # the coarse grid (the next lower one even if the bound above stopped the search
        # before it), each again only if the firmware's plan there could win
        a_best = a0 if chosen is None else chosen
        grid = [a0] + [a0 * f for f in factors]
        k = int(np.argmin([abs(g - a_best) for g in grid]))
        for nb in (grid[k - 1] if k > 0 else None, grid[k + 1] if k + 1 < len(grid) else None):
            if nb is None:
                continue
            a = math.sqrt(a_best * nb)
            tk = t_kin(a)
            if worth(tk):
                attempt(a, tk)
    return best, chosen, tried


def plan_offline(path, profile, req: PlanRequest, *, tolerance_mm, plant=None,
                 fw_limits=None, settings=None) -> Schedule:
    """Offline plan of a whole file for pb | pidd | oracle: the firmware's own plan slowed
    down locally until the twin (or, for the oracle, the plant) keeps the chance bound on
    every sample (optimize.slowdown; the window LP of mpc.py is the full method it is tested
    against). ``tolerance_mm``: the E_max the plan keeps, scalar or (N,) per segment."""
    method, stringency, use_slicer_feed = req.method, req.stringency, req.use_slicer_feed
    if method == "dd":
        raise FeedOptError("method dd learns from data only (zero prior) and has no data offline; "
                           "use --method pidd, or run dd online on the virtual machine with "
                           "`gcode-feedopt compare`")
    vmax, axis_v, axis_a = effective_limits(profile, req.plan_vmax_mm_s, req.amax_mm_s2)
    limits = planner_limits(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v,
                            axis_amax_mm_s2=axis_a, firmware=profile.firmware,
                            fw_limits=fw_limits, use_slicer_feed=use_slicer_feed)
    z = float(norm.ppf(stringency))
    seg_tol = None
    if np.ndim(tolerance_mm):  # per feature: (N,) E_max of each segment
        seg_tol = np.asarray(tolerance_mm, float)
        tolerance_mm = scalar_tolerance(seg_tol)
    kw = dict(z=z, tol_mm=tolerance_mm, overshoot_reach_mm=max(1.0, OVERSHOOT_LAG_S * vmax))
    rules = ContourRules(path)
    if method == "oracle":
        evaluator = PlantEvaluator(plant, rules, **kw)
    else:
        predictor = make_twin_predictor(profile, method, learn=False)
        check_noise_floor(predictor, profile, tolerance_mm, stringency)
        evaluator = TwinEvaluator(predictor, rules, ts_s=profile.ts_s,
                                  offsets=motion_offsets(profile),
                                  shapers=profile.firmware.input_shaper, **kw)
    if seg_tol is not None:
        evaluator.set_feature_tolerance(path, seg_tol)
    # the plan must see the machine's ringing and settling out (SlowdownSettings.seeing_out)
    settings = (settings or SlowdownSettings()).seeing_out(memory_time_s(profile))
    res = plan_slowdown(path, limits, evaluator, ts_s=profile.ts_s, settings=settings)

    def plan_at(axis_a2):
        lim2 = planner_limits(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v,
                              axis_amax_mm_s2=axis_a2, firmware=profile.firmware,
                              fw_limits=fw_limits, use_slicer_feed=use_slicer_feed)
        return plan_slowdown(path, lim2, evaluator, ts_s=profile.ts_s, settings=settings)

    res, chosen, tried = search_acceleration(
        path, profile, res, plan_at, vmax=vmax, axis_v=axis_v, axis_a=axis_a,
        fw_limits=fw_limits, use_slicer_feed=use_slicer_feed,
        budget=(settings.budget_share * (1.0 - stringency),
                settings.budget_share * (1.0 - stringency) * tolerance_mm))
    on = res.bound_mm > 0
    info = dict(res.info)
    info.update({
        "plan_time_s": (res.s_mm.size - 1) * profile.ts_s, "stringency": stringency,
        "tolerance_mm": tolerance_mm, "z": z, "online": False,
        "predicted_max_contour_error_mm": float(np.max(res.bound_mm)) if on.any() else 0.0,
        "predicted_p95_contour_error_mm":
            float(np.quantile(res.motion_mm[on], 0.95)) if on.any() else 0.0,
        "predicted_bound_mm": res.bound_mm, "predicted_motion_mm": res.motion_mm,
        "_predicted_xy_mm": res.mean_xy_mm,
        "vmax_mm_s": vmax,
        "amax_mm_s2": chosen if chosen is not None else min(axis_a["x"], axis_a["y"]),
        "accel_chosen_mm_s2": chosen, "accel_search": [t[:2] for t in tried],
        # the firmware's own plan of the path at F's limits (what the twin's changes are
        # measured against: the report's time split); None when the first plan was not
        # slowed (it is F, but sampled: the report plans F itself)
        "kinematic_time_s": tried[0][2] if len(tried[0]) > 2 else None})
    return Schedule(ts_s=profile.ts_s, s_mm=res.s_mm, method=method, info=info,
                    segment_plan=_segment_plan(res.cells, path.n_segments), cells=res.cells)


def scalar_tolerance(seg_tol: np.ndarray) -> float:
    """The one number of a per-segment tolerance: its tightest finite value (1 mm when no
    segment is constrained)."""
    finite = seg_tol[np.isfinite(seg_tol)]
    return float(finite.min()) if finite.size else 1.0


def _segment_plan(cells: SlowdownCells, n_segments: int) -> SegmentPlan:
    """Each segment's peak speed and acceleration in a slow-down plan (the writer's one line
    per unslowed segment: its cells share one acceleration and meet without a junction rule,
    so the segment is one trapezoid; slowed segments are written from the cells)."""
    first = np.searchsorted(cells.parent, np.arange(n_segments + 1))
    return segment_plan(np.maximum.reduceat(cells.vpeak_mm_s, first[:-1]),
                        np.minimum.reduceat(cells.accel_mm_s2, first[:-1]),
                        np.asarray(cells.jerk_junction)[first],
                        np.minimum.reduceat(cells.vcap_mm_s, first[:-1]))


def plan_mpc(path, profile, predictor, *, method, tolerance_mm, stringency, vmax_mm_s=None,
             amax_mm_s2=None, settings: MpcSettings | None = None, plant=None,
             online: bool = False, fw_limits=None, free: bool = True, screen: bool = True,
             workers: int | None = None, use_slicer_feed: bool = False):
    """Receding-window plan of the whole path with ``predictor``; with ``plant`` and
    ``online`` the plant runs each committed window and the predictor observes it.

    Long for a reason: the serial and the parallel runs build their planners from the same
    locals (limits, z, settings, the free plan) and the online run's commit hook closes over
    the planner; the pieces' loop and the result's info are their own functions."""
    if profile.firmware.input_shaper:
        raise FeedOptError(f"profile {profile.name}: the window optimizer does not model the "
                           "firmware's input shaper (firmware.input_shaper); the main command "
                           "plans with the slow-down optimizer, which does (`compare` runs the "
                           "paper's window optimizer)")
    vmax, axis_v, axis_a = effective_limits(profile, vmax_mm_s, amax_mm_s2)
    ts = profile.ts_s
    z = float(norm.ppf(stringency))
    settings = settings or MpcSettings()
    measured = []
    learning = online and plant is not None and getattr(predictor, "learn", False)
    if method == "dd" and not learning:
        raise FeedOptError("method dd learns from data only (zero prior) and has no data offline; "
                           "use --method pidd, or run dd online on the virtual machine with "
                           "`gcode-feedopt compare`")
    if hasattr(predictor, "s2") and not learning:
        check_noise_floor(predictor, profile, tolerance_mm, stringency)

    def on_commit(k0, cmd):
        if not (online and plant is not None):
            return
        # the plant is causal: run the whole committed history, read the new samples
        full = np.asarray(planner.cmd_hist, float)

        tr = Trajectory(ts_s=ts, pos_mm=np.column_stack([full, np.zeros(len(full))]),
                        e_mm=np.zeros(len(full)))
        out = plant.simulate(tr)
        meas = out.measured_mm[k0:, :2]
        measured.append((k0, meas))
        predictor.observe(k0, meas)

    fp = None
    if free:
        fp = FreePlan(path, plan_kinematic(path, profile, vmax_mm_s=vmax_mm_s,
                                           amax_mm_s2=amax_mm_s2, fw_limits=fw_limits,
                                           use_slicer_feed=use_slicer_feed))
    planner = MpcPlanner(path, predictor, ts_s=ts, vmax_mm_s=vmax,
                         amax_mm_s2=np.array([axis_a["x"], axis_a["y"]]), tol_mm=tolerance_mm,
                         z=z, settings=settings, axis_vmax_mm_s=axis_v, on_commit=on_commit,
                         free=fp, screen=screen)
    t0 = time.perf_counter()
    pieces = _pieces(path, z_pieces=fp is None)
    n_workers = parallel.default_workers() if workers is None else int(workers)
    if (fp is not None and screen and not (online and plant is not None) and n_workers > 1
            and hasattr(predictor, "load_history") and len(pieces) > 1
            and fp.s_mm.size >= parallel.MIN_PARALLEL_SAMPLES):
        import copy

        pristine = copy.deepcopy(predictor)

        def make_planner():
            pr = copy.deepcopy(pristine)
            return MpcPlanner(path, pr, ts_s=ts, vmax_mm_s=vmax,
                              amax_mm_s2=np.array([axis_a["x"], axis_a["y"]]),
                              tol_mm=tolerance_mm, z=z, settings=settings,
                              axis_vmax_mm_s=axis_v, free=fp, screen=screen), pr

        nt = max(h.size for h in predictor.h)
        ctx = {"make_planner": make_planner, "pieces": pieces, "F_s": fp.s_mm, "ts": ts,
               "path": path, "predictor": pristine, "dwell_before_s": path.dwell_before_s,
               "history": nt + predictor.maxlag + parallel.HISTORY_PAD}
        s_par, info_par, xy_par = parallel.run_parallel(ctx, n_workers)
        res = MpcResult(s_par, info_par)
        pred_xy_override = xy_par
    else:
        res = None
        pred_xy_override = None
        planner.start(0.0)
        planner.hold(int(round(path.dwell_before_s / ts)))
    if res is None:
        _run_pieces(planner, pieces, path, vmax, axis_v, axis_a, ts)
        res = planner.result()
    info = _mpc_info(res, predictor, pred_xy_override)
    info["compute_s"] = time.perf_counter() - t0
    info["plan_time_s"] = (res.s_mm.size - 1) * ts
    info["stringency"] = stringency
    info["tolerance_mm"] = tolerance_mm
    info["z"] = z
    info["online"] = bool(online and plant is not None)
    if "_pred_mean_mm" in info:
        mu = info.pop("_pred_mean_mm")
        sd = info.pop("_pred_std_mm")
        on = info.pop("_pred_on", None)
        if on is not None and on.size == mu.size:
            mu, sd = mu[on], sd[on]
        bnd = np.abs(mu) + z * sd
        info["predicted_max_contour_error_mm"] = float(np.max(bnd)) if bnd.size else 0.0
        info["predicted_p95_contour_error_mm"] = float(np.quantile(np.abs(mu), 0.95)) if mu.size else 0.0
    info["vmax_mm_s"] = vmax
    info["amax_mm_s2"] = min(axis_a["x"], axis_a["y"])
    return Schedule(ts_s=ts, s_mm=res.s_mm, method=method, info=info)


def _run_pieces(planner, pieces, path, vmax, axis_v: dict, axis_a: dict, ts: float) -> None:
    """The window planner over the stretches between exact stops, in order: a stretch that
    moves Z as a rest-to-rest trapezoid at the axes' limits along its direction, the others
    window by window; then each stop's dwell."""
    for s_end, dwell_s, z_move in pieces:
        if z_move:
            s_a = planner.s_hist[-1]
            mid = 0.5 * (s_a + s_end)
            t = np.abs(path.tangent(np.array([mid]))[0])
            vz = min([vmax] + [axis_v[a] / t[i] for i, a in enumerate("xyz") if t[i] > 1e-12])
            az = min([axis_a[a] / t[i] for i, a in enumerate("xyz") if t[i] > 1e-12])
            planner._commit(_trapezoid_samples(s_a, s_end, vz, az, ts))
            planner._prev = None
        else:
            planner.run_piece(s_end)
        planner.hold(int(round(dwell_s / ts)))


def _mpc_info(res, predictor, pred_xy_override) -> dict:
    """The window plan's info with the twin's predicted X/Y (the workers' when they planned,
    else the predictor's own) where it covers the plan."""
    info = dict(res.info)
    pred_xy = getattr(predictor, "pred_mean", None)
    if pred_xy_override is not None and pred_xy_override.shape[0] == res.s_mm.size:
        info["_predicted_xy_mm"] = pred_xy_override
    elif pred_xy is not None and len(pred_xy[0]) == res.s_mm.size:
        info["_predicted_xy_mm"] = np.column_stack([np.asarray(pred_xy[0]), np.asarray(pred_xy[1])])
    info.pop("_pred_xy_mm", None)
    return info


def optimizer_of(opts: dict, online: bool) -> str:
    return opts.get("optimizer") or ("window" if online else "slowdown")


def plan_schedule(method: str, path, profile, *, tolerance_mm: float, stringency: float,
                  vmax_mm_s: float | None = None, amax_mm_s2: float | None = None,
                  plant=None, online: bool = False, settings: MpcSettings | None = None,
                  fw_limits=None, use_slicer_feed: bool = False, **opts) -> Schedule:
    """The Schedule of ``method`` on ``path`` (see the module docstring): :func:`plan_request`
    of the request these values make.

    Args:
        method: kinematic | conservative | pb | dd | pidd | oracle.
        path: gcode.path.Path.
        profile: MachineProfile.
        tolerance_mm: E_max, mm, scalar or (N,) per segment. stringency: η in (0, 1).
        vmax_mm_s, amax_mm_s2: override the profile's V_max and X/Y A_max.
        plant, online, settings, fw_limits, opts: as :func:`plan_request` takes them.
        use_slicer_feed: never faster than the slicer's F (every method plans below the
            firmware's plan at those feeds).
    """
    scalar = (scalar_tolerance(np.asarray(tolerance_mm, float)) if np.ndim(tolerance_mm)
              else tolerance_mm)
    req = PlanRequest(method=method, tolerance_mm=scalar, stringency=stringency,
                      vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2, plan_vmax_mm_s=vmax_mm_s,
                      use_slicer_feed=use_slicer_feed)
    return plan_request(req, path, profile, tolerance_mm, plant=plant, online=online,
                        settings=settings, fw_limits=fw_limits, **opts)


def plan_request(req: PlanRequest, path, profile, tolerance_mm=None, *, plant=None,
                 online: bool = False, settings: MpcSettings | None = None, fw_limits=None,
                 **opts) -> Schedule:
    """The Schedule of ``req.method`` on ``path`` (see the module docstring).

    Args:
        req: plan.request.PlanRequest (method, stringency, V_max under the speed policy,
            --amax, use_slicer_feed).
        path: gcode.path.Path.
        profile: MachineProfile.
        tolerance_mm: the E_max the plan keeps, mm: scalar or (N,) per segment
            (pipeline.tolerance_for); None: ``req.tolerance_mm``.
        plant: vm.plant.Plant the method is tuned on (conservative), knows (oracle) or runs
            on (online). Default: the profile's nominal plant (the FRF set's mean response).
        online: learn from the plant's measurements window by window (pb never learns).
        settings: MpcSettings (window length, horizon, solver, ...) of the window optimizer.
        fw_limits: the file's firmware.MoveLimits (firmware.Replay.move_limits).
        opts: ``optimizer`` (``slowdown`` offline by default, ``window`` online and on
            request), ``seed`` (the default plant), and the window optimizer's ``free``,
            ``screen``, ``workers``.
    """
    method, stringency = req.method, req.stringency
    vmax_mm_s, amax_mm_s2 = req.plan_vmax_mm_s, req.amax_mm_s2
    use_slicer_feed = req.use_slicer_feed
    if tolerance_mm is None:
        tolerance_mm = req.tolerance_mm
    if method not in METHODS:
        raise FeedOptError(f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    if not (0.5 <= stringency < 1.0):
        raise FeedOptError(f"stringency {stringency} is outside [0.5, 1); pass e.g. 0.95")
    if np.ndim(tolerance_mm):
        tol_arr = np.asarray(tolerance_mm, float)
        if tol_arr.shape != (path.n_segments,) or not np.all(tol_arr > 0):
            raise FeedOptError(f"per-feature tolerance: {tol_arr.shape} values for "
                               f"{path.n_segments} segments, all must be positive")
        if method in ("conservative", "kinematic"):
            tolerance_mm = scalar_tolerance(tol_arr)
        elif optimizer_of(opts, online) != "slowdown":
            raise FeedOptError("a tolerance per feature is planned by the slow-down optimizer "
                               "(pb, pidd, oracle offline); the window optimizer takes one "
                               "--tolerance")
    elif not tolerance_mm > 0:
        raise FeedOptError(f"tolerance {tolerance_mm} mm must be positive; pass e.g. 0.1")
    unknown = set(opts) - {"seed", "free", "screen", "workers", "optimizer"}
    if unknown:
        raise FeedOptError(f"unknown option(s) {sorted(unknown)} for plan_schedule")
    optimizer = opts.get("optimizer") or ("window" if online else "slowdown")
    if optimizer not in OPTIMIZERS:
        raise FeedOptError(f"unknown optimizer {optimizer!r}; use one of {', '.join(OPTIMIZERS)}")
    if optimizer == "slowdown" and online:
        raise FeedOptError("the slow-down optimizer plans offline; online learning on the "
                           "virtual machine needs the window optimizer")
    if method == "kinematic":
        return plan_kinematic(path, profile, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                              fw_limits=fw_limits, use_slicer_feed=use_slicer_feed)
    if plant is None and method in ("conservative", "oracle"):
        plant = Plant(profile, seed=int(opts.get("seed", 0)), nominal=True)
    if method == "conservative":
        return plan_conservative(path, profile, req, tolerance_mm=tolerance_mm, plant=plant,
                                 fw_limits=fw_limits)
    if optimizer == "slowdown":
        return plan_offline(path, profile, req, tolerance_mm=tolerance_mm, plant=plant,
                            fw_limits=fw_limits)
    if method == "oracle":
        predictor = PlantPredictor(plant)
    else:
        predictor = make_twin_predictor(profile, method, learn=online)
    return plan_mpc(path, profile, predictor, method=method, tolerance_mm=tolerance_mm,
                    stringency=stringency, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                    settings=settings, plant=plant, online=online, fw_limits=fw_limits,
                    use_slicer_feed=use_slicer_feed,
                    **{k: opts[k] for k in ("free", "screen", "workers") if k in opts})
