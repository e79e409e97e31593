"""The run report: what was done, in figures, as JSON (``--report``) and as a short human
summary on stderr."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field



def hms(t: float) -> str:
    """A duration as the summary and the batch table write it: ``5m57s``, ``1h35m57s``
    (rounded to the second once, so 359.6 s is 6m00s, never 5m60s)."""
    t = int(round(t))
    h, r = divmod(t, 3600)
    m, s = divmod(r, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"

@dataclass
class Report:
    """Figures of one run. Times in seconds, errors in mm."""

    input: str
    output: str | None
    machine: str
    method: str
    mode: str
    tolerance_mm: float
    stringency: float
    moves: int
    moves_changed: int
    lines_in: int
    lines_written: int
    input_time_s: float
    output_time_s: float
    plan_time_s: float
    time_source: str
    #: speed policy (plan.speed): ``slicer`` — no move above its sliced F — or ``machine``
    speed: str = "slicer"
    #: acceleration policy (firmware.ACCELS): ``plan`` — the plan's accelerations override
    #: lower ones the file sets — or ``file``
    accel: str = "plan"
    dry_run: bool = False
    predicted_max_contour_error_mm: float | None = None
    predicted_p95_contour_error_mm: float | None = None
    #: the expected share of the constrained samples within tolerance under the twin
    #: (optimize.slowdown.budget; the stringency is this share)
    predicted_within_fraction: float | None = None
    stage_wall_s: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    @property
    def saved_pct(self) -> float:
        if self.input_time_s <= 0:
            return 0.0
        return 100.0 * (self.input_time_s - self.output_time_s) / self.input_time_s

    def to_dict(self) -> dict:
        d = asdict(self)
        d["saved_pct"] = round(self.saved_pct, 3)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, default=float)

    def _and_junctions(self) -> str:
        """The words ' and junctions' where the plan's junctions differ from the file's and
        the firmware's (the time split's junctions term; firmware.plan_junction)."""
        sp = (self.extra or {}).get("time_split_s") or {}
        return " and junctions" if sp.get("junctions") else ""

    def summary(self) -> str:
        """A few lines a person reads at a glance."""
        lines = [f"gcode-feedopt: {self.input}: {hms(self.input_time_s)} -> {hms(self.output_time_s)} "
                 f"({self.saved_pct:+.1f} % saved; {self.time_source})",
                 f"  method {self.method}, machine {self.machine}, speed {self.speed}"
                 f"{' (no move above its sliced F)' if self.speed == 'slicer' else ''}, "
                 f"accel {self.accel}"
                 + (f" (the plan's accelerations{self._and_junctions()} over the file's)"
                    if self.accel == "plan" else " (the file's own accelerations and junctions kept)")
                 + f", {self.moves_changed} of "
                 f"{self.moves} moves re-timed, {self.lines_written} lines written"
                 + (" (dry run: nothing written)" if self.dry_run else "")]
        if self.predicted_max_contour_error_mm is not None:
            lines.append(f"  predicted contour error: worst {self.predicted_max_contour_error_mm:.3f} mm, "
                         f"95th percentile {self.predicted_p95_contour_error_mm:.3f} mm "
                         + (f"(tolerance per feature, {self.tolerance_mm:g} mm elsewhere, at "
                            f"{self.stringency:.0%})" if (self.extra or {}).get("feature_tolerance_mm")
                            else f"(tolerance {self.tolerance_mm:g} mm at {self.stringency:.0%})")
                         + (f"; {self.predicted_within_fraction:.1%} of samples expected within"
                            if self.predicted_within_fraction is not None else ""))
        else:
            lines.append(f"  predicted contour error: n/a ({self.method} plans kinematic limits only; "
                         f"tolerance {self.tolerance_mm:g} mm not checked)")
        ex = (self.extra or {}).get("executed")
        if ex:
            lines.append(f"  executed (firmware model + nominal plant): {ex['time_s']:.2f} s vs plan "
                         f"{self.plan_time_s:.2f} s; contour error worst {ex['max_contour_error_mm']:.3f} mm, "
                         f"95th percentile {ex['p95_contour_error_mm']:.3f} mm, "
                         f"{ex['within_fraction']:.1%} within tolerance")
        sp = (self.extra or {}).get("time_split_s")
        if sp and any(abs(v) >= 0.05 for v in sp.values()):
            lines.append(
                f"  where the time went (s; − saved): limits {sp['limits']:+.1f} (as configured"
                + (", the file's accelerations" if (self.extra or {}).get(
                    "accel_override_lines") else "")
                + f" → the plan's), feed {sp['feed']:+.1f}"
                + (" (--speed machine)" if self.speed == "machine" else " (sliced F kept)")
                + f", junctions {sp['junctions']:+.1f}"
                + (" (the file's → the plan's)" if sp["junctions"] else " (the firmware's rule kept)")
                + ", twin "
                f"{sp['twin']:+.1f} (slow-downs where the tolerance needs them), firmware vs "
                f"plan {sp['firmware_vs_plan']:+.1f}")
        feats = (self.extra or {}).get("features")
        if feats:
            lines.append("  per feature (plan s / worst / p95 mm): " + "; ".join(
                f"{k} {v['plan_time_s']:.0f} s / {v['predicted_max_contour_error_mm']:.3f} / "
                f"{v['predicted_p95_contour_error_mm']:.3f}"
                + (f" (tol {v['tolerance_mm']:g})" if v.get("tolerance_mm") else "")
                for k, v in feats.items() if k != "travel"))
        for n in self.notes:
            lines.append(f"  note: {n}")
        return "\n".join(lines)
