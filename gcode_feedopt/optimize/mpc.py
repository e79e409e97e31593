"""Receding-window driver (paper Sec. 4 "model predictive control", with the additions of
issue 5): plan a horizon, commit its first ``n_window`` samples, move on.

Horizon of every window = ``n_window`` committed samples + ``n_brake`` samples in which the
plan must come to rest + ``n_hold`` samples held at rest. So
- the vibration that outlives the committed window (and the braking) is predicted and
  constrained (prediction horizon longer than the window);
- every accepted plan ends at standstill within the known path (terminal condition): the
  rest of an accepted horizon is always a valid continuation, which is the *fallback* when a
  later window is infeasible or fails verification (it is reported in ``info``);
- the path is re-linearised about each solution until the plan moves by less than
  ``conv_tol_mm`` (or ``max_iter``), then the plan is verified on the exact (non-linearised)
  path with the predictor; a plan that fails verification is not committed.
If even the first window at rest is infeasible (the predicted error alone exceeds the
tolerance, e.g. an un-learned disturbance), the window is solved with the chance constraint
made elastic (violation penalised ``ELASTIC_WEIGHT`` times more than any progress can gain)
and reported as ``relaxed``.

Predictors (see methods.py) give, for the horizon commands, the predicted actual XY position
(affine: mean at a nominal command plus its Jacobian) and its std.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..errors import SolverError
from . import window as win

#: Elastic chance constraint: weight of 1 mm of violation relative to the progress objective
#: (≤ n per window in scaled units); large enough that slack is used only when unavoidable.
ELASTIC_WEIGHT = 1e5
#: Verification slack on the chance constraint (linearisation residue accepted), mm per mm of
#: tolerance.
VERIFY_REL = 0.02
#: Verification slack on the free plan's speed cap, mm/s: near slow junctions the cap is
#: strongly curved in s and its linearisation misses by ~1 mm/s; the firmware's own junction
#: rule clips such an excess when it runs the file (executed vs plan time in the report).
VERIFY_CAP_MM_S = 2.0
#: Verification slack on the acceleration limits (relative).
VERIFY_ACC_REL = 0.01
#: The LP uses this fraction of A_max: the tangent linearisation misses part of the
#: centripetal term while the plan moves from s̄, and verification allows VERIFY_ACC_REL.
LP_ACC_MARGIN = 0.995
#: Speed trust region of the sequential LP: initial radius such that the linearisation
#: residue κ(ṡ − ṡ̄)² is this fraction of A_max; lower bound, mm/s.
TRUST_ACC_FRAC = 0.01
TRUST_MIN_MM_S = 1.0
#: Lag/lead of the actual position behind the command covered by the overshoot rows, s.
OVERSHOOT_LAG_S = 0.02
#: Secant of the orbit cap's slope Φ' behind s̄ (mm), and its clip (Φ' = ratio of F's
#: speeds one sample apart; large only leaving a standstill).
CAP_SLOPE_H_MM = 0.05
CAP_SLOPE_MAX = 4.0
#: With the free plan's constraints: initial speed trust radius as a fraction of V_max.
TRUST_FREE_FRAC = 0.25
#: Step fractions tried back towards the verified plan when a linearised step fails
#: verification.
LINE_SEARCH = (0.5, 0.25)
#: Windows without progress after which the plan proceeds along the firmware's plan (the
#: error that standing still does not cure is not the motion's).
STALL_PROCEED = 3


class Predictor(Protocol):
    def predict(self, k0: int, cmd_h: np.ndarray):
        """For horizon commands cmd_h (n, 2) starting at global sample k0 (all earlier
        commands committed): mean (2, n) predicted actual XY, jac (2, n, n) d mean/d cmd
        per axis, std (2, n) mm."""

    def commit(self, k0: int, cmd: np.ndarray) -> None:
        """Samples k0 … k0+len(cmd)−1 are committed with XY commands cmd (m, 2)."""


@dataclass(frozen=True)
class MpcSettings:
    """Knobs of the receding window (defaults: the paper's printer settings, n_w = 30)."""

    n_window: int = 30
    n_brake: int | None = None  # None: enough to stop from V_max at A_max, plus 2
    n_hold: int = 20
    max_iter: int = 10
    conv_tol_mm: float = 2e-3
    solver: str = "highs"
    jmax_mm_s3: float | None = None


@dataclass
class MpcResult:
    s_mm: np.ndarray
    info: dict = field(default_factory=dict)


class Geometry(Protocol):
    def position(self, s_mm) -> np.ndarray: ...
    def tangent(self, s_mm) -> np.ndarray: ...


def _normals(tan_xy: np.ndarray) -> np.ndarray:
    nrm = np.linalg.norm(tan_xy, axis=1, keepdims=True)
    t = tan_xy / np.where(nrm > 1e-12, nrm, 1.0)
    out = np.column_stack([-t[:, 1], t[:, 0]])
    out[nrm[:, 0] <= 1e-12] = 0.0
    return out


def _contour(normal, cmd, mean, std):
    """Predicted contour error mean and std (n,) (paper Eqs. 6, 21)."""
    err = cmd.T - mean  # (2, n)
    mu = normal[:, 0] * err[0] + normal[:, 1] * err[1]
    sig = np.sqrt((normal[:, 0] * std[0]) ** 2 + (normal[:, 1] * std[1]) ** 2)
    return mu, sig


class MpcPlanner:
    """Stateful driver over one path (pieces between exact stops are planned in order)."""

    def __init__(self, geom: Geometry, predictor: Predictor, *, ts_s: float, vmax_mm_s: float,
                 amax_mm_s2, tol_mm: float, z: float, settings: MpcSettings = MpcSettings(),
                 axis_vmax_mm_s=None, on_commit=None, free=None, screen: bool = True):
        self.geom = geom
        #: optimize.free.FreePlan: firmware-consistent constraints (cap along the kinematic
        #: plan's orbit, tangential acceleration, contour on extruding samples); None keeps
        #: the paper's per-axis sampled acceleration rows
        self.free = free
        #: with ``free``: accept a window's greedy continuation along the free plan without
        #: an LP when it verifies (it is then the LP's optimum; see free.py)
        self.screen = bool(screen) and free is not None
        #: sharp vertices within this path distance of a sample get an overshoot row (mm):
        #: how far the actual position can lag or lead the command (≈ V_max × 20 ms)
        self.overshoot_reach = max(1.0, OVERSHOOT_LAG_S * float(vmax_mm_s))
        self.pred = predictor
        self.ts = float(ts_s)
        self.vmax = float(vmax_mm_s)
        self.amax = np.broadcast_to(np.asarray(amax_mm_s2, float), (2,)).copy()
        self.tol = float(tol_mm)
        self.z = float(z)
        self.st = settings
        self.axis_vmax = axis_vmax_mm_s
        self.on_commit = on_commit
        amin = float(np.min(self.amax))
        self.n_brake = settings.n_brake if settings.n_brake is not None else \
            int(math.ceil(self.vmax / (amin * self.ts))) + 2
        self._nb_default = self.n_brake
        self.n = settings.n_window + self.n_brake + settings.n_hold
        self.s_hist: list[float] = []
        self.cmd_hist: list[np.ndarray] = []
        self.osqp = win.OsqpWindowSolver()
        self.stats = {"windows": 0, "iterations": 0, "solver_s": 0.0, "status": {},
                      "fallback_windows": [], "relaxed_windows": [], "unconverged": 0,
                      "pred_mean_mm": [], "pred_std_mm": [], "pred_on": [], "pred_xy_mm": [], "solve_times_s": []}
        self._prev: np.ndarray | None = None  # previous accepted horizon s (n,)

    # -- helpers -------------------------------------------------------------------------
    def _count(self, key):
        self.stats["status"][key] = self.stats["status"].get(key, 0) + 1

    def _vcap(self, s_bar):
        """(n,) feed cap per sample from V_max and the per-axis feed limits on the tangent."""
        cap = np.full(s_bar.size, self.vmax)
        if self.axis_vmax is not None:
            t = np.abs(self.geom.tangent(s_bar))
            lim = np.array([self.axis_vmax.get(a, np.inf) for a in ("x", "y", "z")])
            with np.errstate(divide="ignore"):
                cap = np.minimum(cap, np.where(t > 1e-12, lim[None, :] / t, np.inf).min(axis=1))
        return cap

    def _past_cmd(self):
        if not self.cmd_hist:
            raise RuntimeError("no committed sample")
        last = self.cmd_hist[-3:]
        while len(last) < 3:
            last = [last[0]] + last
        return np.array(last)

    def _window_data(self, s_start, s_bar, s_max, trust=None, trust_v=None):
        n = self.n
        nw, nb = self.st.n_window, self.n_brake
        pos = self.geom.position(s_bar)[:, :2]
        tan = self.geom.tangent(s_bar)[:, :2]
        normal = _normals(tan)
        k0 = len(self.s_hist)
        mean, jac, std = self.pred.predict(k0, pos)
        err_bar = pos.T - mean
        err_jac = np.eye(n)[None, :, :] - jac
        sig = np.sqrt((normal[:, 0] * std[0]) ** 2 + (normal[:, 1] * std[1]) ** 2)
        ds_max = self._vcap(s_bar) * self.ts
        jmax = None if self.st.jmax_mm_s3 is None else np.full(2, self.st.jmax_mm_s3)
        amax = self.amax * LP_ACC_MARGIN
        acc_t = rows = cap_next = cap_slope = halfplanes = None
        past_ds = 0.0
        if self.free is not None:
            f = self.free
            ext = np.concatenate([[self._s_before(), s_start], s_bar])
            s_prev = ext[1:-1]
            cap_next = s_prev + f.step_cap(s_prev)
            # secant slope of Φ just behind s̄ (a slower plan sits behind it)
            back = np.maximum(s_prev - CAP_SLOPE_H_MM, 0.0)
            span = s_prev - back
            cap_slope = np.where(span > 0, (cap_next - back - f.step_cap(back))
                                 / np.where(span > 0, span, 1.0), 1.0)
            cap_slope = np.clip(cap_slope, 0.0, CAP_SLOPE_MAX)
            ds_max[0] = min(ds_max[0], cap_next[0] - s_start)
            # the LP takes the smaller per-move acceleration where a span touches two
            # segments (verification allows the larger, which F itself may use)
            acc_t = f.accel(ext[:-2], ext[2:], smallest=True)
            rows = f.constrained(s_bar, s_start)
            halfplanes = f.overshoot_rows(s_bar, rows, self.overshoot_reach, self.tol)
            past_ds = s_start - ext[0]
            amax = None
        ds_max[nw + nb:] = 0.0
        return win.WindowData(
            ts_s=self.ts, s_start_mm=s_start, s_bar_mm=s_bar, pos_bar_mm=pos, tan_bar=tan,
            past_cmd_mm=self._past_cmd(), s_max_mm=s_max, ds_max_mm=ds_max,
            amax_mm_s2=amax, tol_mm=self.tol, z=self.z, err_bar_mm=err_bar,
            err_jac=err_jac, normal=normal, sigma_mm=sig, jmax_mm_s3=jmax, trust_mm=trust,
            trust_v_mm_s=trust_v, acc_t_mm_s2=acc_t, past_ds_mm=past_ds, contour_rows=rows,
            cap_next_mm=cap_next, cap_slope=cap_slope, halfplanes=halfplanes, std_xy_mm=std)

    def _s_before(self) -> float:
        """s of the sample before the last committed one (the last one at the start)."""
        return self.s_hist[-2] if len(self.s_hist) > 1 else self.s_hist[-1]

    def _verify(self, s, s_max, kinematic: bool = True):
        """Exact-path check of a horizon plan: (ok, worst chance value / tol, worst accel
        ratio, predicted mean, std). ``kinematic=False`` skips the cap and acceleration
        checks (for F's own continuation: the firmware's plan, executable by definition; its
        sampled second differences across sub-sample segments may exceed a_t by a few %)."""
        cmd = self.geom.position(s)[:, :2]
        tan = self.geom.tangent(s)[:, :2]
        k0 = len(self.s_hist)
        mean, _, std = self.pred.predict(k0, cmd, jac=False)
        mu, sig = _contour(_normals(tan), cmd, mean, std)
        bound = np.abs(mu) + self.z * sig
        if self.free is not None:
            f = self.free
            on = f.constrained(s, self.s_hist[-1])
            bound = np.where(on, bound, 0.0)
            kk, U, b = f.overshoot_rows(s, on, self.overshoot_reach, self.tol)
            if kk.size:
                over = (np.sum(U * mean[:, kk].T, axis=1)
                        + self.z * np.sqrt((U[:, 0] * std[0, kk]) ** 2 + (U[:, 1] * std[1, kk]) ** 2)
                        - (b - self.tol))
                np.maximum.at(bound, kk, over)
            acc_ratio = 1.0
            if kinematic:
                ext = np.concatenate([[self._s_before(), self.s_hist[-1]], s])
                ds = np.diff(ext)
                a_t = f.accel(ext[:-2], ext[2:])
                acc_ratio = float(np.max(np.abs(np.diff(ds)) / (a_t * self.ts ** 2)))
                cap = f.step_cap(ext[1:-1])
                over = float(np.max(ds[1:] - cap * (1.0 + VERIFY_ACC_REL)
                                    - VERIFY_CAP_MM_S * self.ts - 1e-9))
                if over > 0:
                    acc_ratio = max(acc_ratio, 1.0 + VERIFY_ACC_REL + over)
        else:
            full = np.vstack([self._past_cmd(), cmd])
            acc = np.abs(np.diff(full, 2, axis=0)) / self.ts ** 2
            acc_ratio = float(np.max(acc / self.amax[None, :]))
        chance = float(np.max(bound)) / self.tol
        ok = (chance <= 1.0 + VERIFY_REL and acc_ratio <= 1.0 + VERIFY_ACC_REL
              and s[-1] <= s_max + 1e-9 and np.all(np.diff(np.concatenate([[self.s_hist[-1]], s])) >= -1e-9))
        self._last_mean = mean
        return ok, chance, acc_ratio, mu, sig

    def _trust0(self, s_start):
        """Initial speed trust radius (mm/s): the tangent linearisation misses κ(ṡ − ṡ̄)² of
        acceleration; keep that within ``TRUST_ACC_FRAC`` of A_max on the sharpest turn
        ahead (from the turning of the tangent over the reach of the horizon)."""
        reach = self.vmax * self.ts * self.n
        grid = s_start + np.linspace(0.0, reach, 128)
        t = self.geom.tangent(grid)[:, :2]
        turn = np.linalg.norm(np.diff(t, axis=0), axis=1)
        kappa = float(np.max(turn)) / max(grid[1] - grid[0], 1e-9)
        if kappa <= 1e-9:
            return self.vmax
        return float(np.clip(math.sqrt(TRUST_ACC_FRAC * float(np.min(self.amax)) / kappa),
                             TRUST_MIN_MM_S, self.vmax))

    def _objective(self, s):
        return float(np.sum(s))

    def _solve(self, s_start, s_ref, s_max, ref_ok, s_guess, incumbent=None):
        """Sequential LP with an adaptive trust region. Linearises first about ``s_guess``
        (the previous plan continued at its speed: where the new plan is likely to go), and
        falls back to the verified reference ``s_ref`` (the previous horizon's braking
        continuation, or rest) when the LP there is infeasible. Returns (status, s): s is the
        best *verified* plan found (s_ref when nothing better verifies and ``ref_ok``)."""
        s_best = s_ref if ref_ok else None
        best_obj = self._objective(s_ref) if ref_ok else -np.inf
        status = "continued"
        if incumbent is not None and self._objective(incumbent) > best_obj:
            # a verified plan to beat (the greedy continuation along the free plan)
            s_best, best_obj, status = incumbent, self._objective(incumbent), "optimal"
        s_lin = s_guess
        delta = self._trust0(s_start)
        if self.free is not None:
            # no per-axis rows to protect: the trust region only guards the chance
            # constraint's path linearisation (the line search halves it when needed)
            delta = max(delta, TRUST_FREE_FRAC * self.vmax)
        delta_cap = self.vmax
        for _ in range(self.st.max_iter):
            w = self._window_data(s_start, s_lin, s_max, trust_v=delta)
            warm = np.diff(np.concatenate([[s_start], s_lin]))
            sol = win.solve_window(w, solver=self.st.solver, osqp_solver=self.osqp,
                                   warm_ds_mm=warm)
            self.stats["solver_s"] += sol.solve_s
            self.stats["solve_times_s"].append(sol.solve_s)
            self.stats["iterations"] += 1
            if sol.status != win.STATUS_OPTIMAL:
                key = "lp_" + sol.status
                self.stats[key] = self.stats.get(key, 0) + 1
                if s_best is None:
                    return sol.status, None
                if s_lin is s_best:
                    # infeasible about the best verified plan itself: a smaller trust region
                    # only shrinks the feasible set further, so keep the verified plan
                    break
                s_lin = s_best
                continue
            s_new = np.minimum(sol.s_mm, s_max)
            ok = self._verify(s_new, s_max)[0]
            moved = float(np.max(np.abs(s_new - s_lin)))
            if ok:
                obj = self._objective(s_new)
                if obj >= best_obj:
                    s_best, best_obj = s_new, obj
                    status = "optimal"
                if moved < self.st.conv_tol_mm:
                    return "converged", s_best
                s_lin = s_new
                delta = min(2.0 * delta, delta_cap)
            else:
                # linearisation residue: step back towards the verified plan (line search on
                # the convex combination), else re-linearise at the new point
                stepped = False
                if s_best is not None:
                    for alpha in LINE_SEARCH:
                        s_a = s_best + alpha * (s_new - s_best)
                        if self._verify(s_a, s_max)[0] and self._objective(s_a) > best_obj:
                            s_best, best_obj = s_a, self._objective(s_a)
                            status = "optimal"
                            stepped = True
                            break
                if stepped:
                    s_lin = s_best
                elif moved < 4 * self.st.conv_tol_mm or s_best is not None:
                    delta *= 0.5
                    s_lin = s_best if s_best is not None else s_new
                else:
                    s_lin = s_new
                if delta < TRUST_MIN_MM_S * 0.25:
                    break
        if s_best is None:
            return "unverified", None
        if status == "optimal":
            self.stats["unconverged"] += 1
        return status, s_best

    def _elastic(self, s_start, s_bar, s_max):
        """Minimum-violation plan: the chance constraint with a penalised slack (HiGHS),
        within a trust region about s_bar (which must satisfy the kinematic limits)."""
        from scipy.optimize import linprog

        delta = self._trust0(s_start)
        w = self._window_data(s_start, s_bar, s_max, trust_v=delta)
        lp = win.build_lp(w)
        n = lp.c.size
        cont = lp.row_kind == 3
        m_c = int(cont.sum())
        # slack per contour row, in mm (the rows are in mm)
        S = np.zeros((lp.A.shape[0], m_c))
        S[np.flatnonzero(cont), np.arange(m_c)] = 1.0
        A_hi = np.hstack([lp.A, -S])
        A_lo = np.hstack([-lp.A, -S])
        fh, fl = np.isfinite(lp.hi), np.isfinite(lp.lo)
        c = np.concatenate([-lp.c, np.full(m_c, ELASTIC_WEIGHT * n / self.tol)])
        bounds = np.vstack([np.column_stack([lp.lb, lp.ub]),
                            np.column_stack([np.zeros(m_c), np.full(m_c, np.inf)])])
        t0 = time.perf_counter()
        res = linprog(c, A_ub=np.vstack([A_hi[fh], A_lo[fl]]),
                      b_ub=np.concatenate([lp.hi[fh], -lp.lo[fl]]), bounds=bounds,
                      method="highs-ds")
        self.stats["solver_s"] += time.perf_counter() - t0
        if res.status != 0:
            return None
        ds = np.clip(res.x[:n], lp.lb, lp.ub) * lp.ds_ref_mm
        s = np.minimum(s_start + np.cumsum(ds), s_max)
        _, _, acc_ratio, _, _ = self._verify(s, s_max)
        if acc_ratio > 1.0 + VERIFY_ACC_REL:
            return None
        return s

    def _commit(self, s_new: np.ndarray):
        cmd = self.geom.position(s_new)[:, :2]
        k0 = len(self.s_hist)
        self.s_hist.extend(float(v) for v in s_new)
        self.cmd_hist.extend(cmd)
        self.pred.commit(k0, cmd)
        if self.on_commit is not None:
            self.on_commit(k0, cmd)

    # -- public --------------------------------------------------------------------------
    def start(self, s0_mm: float = 0.0):
        self._commit(np.array([s0_mm]))

    def hold(self, n_samples: int):
        """Stand still for n samples (dwell at an exact stop)."""
        if n_samples > 0:
            self._commit(np.full(n_samples, self.s_hist[-1]))
            if self._prev is not None:
                self._prev = None

    def _size_horizon(self, s_start: float, s_max: float) -> None:
        """With the free plan: the braking stretch must stop from the fastest speed F has on
        the segments this horizon can reach, at their own per-move acceleration (a file's own
        M204 may be far below the profile's A_max: at 500 mm/s² a stretch sized for 3000 mm/s²
        caps every window at ~15 mm/s through the terminal condition)."""
        if self.free is None or self.st.n_brake is not None:
            return
        f = self.free
        nb = self._nb_default
        for _ in range(2):  # the reach depends on the stretch: settle it
            reach = self.vmax * self.ts * (self.st.n_window + nb)
            lo, hi = np.clip(self.geom.segment_at(np.array([s_start, min(s_start + reach, s_max)])),
                             0, f.seg_accel.size - 1)
            nb = max(self._nb_default,
                     int(math.ceil(float(np.max(f.stop_time_s[lo:hi + 1])) / self.ts)) + 2)
        self.n_brake = nb
        self.n = self.st.n_window + nb + self.st.n_hold

    def run_piece(self, s_max: float, max_windows: int | None = None):
        """Plan from the current (resting) position to s_max, ending at rest there.

        Long for a reason: one window's chain of decisions in the order docs/optimizer.md
        states it (the free plan, the LP, the fallback, the elastic LP, held, proceeding along
        F after a stall), with the state it carries from window to window (the previous
        horizon, the stall count)."""
        nw = self.st.n_window
        stall = 0
        windows = 0
        self._prev = None
        while True:
            s_start = self.s_hist[-1]
            if s_start >= s_max - 1e-9:
                # at the end of the piece: snap exactly, and wait until at rest (it is:
                # every accepted horizon ends at rest and s is capped at s_max)
                if s_start != s_max:
                    self.s_hist[-1] = s_max
                break
            windows += 1
            self._size_horizon(s_start, s_max)
            if self._prev is not None and self._prev.size - nw > self.n:
                # never cut the previous plan's tail (the fallback, which ends at rest)
                self.n = self._prev.size - nw
                self.n_brake = self.n - nw - self.st.n_hold
            n = self.n
            if max_windows is not None and windows > max_windows:
                raise RuntimeError("window budget exhausted")
            self.stats["windows"] += 1
            # reference plan: the previous horizon's continuation (it brakes to rest and was
            # verified), or rest at the start of a piece
            if self._prev is not None:
                tail = self._prev[nw:nw + n]
                s_ref = np.concatenate([tail, np.full(n - tail.size, tail[-1])])
            else:
                s_ref = np.full(n, s_start)
            s_ref = np.minimum(s_ref, s_max)
            v_last = self.s_hist[-1] - self.s_hist[-2] if len(self.s_hist) > 1 else 0.0
            accepted = verified = None
            if self.free is not None:
                incumbent = None
                cand, rest = self.free.greedy(s_start, v_last, nw, n, s_max)
                if rest:
                    # on F's orbit the go part is F itself and the tail brakes at the smallest
                    # per-move acceleration below F: only the chance constraint to check
                    vr = self._verify(cand, s_max, kinematic=not self.free.last_on_orbit)
                    if vr[0] and self.screen:
                        accepted, status, verified = cand, "free", vr
                    elif vr[0]:
                        incumbent = cand
                s_guess = np.maximum(cand, s_ref)
            else:
                s_guess = np.minimum(s_start + v_last * np.arange(1, n + 1), s_max)
                s_guess = np.maximum(s_guess, s_ref)
            if accepted is None:
                ref_ok = self._verify(s_ref, s_max)[0]
                status, accepted = self._solve(s_start, s_ref, s_max, ref_ok, s_guess,
                                               incumbent if self.free is not None else None)
            if accepted is not None and status == "continued":
                self.stats["fallback_windows"].append(len(self.s_hist))
                status = "fallback"
            if accepted is None:
                accepted = self._elastic(s_start, s_ref, s_max)
                self.stats["relaxed_windows"].append(len(self.s_hist))
                status = "relaxed"
                if accepted is None:
                    accepted = s_ref  # kinematically valid: a continuation or rest
                    status = "held"
            still = accepted[min(nw, accepted.size) - 1] <= s_start + 1e-12
            if self.free is not None and stall >= STALL_PROCEED and still:
                # standing still has not cured the chance constraint for STALL_PROCEED windows:
                # the predicted error is not the motion's (a learned disturbance larger than
                # the tolerance leaves room for). Proceed along the firmware's plan, as the
                # slow-down optimizer gives such samples up, and report the window as relaxed:
                # onto F's orbit and along it for the whole horizon (F itself stops at every
                # exact stop, so this needs no braking stretch to remain a valid plan).
                onto, _ = self.free.greedy(s_start, v_last, n, n, s_max)
                go = self._verify(onto, s_max, kinematic=True)
                if go[2] <= 1.0 + VERIFY_ACC_REL and onto[nw - 1] > s_start + 1e-12:
                    if status != "relaxed":
                        self.stats["relaxed_windows"].append(len(self.s_hist))
                    accepted, status, verified = onto, "relaxed", go
            self._count(status)
            if verified is None:
                accepted = np.maximum.accumulate(np.clip(accepted, s_start, s_max))
                verified = self._verify(accepted, s_max)
            ok, chance, acc_ratio, mu, sig = verified
            take = nw
            done = np.flatnonzero(accepted[:take] >= s_max - 1e-12)
            if done.size:
                take = int(done[0]) + 1  # at rest on the piece end: do not idle there
            if self.free is not None:
                self.stats["pred_on"].append(self.free.constrained(accepted[:take], s_start))
            self.stats["pred_mean_mm"].append(mu[:take])
            self.stats["pred_std_mm"].append(sig[:take])
            self.stats["pred_xy_mm"].append(self._last_mean[:, :take].T)
            self._prev = accepted
            progress = accepted[take - 1] - s_start
            stall = stall + 1 if progress <= 1e-12 else 0
            if stall > 50:
                raise win_error(len(self.s_hist), s_start)
            self._commit(accepted[:take])
        return self

    def result(self) -> MpcResult:
        st = self.stats
        info = {
            "windows": st["windows"], "solver_iterations": st["iterations"],
            "solver_s": st["solver_s"], "window_status": dict(st["status"]),
            "fallback_windows": len(st["fallback_windows"]),
            "relaxed_windows": len(st["relaxed_windows"]),
            "fallback_at_samples": st["fallback_windows"][:100],
            "unconverged_windows": st["unconverged"],
            "horizon_samples": self.n, "n_window": self.st.n_window, "n_brake": self.n_brake,
            "n_hold": self.st.n_hold,
            "lp_failed": st.get("lp_failed", 0), "lp_infeasible": st.get("lp_infeasible", 0),
            "_solve_times_s": list(st["solve_times_s"]),
        }
        if st["pred_mean_mm"]:
            info["_pred_mean_mm"] = np.concatenate(st["pred_mean_mm"])
            info["_pred_std_mm"] = np.concatenate(st["pred_std_mm"])
            info["_pred_xy_mm"] = np.concatenate(st["pred_xy_mm"])
            if st["pred_on"]:
                info["_pred_on"] = np.concatenate(st["pred_on"])
        return MpcResult(np.asarray(self.s_hist, float), info)


def win_error(k, s):
    return SolverError(f"sample {k} (s = {s:.3f} mm): no window plan found, not even with the "
                       "tolerance relaxed; raise --tolerance or check the machine profile")
