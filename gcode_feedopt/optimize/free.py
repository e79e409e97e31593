"""The free plan: what the firmware would do without the tolerance, as the optimizer's cap.

The kinematic plan F (plan.kinematic: feed cap, per-move acceleration that keeps every axis
within its limit, the firmware's junction speeds, exact stops) is the fastest motion the
firmware will execute at all: a written F above it is clipped by the firmware's own planner.
The receding-window optimizer therefore works *below* F (firmware-consistent constraints):

- speed cap along F's orbit: s_k ≤ Φ(s_{k−1}) with Φ(s) = S_F(T_F(s) + Ts), where S_F(t) is
  F's path position at time t and T_F(s) the time F leaves s. Φ is monotone, so every plan
  with this cap stays behind F (s_k ≤ F_k by induction) and F itself meets it with equality;
  the junction speeds and the feed caps of the firmware are in it;
- tangential acceleration |Δ²s_k| ≤ a_t Ts², a_t the per-move acceleration of the segments the
  sample touches (the firmware's trapezoid acceleration, per-axis limits included);
- the chance constraint on the contour error of extruding samples (travel moves deposit
  nothing; a file that never extrudes, e.g. a CNC job, constrains every sample).

Consequence (tested): where the chance constraint is slack, the optimizer's plan *is* F, so
a window whose greedy continuation along F is predicted within tolerance needs no LP solve —
the screening shortcut of issue 9 gives the same schedule as solving every window.
"""

from __future__ import annotations

import numpy as np

from ..plan.trapezoid import Trapezoids


def evaluate(tr: Trapezoids, s0_mm: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """F's path position at arbitrary times t (s), exact on the trapezoid phases."""
    t = np.asarray(t_s, float)
    n = s0_mm.size - 1
    if n == 0:
        return np.zeros_like(t)
    i = np.clip(np.searchsorted(tr.t0_s, t, side="right") - 1, 0, n - 1)
    tau = t - tr.t0_s[i]
    v0 = tr.v0_mm_s[i]
    a = tr.accel_mm_s2[i]
    ta = tr.t_acc_s[i]
    tc = tr.t_cru_s[i]
    td = tr.t_dec_s[i]
    vc = tr.vc_mm_s[i]
    L = s0_mm[i + 1] - s0_mm[i]
    s_acc = v0 * tau + 0.5 * a * tau * tau
    s_cru = tr.d_acc_mm[i] + vc * (tau - ta)
    t3 = tau - ta - tc
    s_dec = tr.d_acc_mm[i] + tr.d_cru_mm[i] + vc * t3 - 0.5 * a * t3 * t3
    s = np.where(tau < ta, s_acc, np.where(tau < ta + tc, s_cru,
                                           np.where(tau < ta + tc + td, s_dec, L)))
    s = np.where(tau < 0, 0.0, s)
    s = s0_mm[i] + np.clip(s, 0.0, L)
    return np.where(t >= tr.t0_s[-1], s0_mm[-1], s)


def ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flattened [lo_i, hi_i) integer ranges: (owner i of each element, element value)."""
    lo = np.asarray(lo, np.int64)
    cnt = np.maximum(np.asarray(hi, np.int64) - lo, 0)
    owner = np.repeat(np.arange(lo.size), cnt)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]]) if cnt.size else cnt
    val = np.arange(int(cnt.sum()), dtype=np.int64) - np.repeat(start - lo, cnt)
    return owner, val


class ContourRules:
    """Which samples' contour error is constrained, and the overshoot half-planes at sharp
    vertices, on a path (shared by the window optimizer and the slow-down optimizer).

    Attributes:
        extruding: (N,) bool, segments whose contour error is constrained (every segment when
            the file never extrudes, e.g. a CNC job).
        vertex_s, vertex_xy, vertex_u: (V,), (V, 2), (V, 2) path position, XY and incoming unit
            direction of every vertex where the path turns back by more than 90° next to a
            constrained segment (not at an exact stop), and of every end of an extrusion where
            the XY path does not go straight on (exact stop, Z lift, turn back).
    """

    def __init__(self, path):
        self.path = path
        ext = np.asarray(path.de_mm, float) > 1e-9
        self.extruding = ext if ext.any() else np.ones_like(ext)
        self._ext_cum = np.concatenate([[0], np.cumsum(self.extruding)])
        # vertices the actual position must not overshoot along the incoming direction:
        # - sharp ones (the path turns back by more than 90°) between moves, one of them
        #   constrained;
        # - ends of an extrusion where the XY path does not go straight on (an exact stop, a
        #   Z lift, a turn back into a travel): running past the end point still deposits
        t_beg, t_end = path.end_tangents()
        n = path.n_segments
        stop = np.asarray(path.stop_after, bool)
        u_in = t_end[:, :2]
        nin = np.linalg.norm(u_in, axis=1)
        u_out = np.vstack([t_beg[1:, :2], np.zeros((1, 2))])  # nothing after the last move
        nout = np.linalg.norm(u_out, axis=1)
        dot = np.sum(u_in * u_out, axis=1) / np.maximum(nin * nout, 1e-12)
        nxt_ext = np.concatenate([self.extruding[1:], [False]])
        sharp = (dot < 0.0) & (nin > 0.5) & (nout > 0.5) & (self.extruding | nxt_ext) & ~stop
        ends = self.extruding & (stop | ~nxt_ext) & (nin > 0.5) & \
            (stop | (nout <= 0.5) | (dot < 0.0))
        j = np.flatnonzero(sharp | ends)
        self.vertex_s = np.asarray(path.s0_mm, float)[j + 1]
        self.vertex_xy = np.asarray(path.end_mm, float)[j, :2]
        self.vertex_u = u_in[j] / np.maximum(nin[j], 1e-12)[:, None] if j.size else np.zeros((0, 2))

    def overshoot_rows(self, s_bar, on, reach_mm: float, tol_mm: float):
        """(k, u, b) half-planes u·x̃_k ≤ b = u·V + E_max for every horizon sample k (with
        ``on``) within ``reach_mm`` of a sharp vertex V along the path: the paper's contour
        error (the projection on the path normal at the commanded point) does not see the
        actual position running on past a near-reversal, the distance to the path does."""
        if self.vertex_s.size == 0:
            return np.zeros(0, int), np.zeros((0, 2)), np.zeros(0)
        s_bar = np.asarray(s_bar, float)
        lo = np.searchsorted(self.vertex_s, s_bar - reach_mm, side="left")
        hi = np.searchsorted(self.vertex_s, s_bar + reach_mm, side="right")
        cnt = np.where(on, hi - lo, 0)
        if cnt.sum() == 0:
            return np.zeros(0, int), np.zeros((0, 2)), np.zeros(0)
        kk = np.repeat(np.arange(s_bar.size), cnt)
        vi = np.concatenate([np.arange(a, b) for a, b, c in zip(lo, hi, cnt) if c])
        U = self.vertex_u[vi]
        V = self.vertex_xy[vi]
        # only where the command itself is not past the vertex (the path may lead on beyond
        # it, e.g. a zigzag: being there is then on the path)
        xy = self.path.position(s_bar[kk])[:, :2]
        keep = np.sum(U * (xy - V), axis=1) <= 1e-9
        kk, U, V = kk[keep], U[keep], V[keep]
        b = np.sum(U * V, axis=1) + tol_mm
        return kk, U, b

    def overshoot_pairs(self, s, on, reach_mm: float):
        """Every (sample k, sharp vertex) pair of :meth:`overshoot_rows`, vectorized for whole
        plans: (k (m,), u (m, 2), V (m, 2)); the row is u·(x̃_k − V) ≤ E_max."""
        if self.vertex_s.size == 0:
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
        s = np.asarray(s, float)
        lo = np.searchsorted(self.vertex_s, s - reach_mm, side="left")
        hi = np.searchsorted(self.vertex_s, s + reach_mm, side="right")
        hi = np.where(on, hi, lo)
        kk, vi = ranges(lo, hi)
        U, V = self.vertex_u[vi], self.vertex_xy[vi]
        xy = self.path.position(s[kk])[:, :2]
        keep = np.sum(U * (xy - V), axis=1) <= 1e-9
        return kk[keep], U[keep], V[keep]

    def constrained_pairs(self, s, s_prev, s_next=None) -> np.ndarray:
        """:meth:`constrained` with the samples before (and after) every sample given (whole
        plans evaluated in windows)."""
        s = np.asarray(s, float)
        on = self._covers_extrusion(np.asarray(s_prev, float), s)
        if s_next is not None:
            on |= self._covers_extrusion(s, np.asarray(s_next, float))
        return on

    def _covers_extrusion(self, s_a, s_b) -> np.ndarray:
        """bool per interval [s_a, s_b]: some segment it covers extrudes."""
        n = self.extruding.size
        b = np.clip(self.path.segment_at(s_b), 0, n - 1)
        a = np.minimum(np.clip(self.path.segment_at(s_a), 0, n - 1), b)
        return self._ext_cum[b + 1] - self._ext_cum[a] > 0

    def constrained(self, s, s_before: float | None = None) -> np.ndarray:
        """bool per sample: its contour error is constrained — some segment covered by the
        interval before it or the one after it extrudes (as the virtual machine's metric
        counts a sample: a 0.05 mm travel right after an extrusion still deposits, and the
        last travel sample before one is where the nozzle starts it). ``s_before``: the
        sample before s[0] (default s[0] itself); the last sample has no interval after."""
        s = np.asarray(s, float)
        if s.size == 0:
            return np.zeros(0, bool)
        prev = np.concatenate([[s[0] if s_before is None else s_before], s[:-1]])
        nxt = np.concatenate([s[1:], s[-1:]])
        return self.constrained_pairs(s, prev, nxt)


class FreePlan(ContourRules):
    """F of a path (a kinematic Schedule with its trapezoids) and the constraints it defines.

    Attributes:
        s_mm: (K,) F sampled at Ts. ts: Ts.
        seg_accel: (N,) per-segment tangential acceleration, mm/s².
        extruding, vertex_*: see ContourRules.
    """

    def __init__(self, path, schedule):
        super().__init__(path)
        self.tr: Trapezoids = schedule.info["trapezoids"]
        self.s_mm = np.asarray(schedule.s_mm, float)
        self.ts = float(schedule.ts_s)
        self.s0 = np.asarray(path.s0_mm, float)
        self.seg_accel = np.asarray(self.tr.accel_mm_s2, float)
        #: (N,) time F needs to stop from each segment's cruise speed at its acceleration, s
        self.stop_time_s = np.asarray(self.tr.vc_mm_s, float) / self.seg_accel

    # -- the orbit cap -------------------------------------------------------------------
    def depart_time(self, s) -> np.ndarray:
        """T_F(s): the time F leaves path position s (linear between samples), s."""
        s = np.asarray(s, float)
        sf = self.s_mm
        i = np.clip(np.searchsorted(sf, s, side="right") - 1, 0, sf.size - 2)
        lo, hi = sf[i], sf[i + 1]
        span = hi - lo
        frac = np.where(span > 0, (s - lo) / np.where(span > 0, span, 1.0), 0.0)
        return (i + np.clip(frac, 0.0, 1.0)) * self.ts

    def step_cap(self, s) -> np.ndarray:
        """Φ(s) − s: the largest increment of the next sample from s, mm (≥ 0)."""
        s = np.asarray(s, float)
        nxt = evaluate(self.tr, self.s0, self.depart_time(s) + self.ts)
        return np.maximum(nxt - s, 0.0)

    def accel(self, s_lo, s_hi, smallest: bool = False) -> np.ndarray:
        """Tangential acceleration limit of samples spanning [s_lo, s_hi]: the largest of the
        segments touched (F's own second difference across a junction uses both), or with
        ``smallest`` the smallest (safe whichever of them the sample ends up in), mm/s²."""
        n = self.seg_accel.size
        a = np.clip(self.path.segment_at(np.asarray(s_lo, float)), 0, n - 1)
        b = np.clip(self.path.segment_at(np.asarray(s_hi, float)), 0, n - 1)
        pick = np.minimum if smallest else np.maximum
        red = np.min if smallest else np.max
        out = pick(self.seg_accel[a], self.seg_accel[b])
        wide = b > a + 1
        if np.any(wide):
            for j in np.flatnonzero(wide):
                out[j] = float(red(self.seg_accel[a[j]:b[j] + 1]))
        return out

    def accel_min(self, s_lo: float, s_hi: float) -> float:
        """The smallest per-move acceleration on [s_lo, s_hi] (safe braking), mm/s²."""
        n = self.seg_accel.size
        a, b = np.clip(self.path.segment_at(np.array([s_lo, s_hi], float)), 0, n - 1)
        return float(np.min(self.seg_accel[a:b + 1]))

    # -- greedy continuation -----------------------------------------------------------------
    def greedy(self, s_prev: float, ds_prev: float, n_go: int, n_total: int, s_max: float):
        """The fastest continuation from (s_prev, last increment ds_prev): n_go samples as
        fast as the cap and the acceleration allow, then the hardest braking to rest, then
        held, n_total samples in all. Returns (s (n_total,), reached_rest).

        On F's orbit (the previous sample was on it too) the go part is F itself, shifted
        in time (one vectorized evaluation); below it, a sample-by-sample loop."""
        ts = self.ts
        ts2 = ts * ts
        T0 = float(self.depart_time(np.array([s_prev]))[0])
        # on the orbit when F, one sample before leaving s_prev, was where we were one sample
        # ago (at rest after a stop of ours while F moves on, we are not)
        back = float(evaluate(self.tr, self.s0, np.array([T0 - ts]))[0])
        go = None
        self.last_on_orbit = abs(back - (s_prev - ds_prev)) <= 1e-9 * max(1.0, abs(s_prev))
        if self.last_on_orbit:
            go = evaluate(self.tr, self.s0, T0 + ts * np.arange(1, n_go + 1))
            # F is at rest on every exact stop, so a piece end inside is reached at rest
            go = np.maximum.accumulate(np.minimum(go, s_max))
        if go is None:
            go = np.empty(n_go)
            s, ds = float(s_prev), float(ds_prev)
            for k in range(n_go):
                cap = float(self.step_cap(np.array([s]))[0])
                # off the orbit: safe whichever segment the sample lands in (as the LP)
                a = float(self.accel(np.array([s - ds]), np.array([s + cap]), smallest=True)[0])
                new = min(cap, ds + a * ts2, s_max - s)
                # never brake harder than the acceleration allows (above F after an LP
                # window, the cap may fall faster than we can slow down: verification decides);
                # the braking is on the segments being left, as F's own (the largest touched)
                a_brk = float(self.accel(np.array([s - ds]), np.array([s + ds]))[0])
                new = max(new, min(ds - a_brk * ts2, s_max - s), 0.0)
                s, ds = s + new, new
                go[k] = s
        out = np.empty(n_total)
        out[:n_go] = go
        s = float(go[-1]) if n_go else float(s_prev)
        ds = float(go[-1] - (go[-2] if n_go > 1 else s_prev)) if n_go else float(ds_prev)
        n_b = n_total - n_go
        if n_b <= 0:
            return out, ds <= 0.0
        if ds <= 0.0:
            out[n_go:] = s
            return out, True
        # brake at the smallest per-move acceleration over the stopping distance
        a = self.accel_min(s - ds, min(s + ds * ds / (2 * self.seg_accel.min() * ts2) + 2 * ds, s_max))
        steps = ds - a * ts2 * np.arange(1, n_b + 1)
        steps = np.maximum(steps, 0.0)
        tail = s + np.cumsum(steps)
        prev = np.concatenate([[s], tail[:-1]])
        ok = np.all(steps <= self.step_cap(prev) + 1e-12) and tail[-1] <= s_max + 1e-12
        if not ok:
            tail = np.empty(n_b)
            for k in range(n_b):
                if ds > 0.0:
                    cap = float(self.step_cap(np.array([s]))[0])
                    new = max(0.0, min(ds - a * ts2, cap, s_max - s))
                    s, ds = s + new, new
                tail[k] = s
        out[n_go:] = tail
        return out, bool(out[-1] - out[-2] <= 0.0) if n_total > 1 else True
