"""The window problem of the receding-window optimizer (paper Section 4, Appendix C): pure.

Decision: the path increments Δs_k = s_k − s_{k−1} (mm) at the n samples of the *horizon*
(the committed window, then a planned braking stretch, then samples held at standstill, so
the vibration that outlives the window is still constrained and the plan always ends at
rest; see mpc.py). Variables are scaled, w_k = Δs_k / ds_ref_mm, so they are O(1).

The path is linearised about the previous plan s̄ (paper Eq. 22):
    x_d(k) = x̄_d(k) + t̄(k) · (s_k − s̄_k),      t̄ = dx/ds at s̄ (unit tangent),
and the predicted tracking error of each axis is affine in that axis's commands (Eq. 25,
ε_a = x_d,a − x̃_a with x̃_a = Φ_c x_d + Φ_p x_c,past):
    ε_a = ε̄_a + E_a (x_d,a − x̄_d,a).
The contour error μ_ε = n · ε (n the unit normal, Eq. 6) and its std σ_ε (Eq. 21) enter the
chance constraint on both signs (Eq. 27):
    ±μ_ε(t) + z σ_ε(t) ≤ E_max,      z = Φ⁻¹(η);
σ_ε is taken at the linearisation point, optionally with its first-order change
(Appendix C) ``dsigma``; the re-linearisation loop of mpc.py makes the two agree.

Constraints, all linear in Δs:
- 0 ≤ Δs_k ≤ ds_max_k (monotonicity and feed cap; ds_max = 0 on held samples);
- s_start + Σ Δs ≤ s_max (never past the end of the known path / the next exact stop);
- |x_d,a(k) − 2 x_d,a(k−1) + x_d,a(k−2)| ≤ A_a Ts² per axis (the previous window's last
  commands enter for k < 2: continuity of position, velocity and acceleration);
- optionally |third difference| ≤ J_a Ts³;
- the chance constraint above.
Objective: max Σ_k s_k (paper: max 1ᵀp).

Solvers (chosen by measurement, see docs/optimizer.md): HiGHS (dual simplex, exact LP) and
OSQP (ADMM, with a tiny quadratic term ``OSQP_RHO_QUAD`` that makes the LP strictly convex;
warm-started and updated in place when the sparsity pattern is unchanged).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

#: OSQP cannot converge on a degenerate LP in bounded iterations; a quadratic term this small
#: (relative to the O(1) linear objective on O(1) scaled variables) changes Σs by < 1e-5 of a
#: sample's progress while making the solution unique.
OSQP_RHO_QUAD = 1e-4
#: OSQP tolerances (scaled units: 1 = one sample at full feed).
OSQP_EPS = 1e-6
OSQP_MAX_ITER = 20000
#: Violation of the linear constraints accepted from a solution, relative to each row's bound
#: scale (solver tolerance, not a physical margin).
FEAS_TOL = 1e-6

STATUS_OPTIMAL = "optimal"
STATUS_INFEASIBLE = "infeasible"
STATUS_FAILED = "failed"


@dataclass(frozen=True)
class WindowData:
    """One window problem, all arrays over the horizon of n samples.

    Attributes:
        ts_s: sample period, s.
        s_start_mm: path position at the last committed sample (before the horizon), mm.
        s_bar_mm: (n,) linearisation point of s, mm.
        pos_bar_mm: (n, 2) path XY at s_bar, mm.
        tan_bar: (n, 2) dXY/ds at s_bar (unit tangent), 1.
        past_cmd_mm: (3, 2) XY commands at the three samples before the horizon, oldest
            first, mm (continuity of acceleration and jerk).
        s_max_mm: the horizon never goes past this path position, mm.
        ds_max_mm: (n,) per-sample upper bound on Δs (feed cap × Ts; 0 = held), mm.
        amax_mm_s2: (2,) per-axis acceleration limit, mm/s².
        tol_mm: E_max, mm.
        z: Φ⁻¹(η), 1.
        err_bar_mm: (2, n) predicted tracking error of X and Y at the linearisation point, mm.
        err_jac: (2, n, n) dε_a(t)/dx_d,a(k) (causal: lower triangular), 1.
        normal: (n, 2) unit normal of the path at s_bar.
        sigma_mm: (n,) std of the predicted contour error at the linearisation point, mm.
        dsigma: optional (2, n, n), dσ_ε(t)/dx_d,a(k), 1/1 (Appendix C linearisation).
        jmax_mm_s3: optional (2,) per-axis jerk limit, mm/s³.
        contour_rows: bool (n,) samples whose contour error is constrained (default all).
        trust_mm: optional trust region |s_k − s̄_k| ≤ trust_mm (the linearisation of a
            curved path is good only near s̄; mpc.py adapts it).
        trust_v_mm_s: optional speed trust region |Δs_k − Δs̄_k| ≤ trust_v·Ts: the tangent
            linearisation misses κ·(ṡ − ṡ̄)² of acceleration, so bounding the speed change
            bounds the acceleration (and contour) residue; plain variable bounds, no rows.
        acc_t_mm_s2: optional (n,) tangential acceleration limits |Δs_k − Δs_{k−1}| ≤
            a_k Ts² (the firmware's per-move acceleration; optimize/free.py). With it,
            ``amax_mm_s2`` may be None (no per-axis rows: junctions are in ``ds_max_mm``).
        past_ds_mm: the last committed increment Δs_{−1}, mm (continuity of speed).
        cap_next_mm, cap_slope: optional (n,) orbit cap s_k ≤ Φ(s_{k−1}) linearised at
            s̄_{k−1}: Φ̄_k = Φ(s̄_{k−1}) and φ_k = Φ'(s̄_{k−1}) (optimize/free.py); rows
            s_k − φ_k s_{k−1} ≤ Φ̄_k − φ_k s̄_{k−1} (the first one, s_{−1} = s_start, exact).
        halfplanes: optional (k (m,), u (m, 2), b (m,)): chance rows on the predicted actual
            position itself, u·x̃_k + z σ_u ≤ b (overshoot past a sharp vertex, mpc.py), with
            ``std_xy_mm`` (2, n) the per-axis std at the linearisation point.
    """

    ts_s: float
    s_start_mm: float
    s_bar_mm: np.ndarray
    pos_bar_mm: np.ndarray
    tan_bar: np.ndarray
    past_cmd_mm: np.ndarray
    s_max_mm: float
    ds_max_mm: np.ndarray
    amax_mm_s2: np.ndarray | None
    tol_mm: float
    z: float
    err_bar_mm: np.ndarray
    err_jac: np.ndarray
    normal: np.ndarray
    sigma_mm: np.ndarray
    dsigma: np.ndarray | None = None
    jmax_mm_s3: np.ndarray | None = None
    contour_rows: np.ndarray | None = None
    trust_mm: float | None = None
    trust_v_mm_s: float | None = None
    acc_t_mm_s2: np.ndarray | None = None
    past_ds_mm: float = 0.0
    cap_next_mm: np.ndarray | None = None
    cap_slope: np.ndarray | None = None
    halfplanes: tuple | None = None
    std_xy_mm: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.s_bar_mm.size)


@dataclass(frozen=True)
class WindowSolution:
    """Result of one window solve.

    Attributes:
        status: ``optimal`` | ``infeasible`` | ``failed``.
        ds_mm: (n,) increments (zeros unless optimal), mm.
        s_mm: (n,) s_start + cumsum(ds), mm.
        solve_s: wall time in the solver, s.
        solver: ``highs`` | ``osqp``.
        iterations: solver iterations.
        max_violation: worst violation of the linear constraints by the returned point, in
            each row's own units (mm for positions; scaled by Ts² for accelerations).
    """

    status: str
    ds_mm: np.ndarray
    s_mm: np.ndarray
    solve_s: float
    solver: str
    iterations: int = 0
    max_violation: float = 0.0
    info: dict = field(default_factory=dict)


@dataclass(frozen=True)
class LinearProgram:
    """max cᵀw s.t. lo ≤ A w ≤ hi, lb ≤ w ≤ ub, in scaled variables w = Δs / ds_ref_mm.

    ``A`` is a dense (m, n) array with a fixed lower-triangular block pattern for a given
    (n, jerk, dsigma) so OSQP can update it in place between windows."""

    c: np.ndarray
    A: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    ds_ref_mm: float
    row_kind: np.ndarray  # (m,) int: 0 path end, 1 accel, 2 jerk, 3 contour, 4 trust, 5 cap,
    #                       6 overshoot half-plane
    row_sample: np.ndarray  # (m,) int: horizon sample of the row (its last nonzero column)

    def pattern(self) -> np.ndarray:
        """(m, n) bool structural pattern: row r may be nonzero in columns ≤ row_sample[r]."""
        n = self.c.size
        return np.arange(n)[None, :] <= self.row_sample[:, None]


def _diff_rows(tan: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the ``order``-th backward difference of x_d(k) = c_k + tan_k · (s_k − s̄_k)
    as a function of Δs (through s = s_start + L Δs): returns the (n, n) matrix acting on Δs
    (lower triangular) and the (n, order) weights of the ``order`` commands before the
    horizon (most recent last)."""
    n = tan.size
    coef = {1: (1.0, -1.0), 2: (1.0, -2.0, 1.0), 3: (1.0, -3.0, 3.0, -1.0)}[order]
    # D acting on the vector s (n,): (D s)_k = Σ_j coef_j · tan_{k−j} s_{k−j} for k−j ≥ 0
    D = np.zeros((n, n))
    for j, cj in enumerate(coef):
        idx = np.arange(j, n)
        D[idx, idx - j] += cj * tan[idx - j]
    past_w = np.zeros((n, order))
    for j, cj in enumerate(coef):
        for k in range(min(j, n)):
            # sample k − j < 0 is past sample index (order + k − j) in a (order,) history
            past_w[k, order + k - j] += cj
    # s = s_start + L Δs  ->  D s = D 1 s_start + (D L) Δs
    DL = np.cumsum(D[:, ::-1], axis=1)[:, ::-1]  # D @ L with L lower-triangular ones
    return DL, past_w


def build_lp(w: WindowData) -> LinearProgram:
    """Assemble the window LP (see the module docstring) in scaled variables.

    Long for a reason: the constraint blocks in the module docstring's order (path end,
    velocity, acceleration, the chance bound's two sides, the terminal rest), each a few
    lines over the same cumulative-sum operator L and scaling; split apart they would pass
    the same eight arrays to each piece."""
    n = w.n
    ts = w.ts_s
    ds_ref = max(float(np.max(w.ds_max_mm)), 1e-9)
    L = np.tril(np.ones((n, n)))
    s_off = w.s_start_mm - w.s_bar_mm  # x_d − x̄_d = tan (s_off + L Δs)
    rows, lo, hi, kinds = [], [], [], []

    # path end: s_start + Σ Δs ≤ s_max (Δs ≥ 0 makes every earlier partial sum smaller)
    rows.append(np.ones((1, n)) * ds_ref)
    lo.append(np.array([-np.inf]))
    hi.append(np.array([w.s_max_mm - w.s_start_mm]))
    kinds.append(np.zeros(1, int))
    samples = [np.array([n - 1])]

    for order, lim, kind in ((2, w.amax_mm_s2, 1), (3, w.jmax_mm_s3, 2)):
        if lim is None:
            continue
        for a in range(2):
            tan = w.tan_bar[:, a]
            DL, past_w = _diff_rows(tan, order)
            # constant part: D applied to (x̄_d − tan s̄ + tan s_start), plus the past commands
            base = w.pos_bar_mm[:, a] + tan * s_off
            coef = {2: (1.0, -2.0, 1.0), 3: (1.0, -3.0, 3.0, -1.0)}[order]
            const = np.zeros(n)
            for j, cj in enumerate(coef):
                const[j:] += cj * base[: n - j]
            const += past_w @ w.past_cmd_mm[3 - order:, a]
            bound = float(lim[a]) * ts ** order
            rows.append(DL * ds_ref)
            lo.append(-bound - const)
            hi.append(bound - const)
            kinds.append(np.full(n, kind))
            samples.append(np.arange(n))

    if w.acc_t_mm_s2 is not None:
        b = np.asarray(w.acc_t_mm_s2, float) * ts * ts
        D = (np.eye(n) - np.eye(n, k=-1)) * ds_ref
        past = np.zeros(n)
        past[0] = w.past_ds_mm
        rows.append(D)
        lo.append(past - b)
        hi.append(past + b)
        kinds.append(np.full(n, 1))
        samples.append(np.arange(n))

    if w.cap_next_mm is not None:
        phi = np.asarray(w.cap_slope, float)
        s_prev_bar = np.concatenate([[w.s_start_mm], w.s_bar_mm[:-1]])
        R = L.copy()
        R[np.tril_indices(n, -1)] = 0.0
        # Σ_{j<k} (1 − φ_k) Δs_j + Δs_k
        R += np.tril(np.ones((n, n)), -1) * (1.0 - phi)[:, None]
        rhs = np.asarray(w.cap_next_mm, float) - w.s_start_mm - phi * (s_prev_bar - w.s_start_mm)
        rows.append(R * ds_ref)
        lo.append(np.full(n, -np.inf))
        hi.append(rhs)
        kinds.append(np.full(n, 5))
        samples.append(np.arange(n))

    if w.trust_mm is not None:
        rows.append(L * ds_ref)
        lo.append(w.s_bar_mm - w.s_start_mm - w.trust_mm)
        hi.append(w.s_bar_mm - w.s_start_mm + w.trust_mm)
        kinds.append(np.full(n, 4))
        samples.append(np.arange(n))

    # chance constraint: μ = μ0 + Mμ Δs (and σ = σ0 + Mσ Δs with dsigma)
    mask = np.ones(n, bool) if w.contour_rows is None else np.asarray(w.contour_rows, bool)
    mu0 = np.zeros(n)
    Mmu = np.zeros((n, n))
    for a in range(2):
        tan = w.tan_bar[:, a]
        J = w.err_jac[a]
        mu0 += w.normal[:, a] * (w.err_bar_mm[a] + J @ (tan * s_off))
        Mmu += w.normal[:, a][:, None] * ((J * tan[None, :]) @ L)
    cap = w.tol_mm - w.z * w.sigma_mm
    if w.dsigma is None:
        rows.append(Mmu[mask] * ds_ref)
        lo.append(-cap[mask] - mu0[mask])
        hi.append(cap[mask] - mu0[mask])
        kinds.append(np.full(int(mask.sum()), 3))
        samples.append(np.flatnonzero(mask))
    else:
        Msig = np.zeros((n, n))
        sig0 = np.zeros(n)
        for a in range(2):
            tan = w.tan_bar[:, a]
            Msig += (w.dsigma[a] * tan[None, :]) @ L
            sig0 += w.dsigma[a] @ (tan * s_off)
        for sgn in (1.0, -1.0):
            rows.append((sgn * Mmu + w.z * Msig)[mask] * ds_ref)
            lo.append(np.full(int(mask.sum()), -np.inf))
            hi.append((cap - sgn * mu0 - w.z * sig0)[mask])
            kinds.append(np.full(int(mask.sum()), 3))
            samples.append(np.flatnonzero(mask))

    if w.halfplanes is not None and len(w.halfplanes[0]):
        kk, U, b = w.halfplanes
        kk = np.asarray(kk, int)
        R = np.zeros((kk.size, n))
        const = np.zeros(kk.size)
        sig_u = np.zeros(kk.size)
        for a in range(2):
            tan = w.tan_bar[:, a]
            J = w.err_jac[a]
            # x̃_a = x_d,a − ε_a, both affine in Δs through s = s_start + L Δs
            xt0 = w.pos_bar_mm[:, a] + tan * s_off - (w.err_bar_mm[a] + J @ (tan * s_off))
            Xt = tan[:, None] * L - (J * tan[None, :]) @ L
            R += U[:, a][:, None] * Xt[kk]
            const += U[:, a] * xt0[kk]
            sig_u += (U[:, a] * w.std_xy_mm[a][kk]) ** 2
        rows.append(R * ds_ref)
        lo.append(np.full(kk.size, -np.inf))
        hi.append(b - w.z * np.sqrt(sig_u) - const)
        kinds.append(np.full(kk.size, 6))
        samples.append(kk)

    c = (n - np.arange(n)) / n  # Σ_k s_k = const + Σ_i (n − i) Δs_i
    lb = np.zeros(n)
    ub = np.asarray(w.ds_max_mm, float).copy()
    if w.trust_v_mm_s is not None:
        ds_bar = np.diff(np.concatenate([[w.s_start_mm], w.s_bar_mm]))
        step = w.trust_v_mm_s * ts
        lb = np.minimum(np.maximum(lb, ds_bar - step), ub)
        ub = np.maximum(np.minimum(ub, ds_bar + step), lb)
    return LinearProgram(c=c, A=np.vstack(rows), lo=np.concatenate(lo), hi=np.concatenate(hi),
                         lb=lb / ds_ref, ub=ub / ds_ref,
                         ds_ref_mm=ds_ref, row_kind=np.concatenate(kinds),
                         row_sample=np.concatenate(samples))


def violation(lp: LinearProgram, x: np.ndarray) -> float:
    """Worst violation of the rows and bounds by x (scaled units)."""
    Ax = lp.A @ x
    v = max(float(np.max(lp.lo - Ax, initial=0.0)), float(np.max(Ax - lp.hi, initial=0.0)))
    v = max(v, float(np.max(lp.lb - x, initial=0.0)), float(np.max(x - lp.ub, initial=0.0)))
    return v


_HIGHS = None
_BASIS = None


def _highs():
    """A reusable quiet highspy.Highs (simplex), or None when highspy is not installed."""
    global _HIGHS
    if _HIGHS is None:
        try:
            import highspy
        except ImportError:  # pragma: no cover - highspy is a dependency
            _HIGHS = False
            return None
        # HiGHS prints its banner to the process's stdout while it is constructed, before
        # output_flag can be set: stdout is ours (``-o -``, tables), so the banner goes nowhere
        sys.stdout.flush()
        saved = os.dup(1)
        try:
            with open(os.devnull, "wb") as null:
                os.dup2(null.fileno(), 1)
                h = highspy.Highs()
                h.setOptionValue("output_flag", False)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        h.setOptionValue("solver", "simplex")
        _HIGHS = h
    return _HIGHS or None


def solve_highs(lp: LinearProgram):
    """HiGHS dual simplex. Returns (status, w, iters).

    Through highspy (HiGHS's own binding) with one reused instance: on these 60–130-column
    LPs scipy's linprog wrapper (option checks, conversions) costs twice the solve itself
    (benchmarks/bench_window_solvers.py: 1.0 vs 2.9 ms per LP, same optima); linprog stays
    as the fallback when highspy is missing."""
    h = _highs()
    if h is not None:
        import highspy

        inf = highspy.kHighsInf
        A = sp.csc_matrix(lp.A)
        m = highspy.HighsLp()
        m.num_col_ = lp.c.size
        m.num_row_ = A.shape[0]
        m.col_cost_ = -lp.c
        m.col_lower_ = lp.lb
        m.col_upper_ = lp.ub
        m.row_lower_ = np.where(np.isfinite(lp.lo), lp.lo, -inf)
        m.row_upper_ = np.where(np.isfinite(lp.hi), lp.hi, inf)
        m.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        m.a_matrix_.start_ = A.indptr
        m.a_matrix_.index_ = A.indices
        m.a_matrix_.value_ = A.data
        h.passModel(m)
        global _BASIS
        if _BASIS is not None and _BASIS[0] == (m.num_col_, m.num_row_):
            # warm start from the previous LP's basis (the next sequential-LP iteration or
            # window has the same structure): half the simplex iterations, same optima
            h.setBasis(_BASIS[1])
        h.run()
        st = h.getModelStatus()
        _BASIS = ((m.num_col_, m.num_row_), h.getBasis()) if st == highspy.HighsModelStatus.kOptimal \
            else None
        it = int(h.getInfo().simplex_iteration_count)
        if st == highspy.HighsModelStatus.kOptimal:
            return STATUS_OPTIMAL, np.array(h.getSolution().col_value), it
        if st == highspy.HighsModelStatus.kInfeasible:
            return STATUS_INFEASIBLE, None, it
        return STATUS_FAILED, None, it
    return solve_linprog(lp)


def solve_linprog(lp: LinearProgram):
    """HiGHS dual simplex through scipy.optimize.linprog. Returns (status, w, iters)."""
    from scipy.optimize import linprog

    fin_hi = np.isfinite(lp.hi)
    fin_lo = np.isfinite(lp.lo)
    A_ub = np.vstack([lp.A[fin_hi], -lp.A[fin_lo]])
    b_ub = np.concatenate([lp.hi[fin_hi], -lp.lo[fin_lo]])
    res = linprog(-lp.c, A_ub=A_ub, b_ub=b_ub, bounds=np.column_stack([lp.lb, lp.ub]),
                  method="highs-ds")
    if res.status == 0:
        return STATUS_OPTIMAL, res.x, int(getattr(res, "nit", 0))
    if res.status == 2:
        return STATUS_INFEASIBLE, None, int(getattr(res, "nit", 0))
    return STATUS_FAILED, None, int(getattr(res, "nit", 0))


def _osqp_major() -> int:
    import osqp

    return int(str(getattr(osqp, "__version__", "0")).split(".")[0] or 0)


def _osqp_flags() -> dict:
    """Solution polishing and warm starts on, under OSQP's names of the installed version
    (1.0 renamed them to polishing / warm_starting and deprecated the old ones)."""
    if _osqp_major() >= 1:
        return {"polishing": True, "warm_starting": True}
    return {"polish": True, "warm_start": True}


class OsqpWindowSolver:
    """OSQP on the window LP plus ``OSQP_RHO_QUAD``·||w||²/2, kept between windows: when the
    problem has the same shape the matrices are updated in place and the previous solution
    (shifted by the caller's choice) warm-starts the next solve."""

    def __init__(self):
        self._prob = None
        self._shape = None

    def solve(self, lp: LinearProgram, warm: np.ndarray | None = None):
        import osqp

        n = lp.c.size
        # bounds become identity rows (OSQP has no variable bounds)
        A = np.vstack([lp.A, np.eye(n)])
        lo = np.concatenate([lp.lo, lp.lb])
        hi = np.concatenate([lp.hi, lp.ub])
        lo = np.where(np.isfinite(lo), lo, -1e30)
        hi = np.where(np.isfinite(hi), hi, 1e30)
        # fixed structural pattern (lower-triangular blocks stored in full, explicit zeros
        # kept) so the next window of the same shape is an in-place update, not a new setup
        pattern = np.vstack([lp.pattern(), np.eye(n, dtype=bool)])
        r, cidx = np.nonzero(pattern)
        Acsc = sp.csc_matrix((A[r, cidx], (r, cidx)), shape=A.shape)
        Acsc.sort_indices()
        P = sp.csc_matrix(OSQP_RHO_QUAD * np.eye(n))
        q = -lp.c
        shape = (A.shape, Acsc.nnz)
        same = (self._prob is not None and self._shape == shape
                and np.array_equal(self._pattern, pattern))
        if same:
            self._prob.update(q=q, l=lo, u=hi, Ax=Acsc.data)
        else:
            self._prob = osqp.OSQP()
            self._prob.setup(P=sp.triu(P, format="csc"), q=q, A=Acsc, l=lo, u=hi,
                             eps_abs=OSQP_EPS, eps_rel=OSQP_EPS, max_iter=OSQP_MAX_ITER,
                             verbose=False, **_osqp_flags())
            self._shape = shape
            self._pattern = pattern
        if warm is not None:
            self._prob.warm_start(x=warm)
        res = self._prob.solve(**({"raise_error": False} if _osqp_major() >= 1 else {}))
        status = res.info.status
        if status in ("solved", "solved inaccurate"):
            return STATUS_OPTIMAL, res.x, int(res.info.iter)
        if "infeasible" in status:
            return STATUS_INFEASIBLE, None, int(res.info.iter)
        return STATUS_FAILED, None, int(res.info.iter)


def solve_window(w: WindowData, *, solver: str = "highs", osqp_solver: OsqpWindowSolver | None = None,
                 warm_ds_mm: np.ndarray | None = None) -> WindowSolution:
    """Solve one window problem.

    Args:
        w: the problem.
        solver: ``highs`` or ``osqp``.
        osqp_solver: a persistent OsqpWindowSolver (updates in place between windows).
        warm_ds_mm: (n,) warm start for OSQP, mm.

    Returns:
        WindowSolution; ``status`` is never silently ignored by the caller (mpc.py falls
        back to a safe plan on anything but ``optimal``).
    """
    lp = build_lp(w)
    t0 = time.perf_counter()
    if solver == "highs":
        status, x, it = solve_highs(lp)
    elif solver == "osqp":
        slv = osqp_solver or OsqpWindowSolver()
        warm = None if warm_ds_mm is None else np.asarray(warm_ds_mm) / lp.ds_ref_mm
        status, x, it = slv.solve(lp, warm)
    else:
        raise ValueError(f"unknown solver {solver!r}; use 'highs' or 'osqp'")
    dt = time.perf_counter() - t0
    n = w.n
    if status != STATUS_OPTIMAL:
        return WindowSolution(status, np.zeros(n), np.full(n, w.s_start_mm), dt, solver, it)
    x = np.clip(x, lp.lb, lp.ub)
    viol = violation(lp, x)
    scale = max(1.0, float(np.max(np.abs(lp.hi[np.isfinite(lp.hi)]), initial=1.0)))
    if viol > FEAS_TOL * scale + 1e-9:
        # an "optimal" point that breaks the rows (OSQP at max_iter): not accepted
        if solver == "osqp":
            return WindowSolution(STATUS_FAILED, np.zeros(n), np.full(n, w.s_start_mm), dt,
                                  solver, it, viol)
    ds = x * lp.ds_ref_mm
    return WindowSolution(STATUS_OPTIMAL, ds, w.s_start_mm + np.cumsum(ds), dt, solver, it, viol)


def predicted_contour(w: WindowData, ds_mm: np.ndarray):
    """Linearised predicted contour-error mean and std (n,) for increments ds_mm (mm)."""
    n = w.n
    s = w.s_start_mm + np.cumsum(ds_mm)
    dx = w.tan_bar * (s - w.s_bar_mm)[:, None]
    mu = np.zeros(n)
    sig = np.array(w.sigma_mm, float)
    for a in range(2):
        mu += w.normal[:, a] * (w.err_bar_mm[a] + w.err_jac[a] @ dx[:, a])
        if w.dsigma is not None:
            sig = sig + w.dsigma[a] @ dx[:, a]
    return mu, sig
