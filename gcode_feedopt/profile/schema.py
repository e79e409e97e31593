"""Machine profile: frozen, typed, unit-bearing dataclasses. No file I/O here (see io.py).

One schema for every profile. Keys carry their unit in their name; every number is checked
against bounds where it is read (see io.py), with messages that name the file, the key, the
value, the limit and the fix.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = ("x", "y")


@dataclass(frozen=True)
class Limits:
    """Kinematic limits the planners respect.

    Attributes:
        vmax_mm_s: path feed cap (paper's V_max).
        amax_mm_s2: per-axis acceleration limit of X and Y used by the planners (paper's A_max).
        jmax_mm_s3: per-axis jerk limit, None for none.
        axis_vmax_mm_s, axis_amax_mm_s2: per axis ``x``, ``y``, ``z``, ``e``.
        tolerance_mm: default contour-error tolerance E_max.
        stringency: default stringency η (0.5–0.9999).
        max_volumetric_mm3_s: the hotend's melt limit, mm³/s (``--speed machine`` keeps
            every extruding move within it; None: not stated).
        filament_diameter_mm: for the volumetric limit.
        feature_tolerance_mm: E_max per slicer feature (gcode.features.FEATURES), e.g.
            ``{outer_wall: 0.05, infill: 0.3}``; features not named, and untagged files, keep
            ``tolerance_mm``; ``travel`` has none unless named. Empty: one tolerance.
        axis_jerk_mm_s: the largest instantaneous change of an axis's speed the motors and
            frame take, mm/s, ``x`` and ``y`` (what the hardware does, apart from what the
            firmware is configured to): the junctions the plan may run at (firmware.base
            .plan_junction: classic jerk ``M205 X Y``; a junction deviation or square corner
            velocity whose largest per-axis speed step stays within it), lowered by the twin
            where the tolerance needs it. None: the firmware's and the file's own junction
            settings hold.
    """

    vmax_mm_s: float
    amax_mm_s2: float
    jmax_mm_s3: float | None
    axis_vmax_mm_s: dict
    axis_amax_mm_s2: dict
    tolerance_mm: float
    stringency: float
    max_volumetric_mm3_s: float | None = None
    filament_diameter_mm: float = 1.75
    feature_tolerance_mm: dict = field(default_factory=dict)
    axis_jerk_mm_s: dict | None = None


@dataclass(frozen=True)
class Firmware:
    """What the machine's firmware does with the G-code we write.

    Attributes:
        flavour: ``marlin`` or ``klipper``.
        g91_relative_e: Marlin semantics: G90/G91 also switch E until the next M82/M83.
        accel_mm_s2, travel_accel_mm_s2: default print and travel acceleration (M204 P/T).
        max_accel_mm_s2, max_feed_mm_s: per-axis maxima (M201, M203), keys x y z e.
        junction_deviation_mm: Marlin's junction deviation.
        square_corner_velocity_mm_s: Klipper's square corner velocity.
        minimum_cruise_ratio: Klipper's minimum_cruise_ratio (1 − max_accel_to_decel/accel).
        mm_per_arc_segment: the firmware's arc segment length (G2/G3 are split into lines).
        max_lines_per_s: how many motion lines per second the firmware can take (planner
            buffer / serial bandwidth); the writer never emits more.
        retract_mm, retract_speed_mm_s: firmware retraction (G10/G11).
        instantaneous_corner_velocity_mm_s: Klipper's extruder instantaneous_corner_velocity:
            at a junction the extruder's speed changes by at most this (Klipper's default 1).
        configured_accel_mm_s2, configured_max_accel_mm_s2: what the printer's firmware is
            configured to before a file runs, where that is below the values above (which
            the plan is timed with): M204 P/T and M201 X/Y (Klipper: its one accel; None:
            the firmware runs the values above). The writer then sets the values above
            before the first re-timed move and restores these after the last one, so a
            printer as its owner configured it runs what was planned.
        input_shaper: axis ("x", "y") -> firmware.shaper.Shaper the firmware applies to that
            axis's planned motion (Klipper's [input_shaper], Marlin's M593); none: the
            machine receives the plan as it is. The FRFs describe the machine without it
            (Klipper's TEST_RESONANCES turns it off); the twin's input is the shaped plan.
    """

    flavour: str
    g91_relative_e: bool
    accel_mm_s2: float
    travel_accel_mm_s2: float
    max_accel_mm_s2: dict
    max_feed_mm_s: dict
    junction_deviation_mm: float
    square_corner_velocity_mm_s: float
    minimum_cruise_ratio: float
    mm_per_arc_segment: float
    max_lines_per_s: float
    retract_mm: float
    retract_speed_mm_s: float
    instantaneous_corner_velocity_mm_s: float = 1.0
    configured_accel_mm_s2: float | None = None
    configured_max_accel_mm_s2: dict | None = None
    input_shaper: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FRFSet:
    """N_H measured frequency responses of one axis, commanded → actual position.

    Attributes:
        freq_hz: (K,) frequency grid, Hz, ascending, starting at 0 (DC).
        response: (N_H, K) complex, dimensionless.
        labels: N_H names (file names or measurement ids).
    """

    freq_hz: np.ndarray
    response: np.ndarray
    labels: tuple = ()

    @property
    def n_measurements(self) -> int:
        return int(self.response.shape[0])


@dataclass(frozen=True)
class Mode:
    """One structural mode: natural frequency, damping ratio, modal gain."""

    freq_hz: float
    damping: float
    gain: float = 1.0


@dataclass(frozen=True)
class Prior:
    """Learned prior of the twin's regression weights for one axis.

    Attributes:
        mu: (n,) mean. cov: (n, n) covariance.
        learned_from: list of records (what data, when, how).
    """

    mu: np.ndarray
    cov: np.ndarray
    learned_from: tuple = ()


@dataclass(frozen=True)
class AxisModel:
    """One axis: its measured FRF set, the modes a generator or fit reported, provenance, and
    the extensions a diagnosis added (``effects``: dicts ``{"kind", "params"}`` of the
    catalogue's linear kinds — ``delay`` {delay_s}, ``gain`` {scale}, ``resonance_shift``
    {frequency_hz} — which ``twin.physics`` applies to every fitted model of the axis)."""

    frf: FRFSet | None
    modes: tuple = ()
    provenance: dict = field(default_factory=dict)
    effects: tuple = ()


@dataclass(frozen=True)
class TwinSettings:
    """Settings of the digital twin (paper Sec. 3).

    Attributes:
        n2, n3: feature orders (past x̂ samples, past prediction errors).
        sigma_eps_mm: σ_ε, the unobserved noise.
        coef_variance: ``minmax`` (paper Eq. 9, 3σ = half the min–max range), ``sample``, or ``ensemble`` (sample covariance of the N_H measured impulse responses, twin.frf.ensemble_impulse_response; the built-ins use it).
        n_taps: impulse-response length used by the twin.
        priors: axis -> Prior (absent when not learned yet).
        physics: ``modal`` (each FRF fitted with a continuous-time modal model, twin.modal; the
            default) or ``bins`` (the raw FRF bins, paper Eqs. 9–11, ``coef_variance``).
        dc_gain: ``unit`` (H(0) = 1 exactly: a position axis at rest sits at its command) or
            ``fitted`` (the data's own low-frequency gain).
    """

    n2: int
    n3: int
    sigma_eps_mm: float
    coef_variance: str
    n_taps: int
    priors: dict = field(default_factory=dict)
    physics: str = "modal"
    dc_gain: str = "unit"


@dataclass(frozen=True)
class MachineProfile:
    name: str
    description: str
    ts_s: float
    limits: Limits
    firmware: Firmware
    axes: dict
    twin: TwinSettings
    provenance: dict
    source_path: str | None = None
