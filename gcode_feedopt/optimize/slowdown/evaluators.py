"""The slow-down's evaluators: the chance bound of sampled plans with the offline twin, or
with the virtual machine's own plant for the oracle (step 3 of the slow-down,
optimize.slowdown)."""

from __future__ import annotations

import numpy as np

from ...firmware.shaper import reach as shaper_reach, shape_axes
from ...vm.metrics import CONTOUR_WINDOW_S, distance_to_polyline_window
from ...vm.plant import simulate_axes
from ..mpc import _normals
from ..predictors import predict_trajectory

#: samples whose |command − predicted position| + zσ exceeds this fraction of E_max get the
#: distance to the path instead of the projection (below it the distance cannot break E_max)
DISTANCE_CHECK = 0.999


class TwinEvaluator:
    """The chance bound of sampled plans with the offline twin (TwinPredictor's prior)."""

    def __init__(self, tp, rules, *, z: float, tol_mm: float, overshoot_reach_mm: float,
                 ts_s: float = 0.002, offsets=None, shapers=None):
        self.tp = tp
        self.rules = rules
        self.ts_s = float(ts_s)
        self.z = float(z)
        self.tol = float(tol_mm)
        self.reach = float(overshoot_reach_mm)
        self.seg_tol = None
        #: the firmware's input shapers {"x"|"y": Shaper}: the twin's input is the shaped
        #: plan, whose sample k looks ``lead`` samples ahead and ``lag`` behind
        self.shapers = dict(shapers or {})
        self.lead, lag = shaper_reach(self.shapers, self.ts_s)
        #: samples of history that make a window's prediction exact (the twin's memory)
        self.memory = max(h.size for h in tp.h) + tp.maxlag + 1 + lag
        #: (function cmd (K, 2) -> (K, 2) mm, its memory) of the profile's extensions that
        #: add to the mean (twin.extensions.motion_offsets), or None
        self.offsets = None
        if offsets is not None:
            self.offsets = offsets[0]
            self.memory = max(self.memory, int(offsets[1]) + 1 + lag)

    def machine_input(self, cmd_xy: np.ndarray, ref_xy, segments=None):
        """(the motion the machine receives, the references of its windows): the plan
        shaped window by window (``segments``: the windows' first rows in ``cmd_xy``). A
        window predicted from its own first command (``ref_xy`` per sample) starts from its
        first shaped sample, the rest it is taken to start from; one reference for all (the
        plan's first point, at rest) stays."""
        if not self.shapers:
            return cmd_xy, ref_xy
        cmd_in = shape_axes(cmd_xy, self.ts_s, self.shapers, segments=segments)
        ref = np.asarray(ref_xy, float)
        if ref.ndim == 2:
            first = np.zeros(cmd_xy.shape[0], np.int64)
            if segments is not None:
                first[np.asarray(segments, np.int64)] = np.asarray(segments, np.int64)
                first = np.maximum.accumulate(first)
            ref = ref + (cmd_in - cmd_xy)[first]
        return cmd_in, ref

    def predict(self, cmd_xy: np.ndarray, ref_xy: np.ndarray, segments=None):
        cmd_in, ref = self.machine_input(cmd_xy, ref_xy, segments)
        mean, std = predict_trajectory(self.tp, cmd_in, ref=ref)
        if self.offsets is not None:
            mean = mean + self.offsets(cmd_in).T
        return mean, std

    def set_feature_tolerance(self, path, seg_tol_mm: np.ndarray) -> None:
        """Per-feature tolerance: (N,) E_max of each segment of ``path`` (inf: no contour
        constraint). ``self.tol`` stays the scalar (the tightest finite one) used where one
        number is needed (which samples get the exact distance)."""
        self.path = path
        self.seg_tol = np.asarray(seg_tol_mm, float)

    def tol_at(self, s: np.ndarray):
        """E_max of samples at arc length ``s``: the scalar, or each one's segment's."""
        if self.seg_tol is None:
            return self.tol
        return self.seg_tol[self.path.segment_at(s)]

    def geometry(self, path, s: np.ndarray, s_prev: np.ndarray,
                 s_next: np.ndarray | None = None) -> dict:
        """What the bound needs of sampled plans that does not depend on the prediction:
        commanded XY ``cmd`` (K, 2), unit normals ``nrm`` (K, 2), constrained samples ``on``
        (K,), and the overshoot pairs (``kk`` (m,), ``U``, ``V`` (m, 2)) of the samples near a
        sharp vertex. ``s_prev``, ``s_next``: (K,) the samples before and after each one."""
        s = np.asarray(s, float)
        on = self.rules.constrained_pairs(s, s_prev, s_next)
        kk, U, V = self.rules.overshoot_pairs(s, on, self.reach)
        return {"cmd": path.position(s)[:, :2], "nrm": _normals(path.tangent(s)[:, :2]),
                "on": on, "kk": kk, "U": U, "V": V}

    def bound(self, geo: dict, mean: np.ndarray, std: np.ndarray, *, idx=None, path_xy=None):
        """Chance bound (K,) (0 where unconstrained), its motion part (K,), and its uncertainty
        part zσ (K,), mm, of samples with geometry ``geo`` (:meth:`geometry`) and predicted XY
        mean and std (2, K).

        The motion part is the distance from the predicted position to the commanded path
        near it, as the virtual machine's metric measures it (vm.metrics: ±W thinned vertices
        of the plan's own commanded samples ``path_xy`` (N, 2), or a function that makes them
        (called only when a sample needs measuring); ``idx`` (K,) the samples' indices into
        it). The paper's projection on the normal at the commanded point (Eq. 6)
        misses the path curving away from a position that also lags along it, and running on
        past a corner (on a Benchy plan: 0.14 mm where the projection said 0.06). The
        distance is at most |command − position| (the command is on the path), which picks
        the samples worth measuring; the projection (and the overshoot rows) stand elsewhere.
        Without ``path_xy`` the projection is used everywhere."""
        nrm, on = geo["nrm"], geo["on"]
        err = geo["cmd"].T - mean
        mu = np.abs(nrm[:, 0] * err[0] + nrm[:, 1] * err[1])
        zsig = self.z * np.sqrt((nrm[:, 0] * std[0]) ** 2 + (nrm[:, 1] * std[1]) ** 2)
        motion = np.where(on, mu, 0.0)
        unc = np.where(on, zsig, 0.0)
        kk, U, V = geo["kk"], geo["U"], geo["V"]
        if kk.size:
            exc = np.sum(U * (mean[:, kk].T - V), axis=1)
            zs = self.z * np.sqrt((U[:, 0] * std[0, kk]) ** 2 + (U[:, 1] * std[1, kk]) ** 2)
            worse = exc + zs > motion[kk] + unc[kk]
            kk, exc, zs = kk[worse], exc[worse], zs[worse]
            # several vertices may reach one sample: keep the worst of each
            order = np.argsort(exc + zs)
            motion[kk[order]] = exc[order]
            unc[kk[order]] = zs[order]
        if path_xy is not None:
            dev = np.hypot(geo["cmd"][:, 0] - mean[0], geo["cmd"][:, 1] - mean[1])
            cand = np.flatnonzero(on & (dev + unc > self.tol * DISTANCE_CHECK))
            if cand.size:
                W = max(1, int(round(CONTOUR_WINDOW_S / self.ts_s)))
                poly = path_xy() if callable(path_xy) else path_xy
                d = distance_to_polyline_window(mean[:, cand].T, poly, W, index=idx[cand])
                del poly
                over = np.zeros(on.size, bool)
                over[kk] = True  # the overshoot rows stay where they say more
                motion[cand] = np.where(over[cand], np.maximum(motion[cand], d), d)
        return motion + unc, motion, unc


    def rest_error(self, geo: dict, idx: np.ndarray) -> np.ndarray:
        """(K,) the contour error of samples that no speed change removes, mm: none for the
        offline twin (a machine at rest is predicted exactly where it is commanded)."""
        return np.zeros(geo["on"].size)

    def rest_uncertainty(self) -> float:
        """zσ of a machine standing still, mm: the noise level and the bias of the axis that
        leaves most room (the uncertainty of the motion itself shrinks as it slows down)."""
        tp = self.tp
        s2 = np.broadcast_to(np.asarray(tp.s2, float), (len(tp.cov),))
        return self.z * float(np.sqrt(min(v + float(c[0, 0]) for v, c in zip(s2, tp.cov))))


class PlantEvaluator(TwinEvaluator):
    """The oracle's bound: the virtual machine's own plant, known exactly (zero std). Its
    effects may depend on absolute time or on the whole history, so it is always evaluated
    over the whole plan (``memory`` None)."""

    def __init__(self, plant, rules, *, z: float, tol_mm: float, overshoot_reach_mm: float):
        self.plant = plant
        self.shapers = dict(getattr(plant, "shapers", {}) or {})
        self.lead = 0  # evaluated over the whole plan at once
        self.rules = rules
        self.ts_s = float(plant.ts_s)
        self.z = float(z)
        self.tol = float(tol_mm)
        self.reach = float(overshoot_reach_mm)
        self.seg_tol = None
        self.memory = None
        self.effects = tuple(e for e in plant.effects if e.stage != "sensor")

    def predict(self, cmd_xy, ref_xy, segments=None):
        cmd3 = np.column_stack([cmd_xy, np.zeros(cmd_xy.shape[0])])
        cmd3 = shape_axes(cmd3, self.plant.ts_s, self.shapers, segments=segments)
        out = simulate_axes(cmd3, self.plant.ts_s, self.plant.impulse, self.effects,
                            mode_hz=self.plant.mode_hz).actual_mm
        return out[:, :2].T, np.zeros((2, cmd_xy.shape[0]))

    def rest_uncertainty(self) -> float:
        """The oracle knows its plant: no uncertainty (its disturbance is ``rest_error``)."""
        return 0.0

    def rest_error(self, geo: dict, idx: np.ndarray) -> np.ndarray:
        """(K,) what the plant's effects add at sample ``idx`` of a machine standing still,
        across the path (|n·d|), on constrained samples, mm: a time-periodic disturbance
        stays whatever the speed."""
        K = int(idx.max()) + 1 if idx.size else 0
        still = np.zeros((K, 3))
        d = simulate_axes(still, self.plant.ts_s, self.plant.impulse, self.effects,
                          mode_hz=self.plant.mode_hz).actual_mm[:, :2]
        nrm = geo["nrm"]
        return np.where(geo["on"], np.abs(nrm[:, 0] * d[idx, 0] + nrm[:, 1] * d[idx, 1]), 0.0)


def plan_bound(ev, path, s_mm: np.ndarray):
    """The chance bound of a whole sampled plan at once (K,), mm: what :func:`plan_slowdown`
    reports, computed from scratch (one whole-file prediction, no windows)."""
    s = np.asarray(s_mm, float)
    geo = ev.geometry(path, s, np.concatenate([s[:1], s[:-1]]), np.concatenate([s[1:], s[-1:]]))
    mean, std = ev.predict(geo["cmd"], geo["cmd"][0])
    return ev.bound(geo, mean, std, idx=np.arange(s.size), path_xy=geo["cmd"])[0]

