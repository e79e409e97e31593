"""Foreign machines: plants whose physics this project's simulator (``vm/``) does not share.

Issue 19: a twin checked only against our own simulator proves little. This module writes
labelled data sets in the layout of ``../shared/data/independent/`` (benchA) — ``frf/x_*.csv``,
``frf/y_*.csv`` (``freq_hz,real,imag``), ``logs/log_NN.csv`` (``t,x_cmd,y_cmd,x,y``) and
``labels.json`` — for machines drawn at random from structures the twin was not written for:

``belt_frame``   rotor lag → belt → carriage, the motor riding on a sprung frame (benchA's kind,
                 with other masses, stiffnesses and damping);
``belt_hotend``  the same plus a hotend on a flexible mount; the sensor is on the nozzle, so the
                 response has a third mode and an anti-resonance;
``servo_screw``  a CNC axis: PID position loop (no feed-forward) on the motor, a lead screw to
                 the table — a lag-dominated closed loop, not a lightly damped resonance;
``corexy``       two belt channels A, B with mismatched stiffness, x = (A + B)/2, y = (A − B)/2:
                 each axis's FRF is the mean of two near modes, and each axis moves a little
                 with the other's command (a cross-talk the per-axis twin does not model).

Any of them may carry a pure transport delay (a drive's step pipeline or fieldbus cycle) in the
commanded path, which no modal model of the form the twin fits reproduces above a few tens of Hz.

The known uncertainty is what it is on a real machine: every FRF measurement is of the same
machine at another excitation level (mild softening) with independent parameter scatter
(fixtures, temperature) and 1–3 % complex noise, on a random grid (start 1–5 Hz, steps
0.5–2 Hz, end 150–240 Hz, no 0 Hz bin). The plant that writes the logs is one more draw of the
same scatter: a plant "inside the spread".

Simulation is exact for the command as the firmware sends it (linear between samples): each
linear channel is discretised with a first-order hold at Ts/R (R = 20) and stepped; the delay is
a whole number of fine steps. The sensor quantises and adds white noise. Nothing here imports
``gcode_feedopt``: the generator and the twin share no code.

A machine may print through its firmware's input shaper (``with_shaper``: ZV, ZVD or MZV at
each axis's dominant mode, Klipper's centred pulses or causal ones): the logs' commands are the
planner's, the motors receive Σ aᵢ u(t − tᵢ) on the fine grid (``shaper_pulses``, written here
apart from the package's); the FRFs stay the machine's own (a resonance test runs unshaped).

Effects (labels follow the project's catalogue, as benchA's): ``delay`` (motor command late),
``gain`` (command scaled about 0 mm), ``periodic_time`` (sinusoidal force on the frame / table,
labelled with the resulting carriage amplitude), ``resonance_shift`` (carriage / table mass ×
1.25–1.4, labelled with the new dominant frequency). ``write_dataset(..., more_effects=True)``
appends the drive's effects, from a random stream of their own (every other file unchanged):
``backlash`` (a dead band between motor and belt / screw), ``periodic_position`` (an eccentric
pulley / screw), ``friction`` (a Coulomb force on the carriage / table) and, not on a corexy,
``cross_coupling`` (the other axis's acceleration pushing the frame / table): ``_more_effects``
states each form and label. ``variants=True`` appends effects in forms those logs do not
have (``_variant_effects``: a fan switched on during the log, two eccentricities on one axis,
and benchA's friction of the carriage's own velocity). benchmarks/foreign_effects.py judges
the diagnosis on them.
"""

from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

KINDS = ("belt_frame", "belt_hotend", "servo_screw", "corexy")
#: sub-steps per log sample of the simulation
R = 20
BENCH_A = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "independent"


# ---------------------------------------------------------------------------- channel models
@dataclass
class Channel:
    """One SISO mechanical chain: physical parameters (SI) of its kind."""

    kind: str
    p: dict

    def scaled(self, **factors) -> "Channel":
        q = dict(self.p)
        for k, f in factors.items():
            if k in q:
                q[k] = q[k] * f
        return Channel(self.kind, q)

    def ss(self, force_on: str = "frame"):
        """(A, B, C): x' = A x + B [u, w], y = C x; u commanded position, w force on the
        frame (belt kinds) or table (servo), N; y the sensed position. DC gain u→y is 1.
        ``force_on="carriage"``: w acts on a belt kind's carriage instead (friction); the
        servo's force is on its table either way."""
        p = self.p
        if self.kind in ("belt_frame", "belt_hotend"):
            tau, m, k, c = p["tau"], p["m"], p["k"], p["c"]
            mf, kf, cf = p["mf"], p["kf"], p["cf"]
            hot = self.kind == "belt_hotend"
            n = 7 if hot else 5
            # states: xr, xc, vc, xf, vf, [xh, vh]
            A = np.zeros((n, n))
            B = np.zeros((n, 2))
            A[0, 0] = -1 / tau
            B[0, 0] = 1 / tau
            # belt force fb = k (xr + xf − xc) + c (xr' + vf − vc), xr' = (u − xr)/tau
            fb = np.zeros(n)
            fb[0] = k - c / tau
            fb[3] = k
            fb[1] = -k
            fb[4] = c
            fb[2] = -c
            fbu = c / tau
            A[1, 2] = 1
            A[2] += fb / m
            B[2, 0] += fbu / m
            A[3, 4] = 1
            A[4] += -fb / mf
            A[4, 3] += -kf / mf
            A[4, 4] += -cf / mf
            B[4, 0] += -fbu / mf
            if force_on == "carriage":
                B[2, 1] = 1 / m
            else:
                B[4, 1] = 1 / mf
            C = np.zeros(n)
            if hot:
                mh, kh, ch = p["mh"], p["kh"], p["ch"]
                A[5, 6] = 1
                # hotend force fh = kh (xc − xh) + ch (vc − vh)
                fh = np.zeros(n)
                fh[1], fh[5], fh[2], fh[6] = kh, -kh, ch, -ch
                A[6] += fh / mh
                A[2] += -fh / m
                C[5] = 1
            else:
                C[1] = 1
            return A, B, C
        if self.kind == "servo_screw":
            J, m, k, c = p["J"], p["m"], p["k"], p["c"]
            kp, kd, ki = p["kp"], p["kd"], p["ki"]
            # states: th, om, xt, vt, I ; e = u − th ; F = kp e − kd om + ki I
            A = np.zeros((5, 5))
            B = np.zeros((5, 2))
            A[0, 1] = 1
            A[1, 0] = (-kp - k) / J
            A[1, 1] = (-kd - c) / J
            A[1, 2] = k / J
            A[1, 3] = c / J
            A[1, 4] = ki / J
            B[1, 0] = kp / J
            A[2, 3] = 1
            A[3, 0] = k / m
            A[3, 1] = c / m
            A[3, 2] = -k / m
            A[3, 3] = -c / m
            B[3, 1] = 1 / m
            A[4, 0] = -1
            B[4, 0] = 1
            C = np.zeros(5)
            C[2] = 1
            return A, B, C
        raise ValueError(self.kind)

    def frf(self, f_hz, inp: int = 0, force_on: str = "frame") -> np.ndarray:
        A, B, C = self.ss(force_on)
        s = 2j * np.pi * np.asarray(f_hz, dtype=float)
        eye = np.eye(A.shape[0])
        return np.array([C @ np.linalg.solve(si * eye - A, B[:, inp]) for si in s])

    def compliance(self, force_on: str = "frame") -> float:
        """Static displacement of the sensed position per unit force (mm per kg·mm/s², i.e.
        1/stiffness in SI) on the frame / carriage; for the servo, of the loop without its
        integral action (1/kp + 1/k: the integrator takes a steady force out in ~ki/kp)."""
        if self.kind == "servo_screw":
            return 1 / self.p["kp"] + 1 / self.p["k"]
        A, B, C = self.ss(force_on)
        return float(-C @ np.linalg.solve(A, B[:, 1]))

    def modes(self):
        """[(f_n Hz, ζ)] of the complex pole pairs, ascending."""
        A, _, _ = self.ss()
        lam = np.linalg.eigvals(A)
        lam = lam[lam.imag > 1e-6]
        out = sorted((abs(v) / (2 * math.pi), -v.real / abs(v)) for v in lam)
        return out

    def dominant_hz(self) -> float:
        """Undamped frequency of the pole pair nearest the FRF's magnitude peak (the peak's
        own frequency when every pole is real: a servo loop damped past critical, seed 347)."""
        f = np.arange(5.0, 400.0, 0.05)
        fp = f[np.argmax(np.abs(self.frf(f)))]
        return min(((abs(fn - fp), fn) for fn, _ in self.modes()), default=(0.0, float(fp)))[1]


# ---------------------------------------------------------------------------- machines
@dataclass
class Machine:
    seed: int
    kind: str
    chans: dict            # axis (x/y) or motor (a/b) -> Channel
    delay_s: float         # transport delay of the whole command path
    sensor_q_mm: float
    sensor_noise_mm: float
    frf_grid: tuple        # (start, stop, step)
    frf_noise: float
    n_meas: int
    scatter: float         # relative RMS scatter of stiffnesses between measurements
    extras: dict = field(default_factory=dict)
    #: the firmware's input shaper per axis, as a printer's configuration states it:
    #: {"x"|"y": {"type": "zv"|"zvd"|"mzv", "freq_hz", "damping_ratio", "centred"}}
    shapers: dict = field(default_factory=dict)

    def describe(self) -> str:
        ch = self.chans
        fs = {a: ", ".join(f"{f:.1f} Hz ζ {z:.3f}" for f, z in c.modes()[:3]) for a, c in ch.items()}
        return (f"seed {self.seed} {self.kind}: " + "; ".join(f"{a}: {v}" for a, v in fs.items())
                + f"; delay {1e3 * self.delay_s:.1f} ms; FRFs {self.n_meas} on "
                f"{self.frf_grid[0]:g}–{self.frf_grid[1]:g} Hz step {self.frf_grid[2]:g}, "
                f"{100 * self.frf_noise:.1f} % noise; sensor q {1e3 * self.sensor_q_mm:.2f} µm, "
                f"σ {1e3 * self.sensor_noise_mm:.2f} µm"
                + "".join(f"; {a} shaped {c['type']} {c['freq_hz']:g} Hz"
                          f"{' centred' if c['centred'] else ''}"
                          for a, c in sorted(self.shapers.items())))


def _belt(rng, hot: bool):
    m = rng.uniform(0.3, 1.6)
    f1 = rng.uniform(25, 70)
    z1 = rng.uniform(0.025, 0.12)
    mf = m * rng.uniform(0.8, 3.0)
    f2 = f1 * rng.uniform(1.8, 4.0)
    z2 = rng.uniform(0.03, 0.1)
    k = m * (2 * math.pi * f1) ** 2
    kf = mf * (2 * math.pi * f2) ** 2
    p = dict(tau=rng.uniform(1e-4, 1e-3), m=m, k=k, c=2 * z1 * math.sqrt(k * m),
             mf=mf, kf=kf, cf=2 * z2 * math.sqrt(kf * mf))
    if hot:
        mh = rng.uniform(0.03, 0.15)
        fh = rng.uniform(60, 160)
        kh = mh * (2 * math.pi * fh) ** 2
        p.update(mh=mh, kh=kh, ch=2 * rng.uniform(0.02, 0.08) * math.sqrt(kh * mh))
    return Channel("belt_hotend" if hot else "belt_frame", p)


def _servo(rng):
    J = rng.uniform(0.5, 2.0)          # motor + screw inertia as a linear mass, kg
    m = rng.uniform(2.0, 10.0)         # table
    fs = rng.uniform(60, 180)          # screw / table mode
    k = m * (2 * math.pi * fs) ** 2
    c = 2 * rng.uniform(0.02, 0.08) * math.sqrt(k * m)
    wc = 2 * math.pi * rng.uniform(20, 60)  # position loop bandwidth
    M = J + m
    kp = M * wc ** 2
    kd = 2 * rng.uniform(0.5, 0.9) * M * wc
    ki = kp * wc / rng.uniform(4, 10)
    return Channel("servo_screw", dict(J=J, m=m, k=k, c=c, kp=kp, kd=kd, ki=ki))


def make_machine(seed: int, kind: str | None = None) -> Machine:
    rng = np.random.default_rng(seed)
    kind = kind or KINDS[int(rng.integers(len(KINDS)))]
    if kind == "servo_screw":
        chans = {"x": _servo(rng), "y": _servo(rng)}
    elif kind == "corexy":
        a = _belt(rng, False)
        chans = {"a": a, "b": a.scaled(k=rng.uniform(0.9, 0.97), c=rng.uniform(0.85, 1.1))}
    else:
        chans = {ax: _belt(rng, kind == "belt_hotend") for ax in "xy"}
    delay = float(rng.choice([0.0, 0.0, round(rng.uniform(0.3, 2.0), 1)])) * 1e-3
    start = float(rng.choice([1.0, 1.5, 2.0, 3.0, 5.0]))
    step = float(rng.choice([0.5, 1.0, 2.0]))
    stop = float(rng.choice([150.0, 200.0, 229.5, 240.0]))
    return Machine(seed=seed, kind=kind, chans=chans, delay_s=delay,
                   sensor_q_mm=rng.uniform(0.5, 2.5) * 1e-3,
                   sensor_noise_mm=rng.uniform(0.2, 2.0) * 1e-3,
                   frf_grid=(start, stop, step), frf_noise=rng.uniform(0.01, 0.03),
                   n_meas=int(rng.integers(3, 9)), scatter=rng.uniform(0.005, 0.03))


def with_shaper(mach: Machine, kind: str = "mzv", centred: bool = True,
                damping: float = 0.1) -> Machine:
    """The machine printing through an input shaper on both axes, each tuned to the axis's
    dominant mode (as a user sets it from a resonance test). Its FRFs stay the machine's
    (Klipper's TEST_RESONANCES turns the shaper off); its logs are prints, shaped."""
    import dataclasses
    sh = {ax: {"type": kind, "freq_hz": round(float(_axis_dominant(mach.chans, ax)), 1),
               "damping_ratio": damping, "centred": centred} for ax in "xy"}
    return dataclasses.replace(mach, shapers=sh)


def shaper_pulses(cfg: dict) -> tuple:
    """(amplitudes, times s) of a configured shaper: the zero-vibration trains (Singer &
    Seering; the modified ZV with pulses at 0, 3/8 and 3/4 of the damped period), written
    here apart from the package's, centred on their mean time when the firmware does so."""
    z, f = cfg["damping_ratio"], cfg["freq_hz"]
    wd_period = 1.0 / (f * math.sqrt(1 - z * z))
    if cfg["type"] == "mzv":
        K = math.exp(-0.75 * z * math.pi / math.sqrt(1 - z * z))
        c = 1 - math.sqrt(0.5)
        a = np.array([c, (math.sqrt(2) - 1) * K, c * K * K])
        t = wd_period * np.array([0.0, 0.375, 0.75])
    else:
        K = math.exp(-z * math.pi / math.sqrt(1 - z * z))
        a = np.array([1.0, K]) if cfg["type"] == "zv" else np.array([1.0, 2 * K, K * K])
        t = wd_period * np.arange(a.size) * 0.5
    a = a / a.sum()
    return a, (t - a @ t if cfg["centred"] else t)


def _stiff_keys(ch: Channel):
    return [k for k in ("k", "kf", "kh", "kp") if k in ch.p]


def draw_factors(mach: Machine, rng, softening: float = 1.0) -> dict:
    """One draw of the machine as factors: every stiffness × (1 + scatter·N), the main belt /
    screw also × ``softening``; channel -> {parameter: factor}."""
    out = {}
    for name, ch in mach.chans.items():
        f = {k: 1 + mach.scatter * rng.standard_normal() for k in _stiff_keys(ch)}
        f["k"] = f.get("k", 1.0) * softening
        out[name] = f
    return out


def apply_factors(mach: Machine, factors: dict) -> dict:
    return {name: ch.scaled(**factors[name]) for name, ch in mach.chans.items()}


def jittered(mach: Machine, rng, softening: float = 1.0) -> dict:
    """One draw of the machine (``draw_factors`` applied)."""
    return apply_factors(mach, draw_factors(mach, rng, softening))


def _axis_dominant(chans: dict, axis: str) -> float:
    return chans[axis if axis in chans else "a"].dominant_hz()


def axis_frf(chans: dict, axis: str, f_hz, delay_s: float) -> np.ndarray:
    """Commanded → sensed position of one axis (the other's command still)."""
    if "a" in chans:
        h = 0.5 * (chans["a"].frf(f_hz) + chans["b"].frf(f_hz))
    else:
        h = chans[axis].frf(f_hz)
    return h * np.exp(-2j * np.pi * np.asarray(f_hz) * delay_s)


def respond_xy(mach: Machine, chans: dict, x_cmd, y_cmd, ts_s: float, *, delay_s=None,
               axis_delay=None, axis_gain=None, force=None, rng=None, play=None, ecc=None,
               friction=None, frame_force=None) -> tuple:
    """Sensed (x, y) of a plant ``chans`` for the command samples; effects on the command path
    (``axis_delay`` {axis: s}, ``axis_gain`` {axis: scale}) and ``force`` {axis: (freq_hz, N,
    phase[, onset s])} on the frame / table (a fan; switched on at the onset, else running
    throughout).

    In the drive, on the (fine, delayed) command of an axis before it reaches the motor (a
    corexy's: before the axis commands are mixed into its motors): ``play`` {axis: width mm}
    (a dead band between motor and belt / screw), ``ecc`` {axis: (A mm, λ mm, φ)} (the drive
    sees u + A sin(2π u/λ + φ): pulley / screw eccentricity; a list of such tuples adds
    each). Forces: ``friction`` {axis: F}
    a Coulomb force −F·tanh(v/0.5 mm/s) of the commanded velocity v on the carriage / table,
    or {axis: (F, "actual")}: −F·tanh(v/0.1 mm/s) of the carriage's own velocity (benchA's:
    the carriage sticks at a reversal until the drive's pull exceeds F; belt kinds only);
    ``frame_force`` {axis: (coef, other axis, source)}: coef × the other axis's acceleration
    (mm/s²) on the frame (belt kinds) / table (servo), source ``"command"`` (its commanded
    acceleration) or ``"actual"`` (that of its simulated sensed position: the reaction of the
    carriage's real motion). Not on a corexy."""
    d_all = mach.delay_s if delay_s is None else delay_s
    cmd = {"x": np.asarray(x_cmd, float), "y": np.asarray(y_cmd, float)}
    for ax, g in (axis_gain or {}).items():
        cmd[ax] = g * cmd[ax]
    steps = {ax: int(round((d_all + (axis_delay or {}).get(ax, 0.0)) / (ts_s / R))) for ax in "xy"}
    # the firmware's input shaper acts on each axis's planned motion (before a corexy's mixing)
    sh = {}
    for ax, cfg in mach.shapers.items():
        a, t = shaper_pulses(cfg)
        sh[ax] = (a, t / (ts_s / R))
    K = len(cmd["x"])
    tf = np.arange((K - 1) * R + 1) * ts_s / R

    def wf(ax):
        if not force or ax not in force:
            return None
        f, amp, ph, *on = force[ax]
        w = amp * np.sin(2 * np.pi * f * tf + ph)
        return w * (tf >= on[0]) if on else w

    if play or ecc or friction or frame_force:
        x, y = _respond_drive(chans, cmd, steps, ts_s, tf, play or {}, ecc or {},
                              friction or {}, frame_force or {}, sh)
    elif "a" in chans:
        # a corexy's motors: the two axes' delays apply to the axis commands before mixing
        fx, fy = _fine(cmd["x"], steps["x"], sh.get("x")), _fine(cmd["y"], steps["y"], sh.get("y"))
        ua, ub = fx + fy, fx - fy
        ya = _sim_fine(chans["a"], ua, ts_s, wf("x"))
        yb = _sim_fine(chans["b"], ub, ts_s, wf("y"))
        x, y = 0.5 * (ya + yb), 0.5 * (ya - yb)
    else:
        x = _sim_fine(chans["x"], _fine(cmd["x"], steps["x"], sh.get("x")), ts_s, wf("x"))
        y = _sim_fine(chans["y"], _fine(cmd["y"], steps["y"], sh.get("y")), ts_s, wf("y"))
    rng = rng or np.random.default_rng(0)
    out = []
    for v in (x, y):
        q = mach.sensor_q_mm
        v = np.round(v / q) * q + mach.sensor_noise_mm * rng.standard_normal(len(v))
        out.append(v)
    return out[0], out[1]


#: friction's velocity scale: sign(v) smoothed as tanh(v / V_FRICTION), mm/s
V_FRICTION = 0.5
#: the same for a force of the carriage's own velocity, benchA's: at rest the force lets
#: the carriage creep in over ~lag / V_FRICTION_ACTUAL
V_FRICTION_ACTUAL = 0.1


def _play_op(u, width):
    """Dead band of total width ``width``: the driven end stays put until the drive has
    crossed the band, then trails it by width/2; starts centred."""
    r = 0.5 * width
    out = np.empty_like(u)
    y = u[0]
    for j, v in enumerate(u.tolist()):
        if v - y > r:
            y = v - r
        elif y - v > r:
            y = v + r
        out[j] = y
    return out


def _respond_drive(chans, cmd, steps, ts_s, tf, play, ecc, friction, frame_force, sh=None):
    """respond_xy with the drive effects (its docstring); noise-free (x, y) at the samples."""
    dt = ts_s / R
    sh = sh or {}
    u = {}
    for ax in "xy":
        v = _fine(cmd[ax], steps[ax], sh.get(ax))
        if ax in play:
            v = _play_op(v, play[ax])
        if ax in ecc:
            e = ecc[ax]
            v = v + sum(A * np.sin(2 * np.pi * v / lam + ph)
                        for A, lam, ph in (e if isinstance(e, list) else [e]))
        u[ax] = v

    def coulomb(ax):
        # the commanded velocity of the axis (as its drive receives it, before the play)
        uf = _fine(cmd[ax], steps[ax], sh.get(ax))
        vel = np.gradient(uf, dt)
        return -friction[ax] * np.tanh(vel / V_FRICTION)

    def sticks(ax):
        return isinstance(friction.get(ax), tuple) and friction[ax][1] == "actual"

    if "a" in chans:
        assert not frame_force, "no frame force on a corexy"
        assert not any(sticks(ax) for ax in friction), "no carriage-velocity friction on a corexy"
        # friction on the carriage along x pushes both belts' carriages alike, along y
        # oppositely (x = (A + B)/2, y = (A − B)/2)
        wx = coulomb("x") if "x" in friction else 0.0
        wy = coulomb("y") if "y" in friction else 0.0
        on = "carriage" if friction else "frame"
        wa = (wx + wy) + np.zeros_like(tf) if friction else None
        wb = (wx - wy) + np.zeros_like(tf) if friction else None
        ya = _sim_fine(chans["a"], u["x"] + u["y"], ts_s, wa, on)
        yb = _sim_fine(chans["b"], u["x"] - u["y"], ts_s, wb, on)
        return 0.5 * (ya + yb), 0.5 * (ya - yb)
    out = {}
    # an axis pushed by the other's motion after the other
    for ax in sorted("xy", key=lambda a: a in frame_force):
        w, on = None, "frame"
        if sticks(ax):
            assert ax not in frame_force and chans[ax].kind != "servo_screw"
            out[ax] = _sim_fine_stick(chans[ax], u[ax], ts_s, friction[ax][0])
            continue
        if ax in friction:
            assert ax not in frame_force
            w, on = coulomb(ax), "carriage"
        elif ax in frame_force:
            coef, oth, source = frame_force[ax]
            assert oth not in frame_force
            c = cmd[oth] if source == "command" else out[oth]
            acc = np.gradient(np.gradient(c, ts_s), ts_s)
            w = coef * np.interp(tf, np.arange(len(c)) * ts_s, acc)
            if source == "command" and steps[oth]:
                w = np.concatenate([np.zeros(steps[oth]), w[:-steps[oth]]])
        out[ax] = _sim_fine(chans[ax], u[ax], ts_s, w, on)
    return out["x"], out["y"]


def _fine(u, delay_steps, shaper=None):
    """The command linear between samples at Ts/R, through the firmware's shaper (``shaper``
    (a, shifts in fine steps): Σ aᵢ u(t − tᵢ) on the fine grid, holding the ends), then the
    transport delay."""
    K = len(u)
    uf = np.interp(np.arange((K - 1) * R + 1) / R, np.arange(K), u)
    if shaper is not None:
        a, shift = shaper
        j = np.arange(uf.size, dtype=float)
        uf = sum(ai * np.interp(j - si, j, uf) for ai, si in zip(a, shift))
    if delay_steps:
        uf = np.concatenate([np.full(delay_steps, uf[0]), uf[:-delay_steps]])
    return uf


def _foh(A, B, dt):
    """(Φ, Γ1, Γ2) of x' = A x + B u with u linear over a step dt (first-order hold):
    x_{j+1} = Φ x_j + (Γ1 − Γ2) u_j + Γ2 u_{j+1}."""
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n] = A * dt
    M[:n, n:n + m] = B * dt
    M[n:n + m, n + m:] = np.eye(m)
    E = expm(M)
    return E[:n, :n], E[:n, n:n + m], E[:n, n + m:]


def _sim_fine(ch: Channel, uf, ts_s, w_fine, force_on: str = "frame"):
    """Response at the sample times (every R-th fine step) to a fine command ``uf`` (linear
    between fine steps: first-order hold, exact) and a force ``w_fine`` (on the frame / the
    carriage: ``Channel.ss``), from rest at uf[0]."""
    A, B, C = ch.ss(force_on)
    n = A.shape[0]
    Phi, G1, G2 = _foh(A, B, ts_s / R)
    wf = np.zeros_like(uf) if w_fine is None else w_fine[: len(uf)]
    U = np.column_stack([uf - uf[0], wf])
    drive = U[:-1] @ (G1 - G2).T + U[1:] @ G2.T          # x_{j+1} = Phi x_j + drive_j
    K = (len(uf) - 1) // R
    # R fine steps at once: x_{k+R} = Phi^R x_k + sum_j Phi^(R-1-j) drive_{k+j}
    pw = [np.eye(n)]
    for _ in range(R - 1):
        pw.append(Phi @ pw[-1])
    P = np.stack(pw[::-1])                                # P[j] = Phi^(R-1-j)
    blocks = np.einsum("kjn,jmn->km", drive[: K * R].reshape(K, R, n), P)
    PhiR = Phi @ pw[-1]
    x = np.zeros(n)
    ys = np.empty(K + 1)
    ys[0] = 0.0
    for k in range(K):
        x = PhiR @ x + blocks[k]
        ys[k + 1] = C @ x
    return uf[0] + ys


def _sim_fine_stick(ch: Channel, uf, ts_s, F):
    """``_sim_fine`` of a belt kind with a Coulomb force −F·tanh(v_c/V) of its carriage's own
    velocity v_c (state 2) on the carriage, V = V_FRICTION_ACTUAL: stepped one fine step at
    a time, the force held over each (sub)step; the step is split until F/V·dt/m ≤ 0.2 (the
    force's slope at rest acts as a damper the explicit step must resolve)."""
    A, B, C = ch.ss("carriage")
    n = A.shape[0]
    V = V_FRICTION_ACTUAL
    sub = max(1, math.ceil(F / V * (ts_s / R) / ch.p["m"] / 0.2))
    Phi, G1, G2 = _foh(A, B, ts_s / R / sub)
    # the command linear between fine steps, so between substeps too
    uu = np.interp(np.arange((len(uf) - 1) * sub + 1) / sub, np.arange(len(uf)), uf) - uf[0]
    du = np.outer(uu[:-1], G1[:, 0] - G2[:, 0]) + np.outer(uu[1:], G2[:, 0])
    gw = G1[:, 1]
    K = (len(uf) - 1) // R
    step = R * sub
    x = np.zeros(n)
    ys = np.empty(K + 1)
    ys[0] = 0.0
    for j in range(K * step):
        x = Phi @ x + du[j] - F * math.tanh(x[2] / V) * gw
        if (j + 1) % step == 0:
            ys[(j + 1) // step] = C @ x
    return uf[0] + ys


# ---------------------------------------------------------------------------- data sets
def bench_a_commands() -> dict:
    """path name -> (x_cmd, y_cmd) at 2 ms: the commands of benchA's three clean logs (another
    project's planner), read from ../shared/data/independent."""
    names = {"butterfly": "log_01.csv", "rose5": "log_02.csv", "benchy_layer10": "log_03.csv"}
    out = {}
    for path, f in names.items():
        a = np.loadtxt(BENCH_A / "logs" / f, delimiter=",", skiprows=1)
        out[path] = (a[:, 1], a[:, 2])
    return out


def write_dataset(mach: Machine, out: pathlib.Path, *, effects: bool = True,
                  fan_hz: float | None = None, more_effects: bool = False,
                  variants: bool = False) -> dict:
    """Write FRFs, logs and labels of ``mach`` under ``out`` (benchA's layout); return labels.
    ``fan_hz`` puts the fan (a periodic_time effect, not on a corexy) at that frequency instead
    of the drawn one; the rest of the data set is the same. ``more_effects`` appends the logs
    of the drive's effects (``_more_effects``: backlash, periodic_position, friction,
    cross_coupling), drawn from a random stream of their own: every other file is the same
    as without them. ``variants`` then appends ``_variant_effects``'s logs (a stream of their
    own too)."""
    rng = np.random.default_rng(10_000 + mach.seed)
    out = pathlib.Path(out)
    (out / "frf").mkdir(parents=True, exist_ok=True)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    start, stop, step = mach.frf_grid
    f = np.arange(start, stop + 1e-9, step)
    levels = [1.0, 0.97, 0.94]
    truth = []
    drawn = {"x": [], "y": []}
    for axis in "xy":
        for i in range(mach.n_meas):
            soft = levels[min(i * len(levels) // mach.n_meas, 2)]
            fac = draw_factors(mach, rng, soft)
            drawn[axis].append(fac)
            member = apply_factors(mach, fac)
            h = axis_frf(member, axis, f, mach.delay_s)
            truth.append({"file": f"frf/{axis}_{i + 1}.csv", "softening": soft,
                          "dominant_hz": round(_axis_dominant(member, axis), 3)})
            noise = mach.frf_noise / math.sqrt(2) * (rng.standard_normal(len(f))
                                                    + 1j * rng.standard_normal(len(f)))
            h = h * (1 + noise)
            np.savetxt(out / "frf" / f"{axis}_{i + 1}.csv", np.column_stack([f, h.real, h.imag]),
                       delimiter=",", header="freq_hz,real,imag", comments="", fmt="%.9g")
    cmds = bench_a_commands()
    ts = 0.002
    # The plant of the logs lies inside the spread the FRFs show: each of its parameters is a
    # random convex combination (Dirichlet weights) of the measured members' (for an axis'
    # channel, of that axis' members; a corexy's belts, of x's).
    fac = {}
    for name in mach.chans:
        members = drawn["y" if name == "y" else "x"]
        w = rng.dirichlet(np.ones(len(members)))
        fac[name] = {k: float(sum(wi * m[name][k] for wi, m in zip(w, members)))
                     for k in members[0][name]}
    plant = apply_factors(mach, fac)
    logs = []
    plan = [("butterfly", []), ("rose5", []), ("benchy_layer10", [])]
    if effects:
        ax = "xy"[int(rng.integers(2))]
        oth = "y" if ax == "x" else "x"
        d = round(float(rng.uniform(2, 6)), 1) * 1e-3
        ff = round(float(rng.uniform(15, 35)), 1)
        ff = ff if fan_hz is None else float(fan_hz)
        amp = round(float(rng.uniform(0.008, 0.02)), 4)
        g = round(1 + float(rng.choice([-1, 1])) * float(rng.uniform(0.002, 0.006)), 4)
        # a corexy's frame force would move both axes through the mismatched belts: its third
        # effect log is a delay on the other axis instead
        third = (("delay", oth, {"seconds": round(d / 2, 4)}) if mach.kind == "corexy" else
                 ("periodic_time", oth, {"frequency_hz": ff, "amplitude_mm": amp}))
        plan += [("butterfly", [("delay", ax, {"seconds": d})]),
                 ("rose5", [third]),
                 ("butterfly", [("gain", oth, {"scale": g})]),
                 ("benchy_layer10", [("resonance_shift", ax, {"factor": float(rng.uniform(1.25, 1.4))})])]
    for i, (path, eff) in enumerate(plan):
        x_cmd, y_cmd = cmds[path]
        chans = dict(plant)
        kw = {"axis_delay": {}, "axis_gain": {}, "force": {}}
        labels = []
        for kind, ax, p in eff:
            if kind == "delay":
                kw["axis_delay"][ax] = p["seconds"]
                labels.append({"kind": kind, "axis": ax, "params": p})
            elif kind == "gain":
                kw["axis_gain"][ax] = p["scale"]
                labels.append({"kind": kind, "axis": ax, "params": p})
            elif kind == "periodic_time":
                key = ax if "a" not in chans else ("x" if ax == "x" else "y")
                ch = chans[ax] if "a" not in chans else chans["a" if ax == "x" else "b"]
                unit = abs(ch.frf([p["frequency_hz"]], inp=1)[0])
                if "a" in chans:
                    unit *= 0.5
                force = p["amplitude_mm"] / unit
                kw["force"][key] = (p["frequency_hz"], force, float(rng.uniform(0, 2 * math.pi)))
                labels.append({"kind": kind, "axis": ax, "params": p,
                               "physics": {"force": force}})
            elif kind == "resonance_shift":
                mk = "m"
                name = ax if "a" not in chans else "a"
                chans[name] = chans[name].scaled(**{mk: p["factor"]})
                if "a" in chans:
                    chans["b"] = chans["b"].scaled(m=p["factor"])
                # a corexy's carriage rides on both belts: both axes shift
                for a in (("x", "y") if "a" in chans else (ax,)):
                    labels.append({"kind": kind, "axis": a,
                                   "params": {"frequency_hz": round(chans[name].dominant_hz(), 3)},
                                   "physics": {"mass_factor": p["factor"],
                                               "nominal_hz": round(plant[name].dominant_hz(), 3)}})
        x, y = respond_xy(mach, chans, x_cmd, y_cmd, ts, rng=rng, **kw)
        t = np.arange(len(x_cmd)) * ts
        fname = f"logs/log_{i + 1:02d}.csv"
        np.savetxt(out / fname, np.column_stack([t, x_cmd, y_cmd, x, y]), delimiter=",",
                   header="t,x_cmd,y_cmd,x,y", comments="", fmt="%.6f")
        logs.append({"file": fname, "path": path,
                     "effects": labels or [{"kind": "none", "axis": None, "params": {}}]})
    # each appended set of logs from a random stream of its own
    streams = []
    if more_effects:
        rng2 = np.random.default_rng(20_000 + mach.seed)
        streams.append((rng2, _more_effects(mach, plant, rng2)))
    if variants:
        rng3 = np.random.default_rng(40_000 + mach.seed)
        streams.append((rng3, _variant_effects(mach, plant, rng3, ts)))
    for rs, plan in streams:
        for path, kw, labels in plan:
            x_cmd, y_cmd = cmds[path]
            x, y = respond_xy(mach, plant, x_cmd, y_cmd, ts, rng=rs, **kw)
            t = np.arange(len(x_cmd)) * ts
            fname = f"logs/log_{len(logs) + 1:02d}.csv"
            np.savetxt(out / fname, np.column_stack([t, x_cmd, y_cmd, x, y]), delimiter=",",
                       header="t,x_cmd,y_cmd,x,y", comments="", fmt="%.6f")
            logs.append({"file": fname, "path": path, "effects": labels})
    labels = {"dataset": f"foreign-{mach.seed}", "machine": mach.describe(), "logs": logs,
              "frf_measurement": truth,
              "plant": {**{a: {"dominant_hz": round(_axis_dominant(plant, a), 3)} for a in "xy"},
                        "factors": fac},
              # present in every log, not in the per-axis FRFs: a diagnosis may name it
              "inherent": ([{"kind": "cross_coupling", "axis": a, "why": "corexy belt mismatch"}
                            for a in "xy"] if mach.kind == "corexy" else [])}
    (out / "labels.json").write_text(json.dumps(labels, indent=1))
    return labels


def _more_effects(mach: Machine, plant: dict, rng) -> list:
    """[(path, respond_xy keywords, labels)] of the drive's effect logs, one effect each, on a
    random axis, in this module's physics (``respond_xy``):

    ``backlash``           a dead band of width b 0.02–0.08 mm between motor and belt / screw,
                           on the command before the dynamics; ``magnitude_mm`` = b;
    ``periodic_position``  pulley / screw eccentricity: the drive sees u + A sin(2π u/λ + φ),
                           A 0.005–0.02 mm, λ 2–8 mm; ``wavelength_mm`` λ, ``amplitude_mm`` A;
    ``friction``           a Coulomb force −F tanh(v_cmd / 0.5 mm/s) on the carriage / table;
                           ``magnitude_mm`` (0.01–0.04 mm, F derived from it) is benchA's
                           quasi-static lag F × the static compliance of the sensed position to
                           a carriage force (belt kinds: 1/k + 1/kf; a corexy: the mean of its
                           belts'); the servo's integrator takes a steady lag out, its label is
                           the lag of the loop without it, F (1/kp + 1/k) — a scale, not a
                           steady lag (``physics.steady`` False);
    ``cross_coupling``     (not a corexy: its belts already couple the axes) a force on this
                           axis's frame (servo: table) = κ m_other a_other, two logs: a_other
                           the other carriage's actual acceleration (the reaction of its real
                           motion, as benchA), then its commanded one;
                           ``mm_per_mm_s2`` (2–6e-6) is its quasi-static displacement per mm/s²
                           (κ m_other × the frame's static compliance; the servo's as above).
    """
    kinds = ["backlash", "periodic_position", "friction"]
    if "a" not in plant:
        kinds += ["cross_coupling", "cross_coupling_cmd"]
    paths = {"backlash": "rose5", "periodic_position": "benchy_layer10", "friction": "butterfly",
             "cross_coupling": "rose5", "cross_coupling_cmd": "rose5"}
    servo = mach.kind == "servo_screw"
    out = []
    for kind in kinds:
        ax = "xy"[int(rng.integers(2))]
        oth = "y" if ax == "x" else "x"
        if "a" in plant:
            ch = plant["a"]
        else:
            ch = plant[ax]
        if kind == "backlash":
            b = round(float(rng.uniform(0.02, 0.08)), 4)
            kw = {"play": {ax: b}}
            lab = {"kind": kind, "axis": ax, "params": {"magnitude_mm": b},
                   "physics": {"applied": "dead band between motor and belt / screw on the "
                                          "command, total width = magnitude_mm, starts centred"}}
        elif kind == "periodic_position":
            A = round(float(rng.uniform(0.005, 0.02)), 4)
            lam = round(float(rng.uniform(2.0, 8.0)), 3)
            ph = float(rng.uniform(0, 2 * math.pi))
            kw = {"ecc": {ax: (A, lam, ph)}}
            lab = {"kind": kind, "axis": ax, "params": {"wavelength_mm": lam, "amplitude_mm": A},
                   "physics": {"applied": "drive sees u + A sin(2 pi u / wavelength + phase)",
                               "phase_rad": round(ph, 4)}}
        elif kind == "friction":
            mag = round(float(rng.uniform(0.01, 0.04)), 4)
            if "a" in plant:
                comp = 0.5 * (plant["a"].compliance("carriage") + plant["b"].compliance("carriage"))
            else:
                comp = ch.compliance("carriage")
            F = mag / comp
            kw = {"friction": {ax: F}}
            lab = {"kind": kind, "axis": ax, "params": {"magnitude_mm": mag},
                   "physics": {"applied": "Coulomb force -F tanh(v_cmd / 0.5 mm/s) on the "
                                          "carriage / table; magnitude_mm = F x static compliance",
                               "force": F, "steady": not servo}}
        else:
            c = round(float(rng.uniform(2e-6, 6e-6)), 8)
            coef = c / ch.compliance("frame")
            m_other = plant[oth].p["m"]
            source = "command" if kind == "cross_coupling_cmd" else "actual"
            kw = {"frame_force": {ax: (coef, oth, source)}}
            lab = {"kind": "cross_coupling", "axis": ax,
                   "params": {"from_axis": oth, "mm_per_mm_s2": c},
                   "physics": {"applied": f"force on the frame (servo: table) = kappa m_other "
                                          f"a_other, a_other its {source} acceleration",
                               "source": source, "kappa": coef / m_other, "steady": not servo}}
        out.append((paths[kind], kw, [lab]))
    return out


def _variant_effects(mach: Machine, plant: dict, rng, ts_s: float) -> list:
    """[(path, respond_xy keywords, labels)] of effects in forms the logs above do not write
    (the first two, benchA neither), each on a random axis, drawn after the others so that
    adding one leaves those before as they were:

    ``periodic_time``      (not a corexy) a fan switched on 40 % into a rose (benchA's fans run
                           from t = 0): the force from then on, the carriage ringing in;
                           ``amplitude_mm`` 0.008–0.02 the steady amplitude, ``physics.onset_s``;
    ``periodic_position``  twice on one axis: a belt's tooth pitch or a screw's thread (λ
                           1.5–3 mm) and a pulley's or screw's runout (λ 20–45 mm), A 0.006–0.015
                           mm each, on a Benchy layer: two effects of one kind;
    ``friction``           (belt kinds) benchA's form: a Coulomb force −F tanh(v / 0.1 mm/s) of
                           the carriage's own velocity (the logs above: of the command), on a
                           rose; the carriage sticks at each reversal until the belt's pull
                           exceeds F, which on steady motion lags it by ``magnitude_mm``
                           (0.01–0.04, F × the static compliance, as above).
    """
    out = []
    cmds = bench_a_commands()
    if "a" not in plant:
        ax = "xy"[int(rng.integers(2))]
        ff = round(float(rng.uniform(15, 35)), 1)
        amp = round(float(rng.uniform(0.008, 0.02)), 4)
        force = amp / abs(plant[ax].frf([ff], inp=1)[0])
        onset = round(0.4 * (len(cmds["rose5"][0]) - 1) * ts_s, 3)
        kw = {"force": {ax: (ff, force, float(rng.uniform(0, 2 * math.pi)), onset)}}
        out.append(("rose5", kw, [{"kind": "periodic_time", "axis": ax,
                                   "params": {"frequency_hz": ff, "amplitude_mm": amp},
                                   "physics": {"force": force, "onset_s": onset}}]))
    ax = "xy"[int(rng.integers(2))]
    ecc, labels = [], []
    for lo, hi in ((1.5, 3.0), (20.0, 45.0)):
        A = round(float(rng.uniform(0.006, 0.015)), 4)
        lam = round(float(rng.uniform(lo, hi)), 3)
        ph = float(rng.uniform(0, 2 * math.pi))
        ecc.append((A, lam, ph))
        labels.append({"kind": "periodic_position", "axis": ax,
                       "params": {"wavelength_mm": lam, "amplitude_mm": A},
                       "physics": {"applied": "drive sees u + A sin(2 pi u / wavelength + "
                                              "phase), both terms", "phase_rad": round(ph, 4)}})
    out.append(("benchy_layer10", {"ecc": {ax: ecc}}, labels))
    if mach.kind in ("belt_frame", "belt_hotend"):
        ax = "xy"[int(rng.integers(2))]
        mag = round(float(rng.uniform(0.01, 0.04)), 4)
        F = mag / plant[ax].compliance("carriage")
        out.append(("rose5", {"friction": {ax: (F, "actual")}},
                    [{"kind": "friction", "axis": ax, "params": {"magnitude_mm": mag},
                      "physics": {"applied": "Coulomb force -F tanh(v / 0.1 mm/s) of the "
                                             "carriage's own velocity; magnitude_mm = F x "
                                             "static compliance", "force": F,
                                  "source": "actual", "steady": True}}]))
    return out


@dataclass
class _Out:
    actual_mm: np.ndarray
    measured_mm: np.ndarray


class ForeignPlant:
    """The logs' plant of a written data set as the optimizer's benchmarks run a plant
    (``simulate(trajectory)`` → ``actual_mm``/``measured_mm`` (K, 3), ``run`` → actual): the
    trajectory's X/Y samples through this module's physics, noise-free; Z passes through."""

    def __init__(self, mach: Machine, labels: dict):
        self.mach = mach
        self.chans = apply_factors(mach, labels["plant"]["factors"])

    def simulate(self, trajectory) -> _Out:
        pos = np.asarray(trajectory.pos_mm, float)
        quiet = Machine(**{**self.mach.__dict__, "sensor_q_mm": 1e-9, "sensor_noise_mm": 0.0})
        x, y = respond_xy(quiet, self.chans, pos[:, 0], pos[:, 1], trajectory.ts_s)
        act = np.column_stack([x, y, pos[:, 2]])
        return _Out(act, act)

    def run(self, trajectory) -> np.ndarray:
        return self.simulate(trajectory).actual_mm
