"""What a run asks the planners for, resolved once from the machine profile and the options.

The options leave most values to the profile (no ``--tolerance``: the profile's E_max; no
``--stringency``: its η; ``--feature-tolerance`` over its per-feature table); a
:class:`PlanRequest` holds the values in force, so every stage of a run (pipeline.py: the
plan, the input's time, the report, the ident line; cli/compare.py) reads the same ones.
The firmware's limits of the file (firmware.Replay.move_limits) stay a separate argument: they
come from the file's own lines, not from the options.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .speed import plan_vmax


@dataclass(frozen=True)
class PlanRequest:
    """The planning settings of one run.

    Attributes:
        method: optimize.METHODS (kinematic, conservative, pb, dd, pidd, oracle); None when
            a run plans several (``compare``).
        tolerance_mm: the scalar E_max, mm (``--tolerance`` or the profile's).
        feature_tolerance_mm: {feature: E_max mm} over the scalar (gcode.features; the
            profile's limits.feature_tolerance_mm updated by ``--feature-tolerance``); {}: one
            tolerance for every move.
        stringency: η, the fraction of samples that must be within the tolerance.
        speed: plan.speed.SPEEDS, the speed policy (``slicer`` or ``machine``).
        vmax_mm_s, amax_mm_s2: ``--vmax`` and ``--amax`` as given (None: the profile's).
        plan_vmax_mm_s: the V_max the planners get under the speed policy
            (plan.speed.plan_vmax); None: the profile's.
        use_slicer_feed: never faster than a move's sliced F (the planners see each move's
            ceiling under the speed policy as its feed).
    """

    method: str | None
    tolerance_mm: float
    stringency: float
    feature_tolerance_mm: dict = field(default_factory=dict)
    speed: str = "slicer"
    vmax_mm_s: float | None = None
    amax_mm_s2: float | None = None
    plan_vmax_mm_s: float | None = None
    use_slicer_feed: bool = False

    @classmethod
    def of(cls, profile, *, method: str | None = None, tolerance_mm: float | None = None,
           stringency: float | None = None, feature_tolerance: dict | None = None,
           speed: str = "slicer", vmax_mm_s: float | None = None,
           amax_mm_s2: float | None = None, use_slicer_feed: bool = True) -> PlanRequest:
        """The request of options as given (None: the profile's value) on ``profile``."""
        return cls(method=method,
                   tolerance_mm=tolerance_mm or profile.limits.tolerance_mm,
                   stringency=stringency or profile.limits.stringency,
                   feature_tolerance_mm=feature_tolerance_map(profile, feature_tolerance),
                   speed=speed, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                   plan_vmax_mm_s=plan_vmax(profile, speed, vmax_mm_s),
                   use_slicer_feed=use_slicer_feed)

    @classmethod
    def from_options(cls, profile, opts) -> PlanRequest:
        """The request of a run of ``opts`` (pipeline.Options) on ``profile``."""
        return cls.of(profile, method=opts.method, tolerance_mm=opts.tolerance_mm,
                      stringency=opts.stringency, feature_tolerance=opts.feature_tolerance,
                      speed=opts.speed, vmax_mm_s=opts.vmax_mm_s, amax_mm_s2=opts.amax_mm_s2)


def feature_tolerance_map(profile, given: dict | None) -> dict:
    """{feature: mm} in force: the profile's, updated by ``given`` (--feature-tolerance;
    None: the profile's; {} turns per-feature tolerances off)."""
    if given is not None and not given:
        return {}
    return {**profile.limits.feature_tolerance_mm, **(given or {})}
