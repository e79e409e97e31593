"""Coverage of the twin's 95 % interval on plants drawn from the profile's own FRF
distribution (the twin issue's done-when), without and with online learning.

    python benchmarks/twin_calibration.py [--plants-nolearn 400] [--plants-learn 20]

Butterfly at the kinematic plan of ender3pro (70 mm/s, 3 m/s²); measured = true + N(0, σ_ε²).
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np
from scipy.signal import oaconvolve

from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_file
from gcode_feedopt.plan.kinematic import plan_kinematic
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.frf import draw_impulse_responses
from gcode_feedopt.twin.model import axis_twin

REPO = pathlib.Path(__file__).resolve().parents[1]
Z95 = 1.959964


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants-nolearn", type=int, default=400)
    ap.add_argument("--plants-learn", type=int, default=20)
    a = ap.parse_args()
    prof = load_profile("ender3pro")
    path = build_path(read_file(REPO / "sample_gcode" / "butterfly.gcode"))
    pos = path.position(plan_kinematic(path, prof).s_mm)
    sig = prof.twin.sigma_eps_mm
    print(f"{'axis':4s} {'learning':8s} {'plants':>6s} {'inside 95 %':>11s} {'late std mm':>11s}")
    for k, axis in enumerate("xy"):
        x_cmd = pos[:, k]
        rng = np.random.default_rng(11 + k)
        H = draw_impulse_responses(prof.axes[axis].frf, prof.ts_s, prof.twin.n_taps, rng,
                                   max(a.plants_nolearn, a.plants_learn),
                                   method=prof.twin.coef_variance)

        def meas(h):
            xt = x_cmd[0] + oaconvolve(x_cmd - x_cmd[0], h)[:x_cmd.size]
            return xt + sig * rng.standard_normal(x_cmd.size)

        tw = axis_twin(prof, axis)
        tw.cov[:] = 0.0
        mean, std = tw.run(x_cmd, None, learn=False)
        ins = [np.abs(meas(h) - mean) <= Z95 * std for h in H[:a.plants_nolearn]]
        print(f"{axis:4s} {'no':8s} {a.plants_nolearn:6d} {100 * np.mean(ins):10.1f}% "
              f"{np.median(std[-1000:]):11.4f}")
        ins, late = [], []
        for h in H[:a.plants_learn]:
            xm = meas(h)
            tw = axis_twin(prof, axis)
            m, s = tw.run(x_cmd, xm, learn=True)
            ins.append(np.abs(xm - m) <= Z95 * s)
            late.append(np.median(s[-1000:]))
        print(f"{axis:4s} {'yes':8s} {a.plants_learn:6d} {100 * np.mean(ins):10.1f}% "
              f"{np.median(late):11.4f}")


if __name__ == "__main__":
    main()
