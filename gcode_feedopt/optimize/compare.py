"""The paper's comparison (Sec. 5, Table 1, Fig. 12) on the virtual machine: every method on
the same plant (same seed, same unknown effects), executed and measured the same way.

Pure orchestration over optimize.methods and vm: no files, no printing. ``run_compare``
returns one ``MethodRun`` per method with the Table 1 columns and the time series for the
figure.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..vm.metrics import contour_error_mm, evaluate
from .methods import METHODS, TWIN_METHODS, make_twin_predictor, plan_mpc, plan_schedule, \
    vm_trajectory
from .predictors import PlantPredictor

#: online by default: the paper's experiment learns between windows while the plan runs.
ONLINE_METHODS = ("dd", "pidd")


@dataclass
class MethodRun:
    method: str
    cycle_time_s: float
    #: time on the evaluated samples (the extruded contour; the whole run for a CNC job): the
    #: paper's cycle time of the butterfly, without the approach travel every method shares
    contour_time_s: float
    rms_gamma_um: float
    within_fraction: float
    max_contour_error_mm: float
    prediction_rms_mm: dict
    compute_s: float
    info: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict)

    def row(self) -> dict:
        return {"method": self.method, "cycle_time_s": round(self.cycle_time_s, 4),
                "contour_time_s": round(self.contour_time_s, 4),
                "rms_gamma_um": round(self.rms_gamma_um, 3),
                "within_fraction": round(self.within_fraction, 5),
                "max_contour_error_mm": round(self.max_contour_error_mm, 5),
                "prediction_rms_x_mm": _r(self.prediction_rms_mm.get("x")),
                "prediction_rms_y_mm": _r(self.prediction_rms_mm.get("y")),
                "compute_s": round(self.compute_s, 3),
                "fallback_windows": self.info.get("fallback_windows", 0),
                "relaxed_windows": self.info.get("relaxed_windows", 0)}


def _r(v):
    return None if v is None else round(float(v), 6)


def run_method(method, path, profile, plant, *, tolerance_mm, stringency, vmax_mm_s=None,
               amax_mm_s2=None, settings=None, online=True) -> MethodRun:
    """Plan ``method`` (tuned on / learning from / knowing ``plant`` as the method allows),
    execute the plan on ``plant`` and measure it."""
    t0 = time.perf_counter()
    predictor = None
    if method in TWIN_METHODS or method == "oracle":
        predictor = PlantPredictor(plant) if method == "oracle" else \
            make_twin_predictor(profile, method, learn=online and method in ONLINE_METHODS)
        sched = plan_mpc(path, profile, predictor, method=method, tolerance_mm=tolerance_mm,
                         stringency=stringency, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                         settings=settings, plant=plant,
                         online=online and method in TWIN_METHODS)
    else:
        sched = plan_schedule(method, path, profile, tolerance_mm=tolerance_mm,
                              stringency=stringency, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                              plant=plant)
    compute = time.perf_counter() - t0
    tr = vm_trajectory(path, sched.s_mm, sched.ts_s)
    out = plant.simulate(tr)
    pred = None
    if predictor is not None and hasattr(predictor, "pred_mean") \
            and len(predictor.pred_mean[0]) == tr.n_samples:
        pred = np.column_stack([np.asarray(predictor.pred_mean[0]),
                                np.asarray(predictor.pred_mean[1])])
    m = evaluate(tr, out.actual_mm, tolerance_mm,
                 predicted_mm=None if pred is None else np.column_stack([pred, tr.pos_mm[:, 2]]))
    md = m.to_dict()
    pr = {}
    if pred is not None:
        err = pred - out.actual_mm[:, :2]
        pr = {"x": float(np.sqrt(np.mean(err[:, 0] ** 2))),
              "y": float(np.sqrt(np.mean(err[:, 1] ** 2)))}
    eps = contour_error_mm(tr.pos_mm, out.actual_mm, tr.ts_s)
    v = np.gradient(sched.s_mm, sched.ts_s)
    xy = tr.pos_mm[:, :2]
    acc = np.gradient(np.gradient(xy, sched.ts_s, axis=0), sched.ts_s, axis=0)
    series = {"t_s": np.arange(sched.s_mm.size) * sched.ts_s, "feed_mm_s": v,
              "acc_x_mm_s2": acc[:, 0], "acc_y_mm_s2": acc[:, 1],
              "contour_error_mm": eps}
    if pred is not None:
        series["pred_err_x_mm"] = pred[:, 0] - out.actual_mm[:, 0]
        series["pred_err_y_mm"] = pred[:, 1] - out.actual_mm[:, 1]
    return MethodRun(method=method, cycle_time_s=float(md["cycle_time_s"]),
                     contour_time_s=float(md["n_evaluated"]) * tr.ts_s,
                     rms_gamma_um=1000.0 * float(md["rms_gamma_mm"]),
                     within_fraction=float(md["within_fraction"]),
                     max_contour_error_mm=float(md["max_contour_error_mm"]),
                     prediction_rms_mm=pr, compute_s=compute,
                     info={k: v for k, v in sched.info.items()
                           if isinstance(v, (int, float, str, bool))}, series=series)


def run_compare(path, profile, plant, *, methods=METHODS, tolerance_mm, stringency,
                vmax_mm_s=None, amax_mm_s2=None, settings=None, online=True):
    return [run_method(m, path, profile, plant, tolerance_mm=tolerance_mm,
                       stringency=stringency, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                       settings=settings, online=online) for m in methods]
