"""The slow-down's current plan (optimize.slowdown): every piece's samples, geometry and
predicted bound, which samples must be predicted again after a change of scale, and their
prediction in windows (steps 2–3 and the incremental prediction of the module docstring)."""

from __future__ import annotations

import numpy as np

from ..free import ranges
from .grid import PlanGrid

_GEO_ROWS = ("cmd", "nrm", "on")
_FIELDS = ("b", "mot", "unc", "rest")


class PlanState:
    """The current plan of pieces [p0, p1) entry by entry, its bound, and which samples must
    be predicted again (NaN).

    Entry 0 is what comes before the first piece: sample 0 and the lead dwell when p0 = 0
    (judged like any sample), otherwise ``history`` — F's last samples before the group,
    which the twin remembers but which are not this state's to judge. Entry e ≥ 1 is piece
    p0 + e − 1 (motion samples, then the dwell held at its end)."""

    def __init__(self, path, grid: PlanGrid, ev, scale: np.ndarray, p0: int = 0,
                 p1: int | None = None, history: np.ndarray | None = None,
                 round_history: int = 150, plan: bool = True):
        self.path, self.grid, self.ev = path, grid, ev
        self.p0 = int(p0)
        self.p1 = grid.n_pieces if p1 is None else int(p1)
        P = self.p1 - self.p0
        self.cell_lo = int(grid.piece_cell[self.p0])
        self.cell_hi = int(grid.piece_cell[self.p1])
        self.scale = np.array(scale, float)
        self.piece_of = grid.piece_of_cell()
        self.end_s = grid.s0_mm[grid.piece_cell[1:]]
        self.start_s = grid.s0_mm[grid.piece_cell[:-1]]
        lead = np.zeros(grid.lead_hold + 1) if history is None else np.asarray(history, float)
        self.s = [lead] + [None] * P
        self.geo = [ev.geometry(path, lead, np.concatenate([lead[:1], lead[:-1]]))] + [None] * P
        if history is not None:  # remembered, not judged
            self.geo[0]["on"][:] = False
            self.geo[0]["kk"] = self.geo[0]["kk"][:0]
        self.tc0, self.tc1, self.v0 = [None] * P, [None] * P, [None] * P
        known = 0.0 if history is not None else np.nan  # history: remembered, never judged
        self.arr = {f: [np.full(lead.size, known)] + [None] * P for f in _FIELDS}
        self.mean = [np.full((2, lead.size), known)] + [None] * P
        #: per entry, samples whose values are carried over from a time-shifted old plan
        self.approx = [np.zeros(lead.size, bool)] + [None] * P
        self.ref = path.position(np.zeros(1))[0, :2]
        self.evaluated = 0
        self.evaluations = 0
        #: history (and reach after a change) of round predictions, samples
        self.reach = None if ev.memory is None else min(ev.memory, round_history)
        #: samples a prediction looks ahead (the firmware's centred input shaper): a change
        #: reaches back this far, and a window is predicted this far past its last sample
        self.lead = int(getattr(ev, "lead", 0))
        if plan:
            self._replan(np.arange(self.p0, self.p1))

    _PER_PIECE = ("tc0", "tc1", "v0")
    _PER_ENTRY = ("s", "geo", "mean", "approx")

    def export(self) -> dict:
        """This state's pieces (entries 1…), to be adopted by a state over more pieces."""
        out = {k: getattr(self, k) for k in self._PER_PIECE}
        out.update({k: getattr(self, k)[1:] for k in self._PER_ENTRY})
        out.update({f: self.arr[f][1:] for f in _FIELDS})
        out["p0"] = self.p0
        return out

    def adopt(self, part: dict) -> None:
        """Take another state's pieces as they are (planned, predicted, checked)."""
        q0 = part["p0"] - self.p0
        n = len(part["s"])
        for k in self._PER_PIECE:
            getattr(self, k)[q0:q0 + n] = part[k]
        for k in self._PER_ENTRY:
            getattr(self, k)[q0 + 1:q0 + 1 + n] = part[k]
        for f in _FIELDS:
            self.arr[f][q0 + 1:q0 + 1 + n] = part[f]
        e = q0 + n
        if self.lead and n and e + 1 < len(self.s):
            # the part's last samples were predicted without the motion after them
            self._invalidate(e, max(0, self.s[e].size - self.lead))
            self.approx[e][max(0, self.s[e].size - self.lead):] = False

    # -- bookkeeping ----------------------------------------------------------------------
    def _invalidate(self, e: int, lo: int, hi: int | None = None):
        for f in _FIELDS:
            self.arr[f][e][lo:hi] = np.nan
        self.mean[e][:, lo:hi] = np.nan

    def invalidate_all(self):
        for e in range(len(self.s)):
            self._invalidate(e, 0)
            self.approx[e][:] = False

    def invalidate_approx(self):
        """Mark every carried-over (time-shifted) value for an exact prediction."""
        for e, ap in enumerate(self.approx):
            if ap.any():
                for f in _FIELDS:
                    self.arr[f][e][ap] = np.nan
                self.mean[e][:, ap] = np.nan
                ap[:] = False

    @property
    def n_approx(self) -> int:
        return int(sum(int(a.sum()) for a in self.approx))

    def _replan(self, pieces):
        """Re-plan ``pieces``; mark what must be predicted again (module docstring)."""
        g = self.grid
        ss, t0, t1, v0 = g.plan(self.scale, pieces)
        mem = self.reach
        fulls = [np.concatenate([x, np.full(g.piece_hold[p], self.end_s[p])])
                 for p, x in zip(pieces, ss)]
        # geometry of every re-planned sample in one vectorized pass
        if fulls:
            sizes = np.array([x.size for x in fulls])
            cat = np.concatenate(fulls)
            prev = np.concatenate([[0.0], cat[:-1]])
            starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            prev[starts] = self.start_s[pieces]
            nxt = np.concatenate([cat[1:], [0.0]])
            ends = np.cumsum(sizes) - 1
            nxt[ends] = cat[ends]  # at rest at the piece's end: no interval after it here
            geo = self.ev.geometry(self.path, cat, prev, nxt)
            cut = np.cumsum(sizes)[:-1]
            rows = {k: np.split(geo[k], cut) for k in _GEO_ROWS}
            pair_cut = np.searchsorted(geo["kk"], cut)
            kk = np.split(geo["kk"], pair_cut)
            UU, VV = np.split(geo["U"], pair_cut), np.split(geo["V"], pair_cut)
        for i, (p, full, a, b, v) in enumerate(zip(pieces, fulls, t0, t1, v0)):
            e = int(p) - self.p0 + 1
            q = int(p) - self.p0
            old = self.s[e]
            n = full.size
            back = 0
            if old is not None and mem is not None:
                src, shifted, spill, back = self._warp(q, old.size, n, a, b, v, mem)
            else:
                src, shifted, spill = np.full(n, -1), np.zeros(n, bool), 0
            take = src >= 0
            self.s[e] = full
            self.geo[e] = {k: rows[k][i] for k in _GEO_ROWS}
            self.geo[e].update(kk=kk[i] - starts[i], U=UU[i], V=VV[i])
            self.tc0[q], self.tc1[q], self.v0[q] = a, b, v
            for f in _FIELDS:
                new = np.full(n, np.nan)
                if old is not None:
                    new[take] = self.arr[f][e][src[take]]
                self.arr[f][e] = new
            newm = np.full((2, n), np.nan)
            ap = np.zeros(n, bool)
            if old is not None:
                newm[:, take] = self.mean[e][:, src[take]]
                ap[take] = self.approx[e][src[take]] | shifted[take]
            self.mean[e], self.approx[e] = newm, ap
            if back and e > 0 and self.s[e - 1] is not None:
                # the piece before sees this one's changed start through the shaper's lead
                m_p = self.s[e - 1].size
                self._invalidate(e - 1, max(0, m_p - back))
                self.approx[e - 1][max(0, m_p - back):] = False
            if old is None or mem is None:
                continue
            # the next pieces' first samples remember this one's end: predicted again where
            # the changed stretch reaches into them, carried over (time-shifted) otherwise
            left, tail, nxt = spill, self.ev.memory, e + 1  # the twin's whole memory
            tail_approx = bool(n) and bool(ap[-1])
            while tail > 0 and nxt < len(self.s) and self.s[nxt] is not None:
                m_n = self.s[nxt].size
                if left > 0:
                    self._invalidate(nxt, 0, left)
                    self.approx[nxt][:left] = False
                if tail_approx:
                    self.approx[nxt][max(left, 0):tail] = True
                left -= m_n
                tail -= m_n
                nxt += 1
        if mem is None:
            self.invalidate_all()

    def _warp(self, q: int, old_n: int, n: int, a, b, v, reach: int):
        """Where a re-planned piece's new samples find their old values.

        A cell whose motion did not change (same duration, entry and exit speed) moves as
        before, only later by the delay of the changed cells before it: its new sample at
        local time t is the old sample at the corresponding old time (the nearest whole
        sample; ``shifted`` when the delay is not zero). Samples in changed cells, within
        ``reach`` samples after them and ``self.lead`` before them have no old value (src
        −1): they are predicted again.

        Returns src (n,) old index or −1, shifted (n,) bool, how many samples the last
        changed stretch reaches past the piece's end (into the next pieces), and how many
        samples before the piece's start the first one reaches back (the lead)."""
        ts = self.grid.ts_s
        a0, b0 = self.tc0[q], self.tc1[q]
        C = a.size
        vn, vo = np.append(v, 0.0), np.append(self.v0[q], 0.0)
        changed = ((b - a) != (b0 - a0)) | (vn[:-1] != vo[:-1]) | (vn[1:] != vo[1:])
        if not changed.any() and old_n == n:
            return np.arange(n), np.zeros(n, bool), 0, 0
        t = np.arange(1, n + 1) * ts
        c = np.clip(np.searchsorted(a, t, side="right") - 1, 0, C - 1)
        last = np.maximum.accumulate(np.where(changed, np.arange(C), -1))[c]
        end_last = np.where(last >= 0, b[np.maximum(last, 0)], -np.inf)
        dirty = (t - end_last) < reach * ts
        back = 0
        if self.lead and changed.any():
            # a changed cell is seen ``lead`` samples before it starts
            nxt = np.minimum.accumulate(np.where(changed, np.arange(C), C)[::-1])[::-1][c]
            ahead = np.where(nxt < C, a[np.minimum(nxt, C - 1)], np.inf) - t
            dirty |= (ahead >= 0) & (ahead < self.lead * ts)
            first = float(a[np.flatnonzero(changed)[0]])
            back = max(0, self.lead - int(np.floor(first / ts + 1e-9)))
        rest = t > b[-1]
        t_old = np.where(rest, t - (b[-1] - b0[-1]), a0[c] + (t - a[c]))
        j = np.rint(t_old / ts).astype(np.int64) - 1
        ok = ~dirty & (j >= 0) & (j < old_n)
        src = np.where(ok, j, -1)
        shifted = ok & (last >= 0)
        spill = 0
        if changed.any():
            end = float(b[np.flatnonzero(changed)[-1]]) + reach * ts
            spill = max(0, int(np.ceil(end / ts - 1e-9)) - n)
        return src, shifted, spill, back

    def set_scale(self, scale: np.ndarray):
        changed = np.flatnonzero(scale != self.scale)
        self.scale = np.array(scale, float)
        if changed.size:
            self._replan(np.unique(self.piece_of[changed]))

    # -- evaluation -------------------------------------------------------------------------
    def assemble(self):
        """Global s (K,), {b, mot, unc, rest} (K,), mean (2, K), and the sample offset of
        every entry (E,).

        Every entry becomes a view of the global arrays, one field at a time: the field's
        old arrays (views of the last assembly, or re-planned entries) are freed before the
        next field is joined, so an evaluation holds one field twice at the most, not every
        field (on the ArcWelder Benchy's 20.6 M samples, 56 bytes a sample at once). The
        caller drops the arrays of the last evaluation before asking again."""
        sizes = np.array([x.size for x in self.s], np.int64)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        cut = starts[1:]
        s = np.concatenate(self.s)
        self.s = np.split(s, cut)
        out = {}
        for f in _FIELDS:
            out[f] = np.concatenate(self.arr[f])
            self.arr[f] = np.split(out[f], cut)
        mean = np.concatenate(self.mean, axis=1)
        self.mean = np.split(mean, cut, axis=1)
        return s, out, mean, starts

    def _gather(self, idx: np.ndarray, starts: np.ndarray) -> dict:
        """The cached geometry of global samples ``idx`` (sorted), overshoot pairs numbered by
        position in ``idx``."""
        bounds = np.searchsorted(idx, np.concatenate([starts, [np.iinfo(np.int64).max]]))
        parts = {k: [] for k in _GEO_ROWS}
        kk, U, V = [], [], []
        for e in np.flatnonzero(np.diff(bounds) > 0):
            lo, hi = bounds[e], bounds[e + 1]
            loc = idx[lo:hi] - starts[e]
            g = self.geo[e]
            for k in _GEO_ROWS:
                parts[k].append(g[k][loc])
            if g["kk"].size:
                pos = np.clip(np.searchsorted(loc, g["kk"]), 0, loc.size - 1)
                hit = loc[pos] == g["kk"]
                kk.append(pos[hit] + lo)
                U.append(g["U"][hit])
                V.append(g["V"][hit])
        out = {k: np.concatenate(v) for k, v in parts.items()}
        out["kk"] = np.concatenate(kk) if kk else np.zeros(0, np.int64)
        out["U"] = np.concatenate(U) if U else np.zeros((0, 2))
        out["V"] = np.concatenate(V) if V else np.zeros((0, 2))
        return out

    def evaluate(self, exact: bool = False):
        """Predict every sample whose bound is unknown; returns :meth:`assemble`'s values.

        ``exact``: with the twin's whole memory of history before every window and the whole
        plan's reference (equal to the whole-file prediction); otherwise with
        ``self.reach`` samples of history, each window from its own first command, and the
        values flagged ``approx`` for the next whole-file check."""
        s, out, mean, starts = self.assemble()
        bad = np.isnan(out["b"])
        if not bad.any():
            return s, out, mean, starts
        mem = self.ev.memory if exact else self.reach
        if mem is None:
            w_lo, w_hi = np.array([0]), np.array([s.size])
            exact = True
        else:
            edge = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
            a_runs, b_runs = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
            # a run is predicted with the plan that follows it as far as the prediction looks
            b_runs = np.minimum(b_runs + self.lead, s.size)
            # each run with its history before it; overlapping ones merge
            h_lo = np.maximum(a_runs - mem, 0)
            first = np.concatenate([[True], h_lo[1:] > b_runs[:-1]])
            w_lo = h_lo[first]
            w_hi = np.maximum.reduceat(b_runs, np.flatnonzero(first))
        owner, idx = ranges(w_lo, w_hi)
        geo = self._gather(idx, starts)
        w_first = np.concatenate([[0], np.cumsum(w_hi - w_lo)[:-1]])  # each window's first row
        ref = self.ref if exact else geo["cmd"][w_first][owner]
        mu, sd = self.ev.predict(geo["cmd"], ref, segments=w_first)
        vals = self.ev.bound(geo, mu, sd, idx=idx,
                             path_xy=lambda: np.concatenate([g["cmd"] for g in self.geo]))
        vals = vals + (self.ev.rest_error(geo, idx),)
        fill = bad[idx]
        tgt = idx[fill]
        for f, v in zip(_FIELDS, vals):
            out[f][tgt] = v[fill]
        mean[:, tgt] = mu[:, fill]
        self.evaluated += int(idx.size)
        self.evaluations += 1
        cut = starts[1:]  # the entries are views of ``out`` and ``mean`` (assemble)
        if not exact:
            # a window from the plan's first sample has its whole history: exact
            ap = np.concatenate(self.approx)
            ap[tgt] = (w_lo[owner] > 0)[fill]
            self.approx = np.split(ap, cut)
        return s, out, mean, starts

    def cell_times(self, starts):
        """Global motion start and end time of this state's cells, s (entry e's local time 0
        is the resting sample before its first motion sample)."""
        base = (starts[1:] - 1) * self.grid.ts_s
        t0 = np.concatenate([c + b for c, b in zip(self.tc0, base)])
        t1 = np.concatenate([c + b for c, b in zip(self.tc1, base)])
        return t0, t1

