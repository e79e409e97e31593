"""Logs the closed loop learns from: encoder logs and Klipper raw accelerometer recordings.

``MotionLog`` is the common form: commanded and measured X, Y (Z) positions on one uniform
grid at the profile's Ts. ``load_log(path, profile)`` reads either kind, takes it as users have
it (cut at either end) and refuses only a log nothing can be learned from, with a one-line
``LogError`` (what, where, value, limit, fix).

**Logs cut mid-print.** The twin is causal: its prediction at sample t depends on the commands
of the last ``n_taps`` samples (the impulse response) and, through its features, on x̂ and the
measured errors of the last max(n2, n3) samples — on nothing later. So

- a log that **ends mid-motion** loses nothing: it is used as is (one-line warning);
- a log that **starts mid-motion** has an unknown past. The convolution's history is held at
  the first commanded sample (exact when the machine sat there at rest), and the first
  ``warmup = n_taps + max(n2, n3)`` samples, whose prediction depends on that unknown past,
  are left out of every score and of learning (``MotionLog.warmup``; ``twin.model.AxisTwin.run``
  ``warmup``; ``closedloop.learn``); from sample ``warmup`` on the physics' prediction is the
  one the whole print would give (one-line warning, stating the warm-up).

Whether the command moves at an edge is judged by extrapolating its last (first) two steps one
sample further (``edge_speeds_mm_s``): a command decelerating to a stop between two samples
(the optimizer's own plans end so, at 1–2 mm/s on the last step) or starting from rest at the
first sample is at rest there.

Refused (genuinely unusable):

- **wrong machine**: the twin's residual after the warm-up is implausible (RMS above ``MAX_RESIDUAL_RATIO`` of the motion's own RMS, e.g. a log of
  another printer whose dynamics the profile does not describe);
- **too short**: fewer samples after the warm-up than the twin has weights
  (``n_features(n2, n3)``, 42 for n2 = 10, n3 = 30): nothing can be identified from fewer;
- **no motion**: commanded range below ``MIN_TRAVEL_MM`` on every axis after the warm-up;
- **clipped**: the measured signal sits flat at its extreme for ``CLIP_RUN`` samples or more
  while the command moves ``CLIP_MARGIN_MM`` past it (encoder), or the accelerometer is at full
  scale (raw).

Used with a one-line ``LogWarning`` (printed by the CLI as ``gcode-feedopt: warning: ...``):
starts mid-motion, ends mid-motion, and **short motion** — the command moves during fewer
samples after the warm-up than the impulse response is long (``n_taps``): a motion shorter than
the response it excites tells little apart; the learning step is bounded anyway
(``closedloop.learn``).

**The sensor's zero.** An incremental encoder counts from wherever it was switched on or zeroed,
and a log in G92-shifted coordinates sits off the machine's: the measured column is the position
plus a constant. A position-controlled axis at rest sits at its command (DC gain 1), so a
constant there is the sensor's, not the machine's: left in, the diagnosis names it (benchA's
clean butterfly with the encoders 0.05 / −0.03 mm off: backlash on both axes) and learning
takes it for machine error. ``sensor_offsets`` reads it where the command stands still and the
twin has settled, tests it (significant, ≥ ``MIN_OFFSET_MM``, the same at every such rest) and
asks whether a scale about the origin (a ``gain`` effect) explains the whole log as well; an
offset is subtracted (one-line warning, ``info["sensor_offset_mm"]``), a constant the log
cannot tell from a gain is said (one-line warning) and left. On benchA's 14 logs and the 476
logs of 68 foreign machines (``tests/foreign/machines.py``, seeds 0–67) nothing is subtracted;
"cannot tell" is said on 3, each a log of a gain effect.

A log the twin misses by more than ``MAX_RESIDUAL_RATIO`` is refused with its likely cause when
the measured column is an affine map of the commands (``_misfit_cause``): positions in µm or
inches, an encoder counting the other way, X and Y swapped.

An encoder log sampled at another period than the profile's Ts (a 1 ms or 5 ms logger) is
resampled to Ts (``resample_columns``: every r-th sample for an integer ratio, else linear
interpolation; one-line warning). Encoder logs share one clock between command and
measurement (one row each), so they need no alignment; shifting them would hide a real delay. A raw accelerometer file has its own
clock: the commanded motion (Klipper's resonance-test excitation, ``identify.excitation``) is
aligned to it by cross-correlation, offset and clock rate (``identify.raw.analyse_raw`` →
``identify.h1.estimate_clock``).

**Acceleration → displacement** (paper Sec. 6.1.1): a Luenberger observer on the double
integrator x'' = a, corrected by the nominal model's position x̂ = h̄ * x_cmd:

    ẋ_o = v_o + l1 (x̂ − x_o),   v̇_o = a + l2 (x̂ − x_o),   l1 = 2ω_o, l2 = ω_o²

Its error dynamics are a critically damped pair at ω_o = 2π·``OBSERVER_HZ`` (15 Hz as in the
paper). In transfer-function form X_o = F(s) X̂ + A(s)/(s + ω_o)², F = (2ω_o s + ω_o²)/(s + ω_o)²:
below ~15 Hz the position is the model's, above it the accelerometer's — so a diagnosis on
observed data can only see what the model gets wrong **above** the observer frequency.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import signal, stats

from ..errors import LogError, LogWarning, ProfileError
from ..identify.excitation import GENERATORS, duration_s, sampled_accel
from ..identify.raw import analyse_raw, check_clipping, resample_uniform
from ..identify.readers import read_raw
from ..twin.features import n_features
from ..twin.physics import log_machine_command, nominal_impulse
from ..vm.log import read_log
from ..vm.plant import respond
from .catalogue import _n_eff

#: Observer bandwidth, Hz (paper Sec. 6.1.1).
OBSERVER_HZ = 15.0
#: Below this commanded range on every axis a log has "no motion", mm.
MIN_TRAVEL_MM = 1.0
#: A twin residual above this fraction of the motion's RMS means the wrong machine.
MAX_RESIDUAL_RATIO = 0.2
#: Samples flat at the extreme that make a measured channel "clipped".
CLIP_RUN = 5
#: The command must be this far beyond a flat measured extreme for it to count as clipping, mm.
CLIP_MARGIN_MM = 0.5
#: A command moving slower than this (extrapolated one sample past an edge) is at rest, mm/s.
END_SPEED_MM_S = 1.0
#: A log sampled this coarsely or more is refused, s (``check_log_period``).
MAX_LOG_PERIOD_S = 0.1
#: Significance level of the sensor-offset test (the diagnosis's α).
OFFSET_ALPHA = 0.01
#: A constant at rest below this is left in, mm: an encoder's count leaves up to half a count
#: at rest (a position between two counts; foreign sensors of 2.3–2.4 µm counts read 1.0–1.4 µm
#: off), and the diagnosis sizes its effects well above it.
MIN_OFFSET_MM = 0.005
#: The twin's mean is settled at rest within this of the command, mm.
SETTLED_MM = 0.0005
#: Contiguous blocks of the batch-means test of a sensor offset.
OFFSET_BATCHES = 20


@dataclass(frozen=True)
class MotionLog:
    """Commanded and measured positions on one grid.

    Attributes:
        ts_s: sample period. cmd_mm, pos_mm: (K, 3) X, Y, Z, mm.
        source: file name. kind: "encoder" | "klipper_raw".
        info: how it was read (alignment, observer, direction, ...).
        warmup: samples at the start whose prediction depends on motion before the log
            (``twin_memory`` when the log starts mid-motion, else 0): left out of scores and
            learning.
    """

    ts_s: float
    cmd_mm: np.ndarray
    pos_mm: np.ndarray
    source: str
    kind: str
    info: dict = field(default_factory=dict)
    warmup: int = 0


def observer_position(x_model: np.ndarray, accel: np.ndarray, fs_hz: float,
                      f_o_hz: float = OBSERVER_HZ) -> np.ndarray:
    """Luenberger observer (module docstring): model position + measured acceleration ->
    position estimate, (K,) each at ``fs_hz``. Discretised by the bilinear transform; the
    start is initialised at the model's first value."""
    w = 2 * np.pi * f_o_hz
    den = [1.0, 2 * w, w * w]
    bF, aF = signal.bilinear([2 * w, w * w], den, fs_hz)
    bA, aA = signal.bilinear([1.0], den, fs_hz)
    x0 = float(x_model[0])
    xf = signal.lfilter(bF, aF, np.asarray(x_model, float) - x0)
    xa = signal.lfilter(bA, aA, np.asarray(accel, float))
    return x0 + xf + xa


def twin_memory(profile) -> int:
    """Samples of the past the twin's prediction at one sample depends on: the impulse
    response (``n_taps``) and the longest feature lag (max(n2, n3)); the warm-up of a log that
    starts mid-motion (module docstring)."""
    tw = profile.twin
    return int(tw.n_taps + max(tw.n2, tw.n3))


def min_usable_samples(profile) -> int:
    """Fewer samples (after the warm-up) than the twin has weights identify nothing."""
    return int(n_features(profile.twin.n2, profile.twin.n3))


def edge_speeds_mm_s(cmd_mm: np.ndarray, ts_s: float) -> tuple[float, float]:
    """(start, end) XY speed of the command at the log's edges, mm/s; 0 where it is at rest.

    The first (last) XY step Δ_0 is extrapolated one sample outwards, 2·Δ_0 − Δ_1, and
    projected on Δ_0: a command that starts from rest at the first sample (accelerating,
    Δ_1 ≈ 3·Δ_0) or stops within the last sample (Δ_last ≈ Δ_prev/3) extrapolates to ≤ 0 and
    is at rest; a command cut while moving keeps its speed. An edge is at rest when either its
    step or the extrapolation is below ``END_SPEED_MM_S``."""
    c = np.asarray(cmd_mm, float)[:, :2]
    if c.shape[0] < 3:
        return 0.0, 0.0

    def speed(d0, d1):
        n0 = float(np.linalg.norm(d0))
        if n0 <= END_SPEED_MM_S * ts_s:
            return 0.0
        v_out = float((2.0 * d0 - d1) @ d0) / n0 / ts_s
        return 0.0 if v_out <= END_SPEED_MM_S else n0 / ts_s

    return speed(c[1] - c[0], c[2] - c[1]), speed(c[-1] - c[-2], c[-2] - c[-3])


def log_warmup(cmd_mm: np.ndarray, ts_s: float, profile) -> int:
    """The warm-up of a log: ``twin_memory(profile)`` samples if the command moves at the first
    sample (the log starts mid-print), else 0."""
    v_start, _ = edge_speeds_mm_s(cmd_mm, ts_s)
    return twin_memory(profile) if v_start > 0 else 0


def check_log(log: MotionLog, profile, *, predicted_mm: np.ndarray | None = None) -> list[str]:
    """Raise LogError if the log is from the wrong machine, too short, motionless or clipped;
    return the one-line warnings it deserves (starts/ends mid-motion, short motion).

    ``predicted_mm`` (K, 2): the twin's mean prediction of X, Y for the residual check; it is
    judged after ``log.warmup``."""
    name = log.source
    if not np.isclose(log.ts_s, profile.ts_s, rtol=1e-3):
        raise LogError(f"{name}: sample period {log.ts_s:.6g} s differs from machine "
                       f"{profile.name!r} Ts={profile.ts_s:g} s; wrong machine? pass the "
                       f"profile the log was recorded with")
    K = log.cmd_mm.shape[0]
    w0 = int(log.warmup)
    n_min = min_usable_samples(profile)
    if K - w0 < n_min:
        after = (f" after the {w0}-sample warm-up of a log that starts mid-motion"
                 if w0 else "")
        raise LogError(f"{name}: too short: {max(K - w0, 0)} samples{after}, fewer than the "
                       f"twin's {n_min} weights (log of {K} samples, {K * log.ts_s:.2f} s); "
                       f"log at least {w0 + n_min} samples ({(w0 + n_min) * log.ts_s:.2f} s)")
    use = slice(w0, K)
    travel = np.ptp(log.cmd_mm[use, :2], axis=0)
    if np.all(travel < MIN_TRAVEL_MM):
        where = f" after the {w0}-sample warm-up" if w0 else ""
        raise LogError(f"{name}: no motion: commanded X/Y range {travel[0]:.3g}/{travel[1]:.3g} mm"
                       f"{where} (< {MIN_TRAVEL_MM} mm); log a print, not an idle machine")
    notes = []
    if log.kind == "encoder":
        for i, ax in enumerate("xy"):
            if np.ptp(log.cmd_mm[:, i]) < MIN_TRAVEL_MM:
                continue
            m = log.pos_mm[:, i]
            moving = np.abs(np.gradient(log.cmd_mm[:, i])) > 1e-9
            c = log.cmd_mm[:, i]
            for extreme, beyond in ((m.max(), c - m.max()), (m.min(), m.min() - c)):
                # flat at the extreme while the command is well past it: a saturated
                # sensor (a dead band, e.g. backlash, stays within its width of the command)
                at = (m == extreme) & moving & (beyond > CLIP_MARGIN_MM)
                run = _longest_run(at)
                if run >= CLIP_RUN:
                    raise LogError(f"{name}: measured {ax} is clipped: {run} samples flat at "
                                   f"{extreme:.6g} mm while the command moves (limit "
                                   f"{CLIP_RUN}); check the encoder range")
        v_start, v_end = edge_speeds_mm_s(log.cmd_mm, log.ts_s)
        if v_start > 0:
            notes.append(f"{name}: starts mid-motion (the command moves at {v_start:.3g} mm/s "
                         f"at t=0): its first {w0} samples ({w0 * log.ts_s:.2f} s, the twin's "
                         f"memory) depend on motion before the log and are left out of scores "
                         f"and learning")
        if v_end > 0:
            notes.append(f"{name}: ends mid-motion (the command moves at {v_end:.3g} mm/s at "
                         f"its last sample, t={(K - 1) * log.ts_s:.2f} s): used as is, the "
                         f"twin is causal")
        step = np.linalg.norm(np.diff(log.cmd_mm[use, :2], axis=0), axis=1)
        n_moving = int(np.count_nonzero(step > END_SPEED_MM_S * log.ts_s))
        n_taps = int(profile.twin.n_taps)
        if n_moving < n_taps:
            notes.append(f"{name}: short motion: the command moves during {n_moving} samples "
                         f"({n_moving * log.ts_s:.2f} s{' after the warm-up' if w0 else ''}), "
                         f"fewer than the twin's impulse response ({n_taps} samples, "
                         f"{n_taps * log.ts_s:.2f} s): too short to identify much; log a "
                         f"longer stretch of the print")
    if predicted_mm is not None:
        for i, ax in enumerate("xy"):
            if travel[i] < MIN_TRAVEL_MM:
                continue
            motion = float(np.std(log.cmd_mm[use, i]))
            r = float(np.sqrt(np.mean((log.pos_mm[use, i] - predicted_mm[use, i]) ** 2)))
            if r > MAX_RESIDUAL_RATIO * motion:
                cause = _misfit_cause(log.pos_mm[use, :2], predicted_mm[use, :2], i)
                raise LogError(f"{name}: the twin of {profile.name!r} misses axis {ax} by "
                               f"{r:.3g} mm RMS, {r / motion:.0%} of the motion (limit "
                               f"{MAX_RESIDUAL_RATIO:.0%})"
                               + (cause or "; wrong machine or a broken sensor"))
    return notes


def _longest_run(mask: np.ndarray) -> int:
    if not mask.any():
        return 0
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return int(np.max(ends - starts))


def check_log_period(name: str, ts_s: float) -> None:
    """Refuse (one-line ``LogError``) a log sampled every ``MAX_LOG_PERIOD_S`` or more: it
    cannot show a printer's dynamics (modes at 20–200 Hz), and a time column in ms or µs reads
    so (a 2 ms log with t in ms steps by 2 "s"; resampled to a 2 ms Ts it became a million
    rows of interpolated nonsense)."""
    if ts_s < MAX_LOG_PERIOD_S:
        return
    for unit, k in (("milliseconds", 1e3), ("microseconds", 1e6)):
        if 1e-5 <= ts_s / k < MAX_LOG_PERIOD_S:
            raise LogError(f"{name}: t steps by {ts_s:g} per row: is t in {unit}? a log's t is "
                           f"in seconds (a {ts_s / k * 1e3:g} ms logger steps by "
                           f"{ts_s / k:g}): divide the column by {k:g}; in seconds, the log "
                           f"is too coarse to show a printer's motion (log at 1–10 ms)")
    raise LogError(f"{name}: sampled every {ts_s:g} s: too coarse to show a printer's motion "
                   f"(limit {MAX_LOG_PERIOD_S:g} s); log at 1–10 ms")


def resample_columns(ts_from_s: float, ts_to_s: float, *cols: np.ndarray):
    """Columns (K, ...) sampled every ``ts_from_s`` on the grid every ``ts_to_s`` over the same
    span: every r-th sample when ``ts_to_s`` = r·``ts_from_s`` for an integer r (the samples
    themselves: the sensor's noise stays white and the motion, far below either Nyquist
    frequency, keeps its values), else linear interpolation between samples. Returns the
    resampled columns and a few words saying how."""
    ratio = ts_to_s / ts_from_s
    r = int(round(ratio))
    if r >= 1 and abs(ratio - r) <= 1e-6 * r:
        return tuple(np.asarray(c)[::r] for c in cols), f"one sample in {r} kept"
    k = np.asarray(cols[0]).shape[0]
    t_from = np.arange(k) * ts_from_s
    t_to = np.arange(int(np.floor(t_from[-1] / ts_to_s + 1e-9)) + 1) * ts_to_s
    out = []
    for c in cols:
        c = np.asarray(c, float)
        flat = c.reshape(k, -1)
        res = np.column_stack([np.interp(t_to, t_from, flat[:, j]) for j in range(flat.shape[1])])
        out.append(res.reshape((t_to.size,) + c.shape[1:]))
    how = "linear interpolation" + (
        f" (the log is coarser than Ts: the motion above {0.5 / ts_from_s:g} Hz, its Nyquist "
        f"frequency, is not seen)" if ts_from_s > ts_to_s else "")
    return tuple(out), how


def twin_mean_xy(profile, machine_cmd_mm: np.ndarray) -> np.ndarray:
    """(K, 2) the twin's mean X, Y (its nominal impulse response) on the machine's input
    ``machine_cmd_mm`` (K, ≥2: the commands through the profile's input shaper, if any)."""
    imp = nominal_impulse(profile)
    return np.column_stack([respond(machine_cmd_mm[:, i], imp[ax][0])
                            for i, ax in enumerate("xy")])


def _settled_runs(cmd: np.ndarray, pred: np.ndarray, min_len: int) -> list[slice]:
    """Runs of at least ``min_len`` samples where the command stands still and the twin's
    mean has settled on it (within ``SETTLED_MM``): where the axis sits at its command."""
    still = np.zeros(cmd.size, bool)
    still[1:] = np.abs(np.diff(cmd)) <= 1e-9
    still[0] = still[1] if cmd.size > 1 else False
    mask = still & (np.abs(pred - cmd) <= SETTLED_MM)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return [slice(int(i), int(j)) for i, j in zip(edges[::2], edges[1::2]) if j - i >= min_len]


def sensor_offsets(pos_mm: np.ndarray, pred_mm: np.ndarray, cmd_mm: np.ndarray,
                   start: int = 0, alpha: float = OFFSET_ALPHA) -> list[tuple[str, float, float]]:
    """Per column of ``pos_mm`` / ``pred_mm`` / ``cmd_mm`` (K, n), from the residual
    r = pos − pred over samples ``start``.. (module docstring, *The sensor's zero*):
    (verdict, offset mm, scale) with verdict ``"offset"`` (a sensor offset: subtract it),
    ``"either"`` (a constant is there, but this log cannot tell an offset from a scale about
    the origin) or ``""`` (none, or a scale: the catalogue's ``gain``, left to the diagnosis).

    1. *At rest.* An axis at rest sits at its command, so an offset is read where the command
       stands still and the twin's mean has settled (``_settled_runs``, runs of at least
       ``OFFSET_BATCHES`` samples): o = their mean residual, significant by Student's t
       (1 − alpha/2) on the rest residual's effective sample count, ≥ ``MIN_OFFSET_MM``, and
       the same at every run (each run's mean within half of o of it: a play or a friction
       holds a different lag at each stop). A constant residual while moving alone is not an
       offset: a 3 ms delay on a stretch moving one way at 50 mm/s leaves −0.15 mm that
       vanishes at rest. A log with no settled rest is taken as measured.
    2. *An offset, not a scale.* Over the whole log, cut into ``OFFSET_BATCHES`` contiguous
       blocks (longer than the residual's ringing, so it holds for any autocorrelation), the
       constant o and a scale about the origin, r = g·pred (g least squares), are compared
       block by block; a sign test (one-sided binomial at ``alpha``: 16 of 20 blocks) names
       the one that leaves the smaller sum of squares, "either" when neither does. On a log
       far from the origin the two differ only through the spread of the positions: a 0.25 %
       gain of a foreign machine under a strongly coloured residual passed the first test
       alone as a −0.28 mm offset."""
    crit_t = float(stats.t.ppf(1.0 - alpha / 2, OFFSET_BATCHES - 1))
    out = []
    for i in range(pred_mm.shape[1]):
        x = np.asarray(pred_mm[start:, i], float)
        r = np.asarray(pos_mm[start:, i], float) - x
        if r.size < 4 * OFFSET_BATCHES or np.ptp(x) == 0.0:
            out.append(("", 0.0, 1.0))
            continue
        runs = _settled_runs(np.asarray(cmd_mm[start:, i], float), x, OFFSET_BATCHES)
        if not runs:
            out.append(("", 0.0, 1.0))
            continue
        rest = np.concatenate([r[sl] for sl in runs])
        o = float(rest.mean())
        se = float(np.std(rest)) / math.sqrt(_n_eff(rest - o))
        if not (abs(o) > crit_t * se and abs(o) >= MIN_OFFSET_MM
                and all(abs(float(r[sl].mean()) - o) <= 0.5 * abs(o) for sl in runs)):
            out.append(("", o, 1.0))
            continue
        g = float(x @ r) / float(x @ x)
        blocks = zip(np.array_split(r, OFFSET_BATCHES), np.array_split(x, OFFSET_BATCHES))
        wins = sum(float(np.sum((rb - g * xb) ** 2)) > float(np.sum((rb - o) ** 2))
                   for rb, xb in blocks)
        if stats.binom.sf(wins - 1, OFFSET_BATCHES, 0.5) < alpha:
            verdict = "offset"
        elif stats.binom.sf(OFFSET_BATCHES - wins - 1, OFFSET_BATCHES, 0.5) < alpha:
            verdict = ""
        else:
            verdict = "either"
        out.append((verdict, o, 1.0 + g))
    return out


def remove_sensor_offsets(log: MotionLog, pred_mm: np.ndarray) -> tuple[MotionLog, list[str]]:
    """``log`` with the sensor offsets of X, Y subtracted from its measured positions, and the
    sentences the CLI prints as warnings: one for the offsets removed, one per axis whose
    constant this log cannot tell from a scale. An offset is not removed where the log would
    still be refused as another machine's (the residual above ``MAX_RESIDUAL_RATIO`` of the
    motion): that refusal then names the cause."""
    use = slice(log.warmup, None)
    found, notes = {}, []
    for i, (verdict, o, g) in enumerate(sensor_offsets(log.pos_mm[:, :2], pred_mm[:, :2],
                                                       log.cmd_mm[:, :2], log.warmup)):
        cmd = log.cmd_mm[use, i]
        if not verdict or np.ptp(cmd) < MIN_TRAVEL_MM:
            continue
        ax = "xy"[i]
        r = log.pos_mm[use, i] - o - pred_mm[use, i]
        if np.sqrt(np.mean(r * r)) > MAX_RESIDUAL_RATIO * float(np.std(cmd)):
            continue  # refused by check_log, which names the cause
        if verdict == "either":
            notes.append(f"{log.source}: measured {ax} sits {o:+.4f} mm off its command at "
                         f"rest, as a sensor offset or a scale of {g:.6g} about the origin "
                         f"would; this log cannot tell which ({ax} spans "
                         f"{np.ptp(cmd):.3g} mm, {abs(float(np.mean(cmd))):.3g} mm from the "
                         f"origin): left as measured. If the encoder's zero is not the "
                         f"machine's, zero it when the printer homes")
            continue
        found[ax] = o
    if found:
        pos = log.pos_mm.copy()
        for ax, o in found.items():
            pos[:, "xy".index(ax)] -= o
        said = ", ".join(f"{ax} by {o:+.4f} mm" for ax, o in found.items())
        notes.insert(0, f"{log.source}: the measured positions sit off the commanded ones by a "
                        f"constant ({said}): the sensor's zero, not the machine's (an axis at "
                        f"rest sits at its command); subtracted. Zero the encoder when the "
                        f"printer homes to silence this")
        log = dataclasses.replace(log, pos_mm=pos, info={**log.info, "sensor_offset_mm": found})
    return log, notes


def _misfit_cause(pos: np.ndarray, pred: np.ndarray, i: int) -> str:
    """Why axis ``i``'s measured column misses the prediction, when it is an affine map of the
    predicted X and Y ("" when it is not): the fix in a few words."""
    n = pos.shape[0]
    A = np.column_stack([np.ones(n), pred[:, 0], pred[:, 1]])
    coef, *_ = np.linalg.lstsq(A, pos[:, i], rcond=None)
    res = pos[:, i] - A @ coef
    if np.sqrt(np.mean(res ** 2)) > MAX_RESIDUAL_RATIO * max(float(np.std(pos[:, i])), 1e-12):
        return ""
    own, other = coef[1 + i], coef[2 - i]
    ax, ox = "xy"[i], "xy"[1 - i]
    if abs(other) > 0.5 > abs(own):
        return (f"; measured {ax} follows the commanded {ox} ({other:.3g}×): are the x and y "
                f"columns swapped?")
    for k, what in ((1000.0, "in µm? write mm"), (25.4, "in mm while the command is in "
                    "inches? write both in mm"), (1 / 25.4, "in inches? write mm")):
        if abs(own / k - 1) < 0.05:
            return f"; measured {ax} is {own:.4g}× the command: {what}"
    if abs(own + 1) < 0.2:
        return (f"; measured {ax} runs against the command ({own:.3g}×): the encoder counts "
                f"the other way; negate the column")
    if abs(own - 1) > 0.2:
        return (f"; measured {ax} is {own:.4g}× the command: a units or steps/mm mismatch, "
                f"or the wrong machine?")
    return ""


def resample_log(log: MotionLog, ts_s: float) -> tuple[MotionLog, str]:
    """``log`` on the profile's grid ``ts_s`` (:func:`resample_columns`), with the sentence
    the CLI prints as a warning."""
    (cmd, pos), how = resample_columns(log.ts_s, ts_s, log.cmd_mm, log.pos_mm)
    note = (f"{log.source}: sampled every {log.ts_s * 1000:.4g} ms, the profile's Ts is "
            f"{ts_s * 1000:g} ms: resampled to it ({how})")
    return dataclasses.replace(log, ts_s=ts_s, cmd_mm=cmd, pos_mm=pos), note


def read_encoder(path) -> MotionLog:
    log = read_log(path)
    return MotionLog(ts_s=log.ts_s, cmd_mm=log.cmd_mm, pos_mm=log.pos_mm,
                     source=os.fspath(path), kind="encoder", info={"aligned": "shared clock"})


def read_klipper_raw(path, profile, *, n_modes: int = 3, axis: str = "x") -> MotionLog:
    """A Klipper raw accelerometer recording of a resonance test, with its commanded motion
    (the detected excitation) aligned by cross-correlation and turned into positions.

    The motion is along one direction (``analyse_raw``'s ``direction``); it is logged as the
    profile axis ``axis`` (the other at rest) and compared with that axis's twin. Command position = double integral of the commanded acceleration
    (piecewise constant, so exact), measured position = observer(model, measured accel).
    The model of the observer is the profile's X twin mean."""
    name = os.fspath(path)
    try:
        t, acc = read_raw(name)
        need = min(duration_s(g) for g in GENERATORS.values())
        if len(t) < 2 or t[-1] - t[0] < 0.9 * need:
            span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
            raise LogError(f"{name}: truncated: the recording spans {span:.1f} s, a Klipper "
                           f"resonance test lasts {need:.1f} s or more; record the whole test")
        clip = check_clipping(acc)
        if clip:
            raise LogError(f"{name}: {clip[0]}")
        res = analyse_raw(t, acc, n_modes=n_modes)
    except ProfileError as exc:
        raise LogError(str(exc)) from None
    fs, acc_u = resample_uniform(t, acc)
    sos = signal.butter(2, [3.0, 0.45 * fs], btype="bandpass", fs=fs, output="sos")
    meas_a = signal.sosfiltfilt(sos, acc_u - acc_u.mean(0), axis=0) @ res.direction
    # commanded acceleration on the recording's clock
    cmd_t, cmd_a = sampled_accel(res.excitation, fs)
    tau = np.arange(meas_a.size) / fs
    a_cmd = np.interp(res.clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
    # the direction's sign is arbitrary: take the one that correlates positively
    if float(a_cmd @ meas_a) < 0:
        meas_a = -meas_a
    # to the profile's grid
    ts = profile.ts_s
    grid = np.arange(0.0, tau[-1], ts)
    a_cmd_g = np.interp(grid, tau, a_cmd)
    meas_g = np.interp(grid, tau, meas_a)
    # command position: double integration (trapezoid) of the commanded acceleration with its
    # drift removed (the test returns to its start in every half-period)
    v = np.concatenate(([0.0], np.cumsum(0.5 * (a_cmd_g[1:] + a_cmd_g[:-1]) * ts)))
    v = signal.detrend(v, type="linear") if v.size > 2 else v
    x = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * ts)))
    x = signal.sosfiltfilt(signal.butter(2, 1.0, btype="highpass", fs=1 / ts, output="sos"), x)
    h = nominal_impulse(profile)[axis][0]
    x_model = respond(x, h)
    pos = observer_position(x_model, meas_g, 1.0 / ts)
    cmd_mm = np.zeros((grid.size, 3))
    pos_mm = np.zeros((grid.size, 3))
    col = "xy".index(axis)
    cmd_mm[:, col], pos_mm[:, col] = x, pos
    return MotionLog(ts_s=ts, cmd_mm=cmd_mm, pos_mm=pos_mm, source=name, kind="klipper_raw",
                     info={"direction": res.direction.tolist(), "generator": res.excitation.generator,
                           "clock_offset_s": float(res.clock.offset_s),
                           "observer_hz": OBSERVER_HZ, "fs_hz": float(fs), "axis": axis,
                           "warnings": list(res.warnings)})


#: The header ``optimize --trajectory`` writes: a plan (commands only), not an encoder log.
TRAJECTORY_HEADER = "t,x,y,z,e"


def load_log(path, profile, *, check: bool = True, raw_axis: str = "x") -> MotionLog:
    """Read an encoder log or a Klipper raw recording (by its header; ``raw_axis``: the
    profile axis a raw recording is compared with) and check it (``check_log``; its warnings
    are issued as ``LogWarning``). An encoder log that starts mid-motion gets its
    ``warmup`` (module docstring)."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            head = f.readline().decode("ascii", "replace").strip()
    except OSError as exc:
        raise LogError(f"{name}: cannot read the log ({exc.strerror})") from None
    if head.startswith("#time"):
        log = read_klipper_raw(name, profile, axis=raw_axis)
    elif head.replace(" ", "") == TRAJECTORY_HEADER:
        raise LogError(f"{name}:1: header {head!r} is a planned trajectory (optimize "
                       f"--trajectory: commands only), not a log of the machine; `predict` "
                       f"reads it, learning and diagnosis need the measured positions "
                       f"(t,x_cmd,y_cmd,x,y)")
    else:
        log = read_encoder(name)
        check_log_period(name, log.ts_s)
        if not np.isclose(log.ts_s, profile.ts_s, rtol=1e-3):
            log, note = resample_log(log, profile.ts_s)
            warnings.warn(note, LogWarning, stacklevel=2)
        log = dataclasses.replace(log, warmup=log_warmup(log.cmd_mm, log.ts_s, profile))
    pred = None
    if log.kind == "encoder" and np.isclose(log.ts_s, profile.ts_s, rtol=1e-3):
        pred = twin_mean_xy(profile, log_machine_command(profile, log))
        log, notes = remove_sensor_offsets(log, pred)
        for note in notes:
            warnings.warn(note, LogWarning, stacklevel=2)
    if check:
        for note in check_log(log, profile, predicted_mm=pred):
            warnings.warn(note, LogWarning, stacklevel=2)
    return log
