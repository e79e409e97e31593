"""The virtual machine's plant: commanded positions in, actual (and measured) positions out.

Per axis x and y the plant is one *draw* of the profile's FRF distribution (the known
uncertainty, paper Sec. 3.2) as an impulse response h (commanded -> actual position, Ts
samples), plus the unknown effects of ``vm.effects``, applied in the order of
``effects.STAGES``:

1. ``response``: effects that reshape h (``resonance_shift``);
2. the convolution x_m = x_0 + h * (x_cmd − x_0), x_0 the first commanded sample, so a
   machine at rest at x_0 stays there whatever h's DC gain; then ``linear`` effects (``gain``,
   ``delay``);
3. ``coupling``, 4. ``nonlinear``, 5. ``additive`` (see ``vm.effects``): the *actual* position;
6. ``sensor`` (``noise``): the *measured* position, what an encoder log holds.

Z has no FRF in a profile: it is passed through ideally (actual z = commanded z).

One seeded draw per run and axis: the paper (Sec. 5) re-samples h at every t; a single draw
is one machine of the population the FRFs describe, which is what a log from a real machine
shows and what the closed loop learns. ``seed`` fixes the draw (x and y from independent child
streams of ``numpy.random.SeedSequence(seed)``) and the sensor noise (a third stream), so
adding an effect never changes the drawn dynamics. ``nominal=True`` uses the twin's mean
response instead (``twin.physics.axis_impulse(...).mean``).

Caveat (measured, see README "Virtual machine"): the FRF coefficients are independent per
frequency bin, so a single draw has a noise tail that does not decay over the n_taps (|h| of a
few 1e-3 at 1 s for ``ender3pro``); it acts as a random lag of a few ms and dominates the
contour error of a drawn plant after fast travels.

DC gain: by default each drawn h is scaled to sum(h) = 1 (``unit_dc_gain``). A stepper or
servo axis has no steady-state position error, while an FRF estimated from accelerometers
has an uncertain low-frequency gain; an unscaled draw with sum(h) = 0.998 would put 0.2 mm of
error on a 100 mm move, which no printer shows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np
from scipy.signal import oaconvolve

from . import effects as fx
from .trajectory import Trajectory
from ..firmware.shaper import shape_axes

AXES = ("x", "y", "z")
PLANT_AXES = ("x", "y")


def respond(cmd_mm: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Shape (K,) -> (K,). Linear response x_0 + (h * (x_cmd − x_0))[:K] by overlap-add FFT
    convolution; x_0 = x_cmd[0], so the response of a constant command is that constant."""
    cmd = np.asarray(cmd_mm, dtype=float)
    if cmd.size == 0:
        return cmd.copy()
    x0 = cmd[0]
    dev = cmd - x0
    if not dev.any():
        return cmd.copy()
    return x0 + oaconvolve(dev, np.asarray(h, dtype=float))[: cmd.size]


@dataclass(frozen=True)
class PlantOutput:
    """What the plant returns.

    Attributes:
        actual_mm: shape (K, 3). True X, Y, Z position, mm (what the metrics judge).
        measured_mm: shape (K, 3). actual_mm plus sensor noise, mm (what a log holds).
        impulse: axis -> shape (n,) impulse response used (after ``response`` effects).
    """

    actual_mm: np.ndarray
    measured_mm: np.ndarray
    impulse: Mapping[str, np.ndarray] = field(default_factory=dict)


def simulate_axes(cmd_mm: np.ndarray, ts_s: float, impulse: Mapping[str, np.ndarray],
                  effects: Iterable[fx.Effect] = (), noise_rng: np.random.Generator | None = None,
                  mode_hz: Mapping[str, float] | None = None) -> PlantOutput:
    """The plant as a pure function of arrays.

    Args:
        cmd_mm: shape (K, 3). Commanded X, Y, Z at t_k = k·ts_s, mm.
        ts_s: sample period, s.
        impulse: "x", "y" -> shape (n,) impulse response per Ts sample (commanded -> actual).
        effects: unknown effects, applied by stage (``effects.STAGES``), in order within one.
        noise_rng: generator for sensor noise (required when a ``noise`` effect is given).
        mode_hz: "x", "y" -> dominant mode frequency, Hz, used by ``resonance_shift``
            (default: the peak of |H| of the given response, ``effects.dominant_mode_hz``).
    """
    cmd = np.asarray(cmd_mm, dtype=float)
    if cmd.ndim != 2 or cmd.shape[1] != 3:
        raise ValueError(f"cmd_mm must have shape (K, 3), got {cmd.shape}")
    effects = tuple(effects)
    by_stage = {s: [e for e in effects if e.stage == s] for s in fx.STAGES}
    t_s = np.arange(cmd.shape[0]) * ts_s
    mode_hz = dict(mode_hz or {})

    # 1. response effects reshape h
    h_used = {}
    for ax in PLANT_AXES:
        h = np.asarray(impulse[ax], dtype=float)
        for e in by_stage["response"]:
            if e.axis == ax:
                h = e.apply(h, ts_s, mode_hz.get(ax))
                mode_hz[ax] = e.frequency_hz
        h_used[ax] = h

    # 2. convolution, then gain and delay
    out = {}
    for i, ax in enumerate(PLANT_AXES):
        x = respond(cmd[:, i], h_used[ax])
        for e in by_stage["linear"]:
            if e.axis == ax:
                x = e.apply(x) if isinstance(e, fx.Gain) else e.apply(x, ts_s)
        out[ax] = x

    # 3. cross coupling from the stage-2 outputs (sources frozen first)
    sources = {ax: out[ax].copy() for ax in PLANT_AXES}
    for e in by_stage["coupling"]:
        out[e.axis] = e.apply(out[e.axis], sources[e.from_axis])

    # 4. nonlinear, 5. additive
    col = {ax: i for i, ax in enumerate(AXES)}
    for e in by_stage["nonlinear"]:
        if isinstance(e, fx.Backlash):
            out[e.axis] = e.apply(out[e.axis])
        else:
            out[e.axis] = e.apply(out[e.axis], cmd[:, col[e.axis]], ts_s)
    for e in by_stage["additive"]:
        if isinstance(e, fx.PeriodicTime):
            out[e.axis] = e.apply(out[e.axis], t_s)
        else:
            out[e.axis] = e.apply(out[e.axis], cmd[:, col[e.axis]])

    actual = np.column_stack([out["x"], out["y"], cmd[:, 2]])

    # 6. sensor noise on the measurement only
    measured = actual
    if by_stage["sensor"]:
        if noise_rng is None:
            raise ValueError("a noise effect needs noise_rng")
        measured = actual.copy()
        for e in by_stage["sensor"]:
            measured[:, col[e.axis]] = e.apply(measured[:, col[e.axis]], noise_rng)
    return PlantOutput(actual_mm=actual, measured_mm=measured, impulse=h_used)


class Plant:
    """A seeded machine: one draw of the profile's FRF distribution plus unknown effects.

    ``Plant(profile, seed, effects)`` draws from the profile's Gaussian impulse response
    through ``twin.physics.draw_impulses``; ``Plant.from_impulse`` takes the responses directly
    (tests, or a model identified elsewhere).
    """

    def __init__(self, profile, seed: int = 0, effects: Iterable[fx.Effect] = (), *,
                 n_taps: int | None = None, unit_dc_gain: bool = True, nominal: bool = False):
        """``nominal``: use the mean impulse response of the FRF distribution instead of a
        draw (a machine without the known uncertainty; the seed then only drives the noise)."""
        from ..twin import physics  # FRF -> h is the twin's; on use (--help loads plant: +10 ms)

        seq = np.random.SeedSequence(seed)
        draw_seq, noise_seq = seq.spawn(2)
        axis_seqs = draw_seq.spawn(len(PLANT_AXES))
        if n_taps is not None and int(n_taps) != profile.twin.n_taps:
            import dataclasses
            profile = dataclasses.replace(profile, twin=dataclasses.replace(profile.twin,
                                                                            n_taps=int(n_taps)))
        impulse = {}
        for ax, s in zip(PLANT_AXES, axis_seqs):
            if nominal:
                h = np.asarray(physics.axis_impulse(profile, ax).mean)
            else:
                h = np.asarray(physics.draw_impulses(profile, ax, np.random.default_rng(s), 1))[0]
            impulse[ax] = h
        # resonance_shift moves the peak of |H| of *this draw* (not the profile's nominal mode
        # list): the frequency a diagnosis can measure in the log lands on frequency_hz
        self._init(profile.ts_s, impulse, effects, noise_seq, unit_dc_gain, {}, seed,
                   profile.firmware.input_shaper)

    @classmethod
    def from_impulse(cls, ts_s: float, impulse: Mapping[str, np.ndarray],
                     effects: Iterable[fx.Effect] = (), seed: int = 0, *,
                     unit_dc_gain: bool = False, mode_hz: Mapping[str, float] | None = None,
                     shapers: Mapping | None = None) -> "Plant":
        """A plant from given impulse responses ("x", "y" -> shape (n,)), used as they are
        unless ``unit_dc_gain``; ``shapers`` {"x"|"y": firmware.shaper.Shaper} shape the
        commanded motion before it (the firmware's input shaper)."""
        self = cls.__new__(cls)
        noise_seq = np.random.SeedSequence(seed).spawn(2)[1]
        self._init(ts_s, impulse, effects, noise_seq, unit_dc_gain, dict(mode_hz or {}), seed,
                   shapers)
        return self

    def _init(self, ts_s, impulse, effects, noise_seq, unit_dc_gain, mode_hz, seed, shapers=None):
        self.ts_s = float(ts_s)
        #: the firmware's input shapers: the machine receives the shaped command
        self.shapers = dict(shapers or {})
        self.seed = seed
        self.effects = tuple(effects)
        self.mode_hz = mode_hz
        self._noise_seq = noise_seq
        h = {}
        for ax in PLANT_AXES:
            a = np.asarray(impulse[ax], dtype=float)
            if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)):
                raise ValueError(f"impulse[{ax!r}] must be a finite non-empty 1-D array")
            if unit_dc_gain:
                a = a / a.sum()
            h[ax] = a
        self.impulse = h

    def simulate(self, trajectory: Trajectory) -> PlantOutput:
        """Actual and measured positions for a commanded trajectory (same Ts as the plant)."""
        if not np.isclose(trajectory.ts_s, self.ts_s, rtol=1e-9, atol=0):
            raise ValueError(f"trajectory Ts={trajectory.ts_s} s differs from the plant's "
                             f"Ts={self.ts_s} s; resample the trajectory or the profile")
        rng = np.random.default_rng(self._noise_seq)
        pos = shape_axes(trajectory.pos_mm, self.ts_s, self.shapers)
        return simulate_axes(pos, self.ts_s, self.impulse, self.effects,
                             noise_rng=rng, mode_hz=self.mode_hz)

    def run(self, trajectory: Trajectory) -> np.ndarray:
        """Shape (K, 3). True actual X, Y, Z for the commanded trajectory, mm."""
        return self.simulate(trajectory).actual_mm
