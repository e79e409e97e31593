"""A profile's extensions that are not a change of the axis's linear response (issue 19).

``diagnose`` names effects; ``extend_profile`` writes them into ``axes.<axis>.effects`` with the
parameters that were fitted. Three kinds change the physics itself and are applied to every
modal fit by ``twin.physics.apply_effects`` (delay, gain, resonance_shift). The others add a
deterministic term to the predicted position, computed here from the commanded motion, the same
way ``diagnose`` fitted it:

- ``periodic_position``: A·sin(2π x_cmd/λ + φ), through the axis dynamics (form ``dynamics``)
  or at the output (form ``output``);
- ``backlash``: the play of width b on the command before the dynamics (form ``input``) or on
  the response (form ``output``), plus ``offset_mm``, where the band sat in the log it was
  fitted on, and on a servo the lag error −``lag_s``·v̂ of the twin fitted with it;
- ``friction``: m·(−sign v_cmd), relaxing with ``relax_s`` once the axis stops, through the
  dynamics (``response``), the force response (``force``) or at the output (``output``); on a
  position loop with integral action (a servo) form ``integral``: the force's step at each
  reversal through the force response, washed out by the integrator with time constant
  ``integral_s`` (:func:`integral_sign`); form ``loop``: the force through the loop that
  holds the load, (1 − H)/(s (s + a)) with ``corner_hz`` a/2π (``ModalModel.load_force``,
  ``magnitude_mm`` the peak of its step response); form ``stick``: a force of the carriage's own
  velocity, which holds it at a reversal until the drive's pull exceeds it: a play of total
  width 2·``magnitude_mm`` on the response, starting centred (a print starts at rest);
- ``cross_coupling``: ``mm_per_mm_s2`` times the other axis's predicted acceleration through
  this axis's dynamics (form ``acceleration``, a frame force: the reaction of the other
  carriage's real motion), its commanded acceleration through them (form ``command``: the
  reaction of a motor force that follows the other axis's command, as a stiff servo's does,
  not its carriage's ringing), the predicted one through them twice (form ``belt``: a
  corexy whose two belts differ, see below), the predicted or the commanded one through the
  axis's response to a force on its frame (forms ``frame`` and ``frame_command``:
  ``twin.physics.frame_model``, the command path's antiresonance taken out) or the force
  response of the load a loop holds at ``corner_hz`` (forms ``loop``, ``loop_command``:
  ``ModalModel.load_force``, a servo's table), or
  ``coefficient`` times the other axis's predicted motion (form ``position``);
- ``gain``: besides its change of the response (about the first commanded sample, where the
  twin works), the constant (s − 1)·x_0 that a scale about the machine origin adds.

``periodic_time`` (a fan) keeps no phase from one print to the next: it adds the variance A²/2
of a sinusoid of random phase to the prediction instead of a mean.

Form ``belt``: on a corexy, x = (A + B)/2 and y = (A − B)/2 for the two belt drives A, B; with
responses G_A ≠ G_B each axis's FRF is (G_A + G_B)/2 and each axis also moves by
(G_A − G_B)/2 times the other's command. To first order in the mismatch, G_A − G_B =
∂G/∂k·Δk, and for a belt mode G = ω²/D(s), ∂G/∂(ω²)·Δω² = (Δω²/ω²)·(s²/ω²)·G² — the other
axis's acceleration through the axis's dynamics twice. On drawn corexy machines
(tests/foreign) the once-filtered form left most of this cross-talk in the residual.

Pure functions on arrays; ``mean_offsets(profile, cmd)`` is what the twin's users call.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from ..vm import effects as fx
from ..vm.plant import respond
from .physics import axis_impulse, axis_physics

#: kinds applied to the modal fits (``twin.physics``)
LINEAR_KINDS = ("delay", "gain", "resonance_shift")
#: kinds that add a deterministic term here
ADDITIVE_KINDS = ("periodic_position", "backlash", "friction", "cross_coupling")
#: cross-coupling forms whose force takes a path of its own (``_path_h``)
PATH_FORMS = ("frame", "frame_command", "loop", "loop_command")
#: kinds that add variance
VARIANCE_KINDS = ("periodic_time",)

#: kind -> {parameter: (lowest, highest)} of what a profile may hold; strings are choices
PARAMS = {
    "delay": {"delay_s": (-0.1, 0.1)},
    "gain": {"scale": (0.5, 2.0)},
    "resonance_shift": {"frequency_hz": (1e-3, 1e4), "load_ratio": (-0.9, 10.0),
                        "corner_hz": (0.0, 1e5), "form": ("mass", "scale", "load")},
    "periodic_time": {"frequency_hz": (1e-3, 1e4), "amplitude_mm": (0.0, 10.0)},
    "periodic_position": {"wavelength_mm": (1e-3, 1e4), "amplitude_mm": (0.0, 10.0),
                          "phase_rad": (-10.0, 10.0), "form": ("dynamics", "output")},
    "backlash": {"magnitude_mm": (0.0, 10.0), "offset_mm": (-10.0, 10.0),
                 "lag_s": (-0.1, 0.1), "form": ("input", "output")},
    "friction": {"magnitude_mm": (-10.0, 10.0), "relax_s": (0.0, 1e6),
                 "integral_s": (1e-4, 10.0), "corner_hz": (0.0, 1e5),
                 "form": ("response", "force", "output", "integral", "stick", "loop")},
    "cross_coupling": {"from_axis": ("x", "y"), "mm_per_mm_s2": (-1.0, 1.0),
                       "coefficient": (-1.0, 1.0),
                       "corner_hz": (0.0, 1e5),
                       "form": ("acceleration", "command", "belt", "position", "frame",
                                "frame_command", "loop", "loop_command")},
}
#: parameters a kind must have (the rest default as in ``DEFAULTS``)
REQUIRED = {
    "delay": ("delay_s",), "gain": ("scale",), "resonance_shift": ("frequency_hz",),
    "periodic_time": ("frequency_hz", "amplitude_mm"),
    "periodic_position": ("wavelength_mm", "amplitude_mm"), "backlash": ("magnitude_mm",),
    "friction": ("magnitude_mm",), "cross_coupling": ("from_axis",),
}
DEFAULTS = {
    "periodic_position": {"phase_rad": 0.0, "form": "dynamics"},
    "backlash": {"offset_mm": 0.0, "lag_s": 0.0, "form": "input"},
    "friction": {"relax_s": 0.0, "integral_s": 0.1, "form": "response"},
    "cross_coupling": {"mm_per_mm_s2": 0.0, "coefficient": 0.0, "form": "acceleration"},
}


def relax_sign(cmd_mm: np.ndarray, ts_s: float, tau_s: float) -> np.ndarray:
    """(K,) −sign(v_cmd) that decays as exp(−t/τ) once the axis stops (τ = 0: at once,
    τ = inf: held, as a stiction would)."""
    s = -fx.velocity_sign(np.asarray(cmd_mm, float), ts_s)
    if tau_s <= 0:
        return s
    a = math.exp(-ts_s / tau_s) if math.isfinite(tau_s) else 1.0
    out = s.copy()
    for k in np.flatnonzero(s == 0).tolist():
        out[k] = a * out[k - 1] if k > 0 else 0.0
    return out


def integral_sign(cmd_mm: np.ndarray, ts_s: float, tau_s: float) -> np.ndarray:
    """(K,) −sign(v_cmd) through the high-pass τs/(1 + τs): a Coulomb force as a position loop
    with integral action sees it. Such a loop (PID on a motor) rejects a steady force: its
    error to a force F is P/(1 + C·P)·F, and against the loop without the integrator the
    ratio is s(K_p + K_d s)/(K_d s² + K_p s + K_i) ≈ τs/(1 + τs), τ = K_p/K_i. The step at a
    reversal moves the axis by the loop's compliance and decays in ~τ, moving or not."""
    s = -fx.velocity_sign(np.asarray(cmd_mm, float), ts_s)
    a = math.exp(-ts_s / tau_s)
    low = lfilter([1.0 - a], [1.0, -a], s)
    return s - low


def lag_regressor(pred_mm: np.ndarray, ts_s: float) -> np.ndarray:
    """(K,) −dx̂/dt: what the prediction x̂ late by τ adds, per second of τ (to first order).
    The backlash form's ``lag_s`` on a servo (diagnose fits it with this column)."""
    return -np.gradient(np.asarray(pred_mm, float), ts_s)


def additive_term(kind: str, params: dict, cmd_mm: np.ndarray, ts_s: float, h: np.ndarray, *,
                  other_pred_mm: np.ndarray | None = None,
                  pred_mm: np.ndarray | None = None,
                  other_cmd_mm: np.ndarray | None = None,
                  path_h: np.ndarray | None = None) -> np.ndarray:
    """(K,) the deterministic term one extension adds to an axis's predicted position, mm.

    Args:
        cmd_mm: (K,) the axis's commanded position. h: (n,) its unit-DC impulse response.
        other_pred_mm: (K,) the other axis's predicted position (cross_coupling).
        other_cmd_mm: (K,) the other axis's commanded position (cross_coupling form ``command``).
        path_h: (n,) the response of the effect's own path (``_path_h``): a friction's force
            response (forms ``force``, ``integral``; ``loop``: the load's,
            ``AxisPhysics.load_force``), a cross_coupling's of PATH_FORMS (``frame``,
            ``frame_command``: the frame's; ``loop``, ``loop_command``: the load's force
            response); None: ``h`` is used.
        pred_mm: (K,) the axis's prediction, for the ``output`` forms (default h * cmd).
    """
    p = {**DEFAULTS.get(kind, {}), **params}
    cmd = np.asarray(cmd_mm, float)
    K = cmd.size
    if kind == "gain":
        return np.full(K, (p["scale"] - 1.0) * cmd[0])
    pred = respond(cmd, h) if pred_mm is None else pred_mm
    if kind == "periodic_position":
        s = p["amplitude_mm"] * np.sin(2 * np.pi * cmd / p["wavelength_mm"] + p["phase_rad"])
        return respond(s, h) if p["form"] == "dynamics" else s
    if kind == "backlash":
        b = p["magnitude_mm"]
        lag = p["lag_s"] * lag_regressor(pred, ts_s) if p["lag_s"] else 0.0
        if p["form"] == "input":
            return respond(fx.play(cmd, b), h) - pred + p["offset_mm"] + lag
        return fx.play(pred, b) - pred + p["offset_mm"] + lag
    if kind == "friction":
        if p["form"] == "stick":
            return fx.play(pred, 2.0 * p["magnitude_mm"]) - pred
        if p["form"] == "integral":
            s = integral_sign(cmd, ts_s, p["integral_s"])
        else:
            s = relax_sign(cmd, ts_s, p["relax_s"])
        if p["form"] == "output":
            return p["magnitude_mm"] * s
        return p["magnitude_mm"] * respond(s, h if path_h is None else path_h)
    if kind == "cross_coupling":
        src = (other_cmd_mm if p["form"] in ("command", "frame_command", "loop_command")
               else other_pred_mm)
        if src is None:
            return np.zeros(K)
        po = np.asarray(src, float)
        if p["form"] != "position":
            acc = np.gradient(np.gradient(po, ts_s), ts_s)
            if p["form"] in PATH_FORMS:
                return p["mm_per_mm_s2"] * respond(acc, h if path_h is None else path_h)
            g = respond(acc, h)
            return p["mm_per_mm_s2"] * (respond(g, h) if p["form"] == "belt" else g)
        return p["coefficient"] * (po - po[0])
    return np.zeros(K)


def extra_variance_mm2(effects) -> float:
    """Variance the axis's periodic_time extensions add (a sinusoid of random phase: A²/2)."""
    return float(sum(0.5 * e["params"]["amplitude_mm"] ** 2 for e in effects
                     if e["kind"] in VARIANCE_KINDS))


def mean_offsets(profile, cmd_mm: np.ndarray) -> np.ndarray:
    """(K, 2) what the profile's extensions add to the twin's mean prediction of X, Y (zeros
    when it has none)."""
    # on use: twin.modal's fitting stack (`gcode-feedopt --help` loads this module; +10 ms)

    cmd = np.asarray(cmd_mm, float)
    K = cmd.shape[0]
    out = np.zeros((K, 2))
    axes = ("x", "y")
    if not any(e["kind"] in ADDITIVE_KINDS or e["kind"] == "gain"
               for ax in axes for e in profile.axes[ax].effects):
        return out
    h = {}
    for ax in axes:
        m = np.asarray(axis_impulse(profile, ax).mean)
        h[ax] = m / np.sum(m)
    preds = {ax: respond(cmd[:, i], h[ax]) for i, ax in enumerate(axes)}
    phys = _lazy_physics(profile)
    for i, ax in enumerate(axes):
        for e in profile.axes[ax].effects:
            if e["kind"] not in ADDITIVE_KINDS and e["kind"] != "gain":
                continue
            other = e["params"].get("from_axis")
            out[:, i] += additive_term(e["kind"], e["params"], cmd[:, i], profile.ts_s, h[ax],
                                       other_pred_mm=preds.get(other), pred_mm=preds[ax],
                                       other_cmd_mm=_column(cmd, axes, other),
                                       path_h=_path_h(phys, ax, e))
    return out


#: additive kinds the optimizer's prediction carries: a cross-coupling is the other axis's
#: motion through this one's dynamics (finite memory, linear in the command, shrinks as the
#: motion slows); the others stay whatever the speed (friction, a pitch error, backlash's
#: band) or hold a state from the whole history (backlash), which the slow-down's windows
#: cannot carry
MOTION_KINDS = ("cross_coupling",)


def motion_offsets(profile):
    """A function cmd (K, 2) -> (K, 2), mm: what the profile's MOTION_KINDS extensions add to
    the twin's mean prediction of X, Y, and the samples of history it needs (a ``belt``
    cross-coupling filters through the dynamics twice); None when the profile has none."""

    axes = ("x", "y")
    todo = [(i, ax, e) for i, ax in enumerate(axes) for e in profile.axes[ax].effects
            if e["kind"] in MOTION_KINDS]
    if not todo:
        return None
    h = {}
    for ax in axes:
        m = np.asarray(axis_impulse(profile, ax).mean)
        h[ax] = m / np.sum(m)
    twice = any({**DEFAULTS[e["kind"]], **e["params"]}["form"] == "belt" for _, _, e in todo)
    # the response of the other axis's prediction, its acceleration (np.gradient reaches two
    # samples) and once or twice through the dynamics: what a window must remember
    memory = (2 if twice else 1) * max(v.size for v in h.values()) + 4

    phys = _lazy_physics(profile)
    paths = [_path_h(phys, ax, e) for _, ax, e in todo]

    def offsets(cmd_mm):
        cmd = np.asarray(cmd_mm, float)
        out = np.zeros((cmd.shape[0], 2))
        preds = {ax: respond(cmd[:, i], h[ax]) for i, ax in enumerate(axes)}
        for (i, ax, e), path in zip(todo, paths):
            other = e["params"].get("from_axis")
            out[:, i] += additive_term(e["kind"], e["params"], cmd[:, i], profile.ts_s, h[ax],
                                       other_pred_mm=preds.get(other), pred_mm=preds[ax],
                                       other_cmd_mm=_column(cmd, axes, other), path_h=path)
        return out

    return offsets, memory


def _column(cmd: np.ndarray, axes, axis):
    """cmd's column of ``axis`` (None when the effect names no axis)."""
    return cmd[:, axes.index(axis)] if axis in axes else None


def _lazy_physics(profile):
    """A function () -> ``axis_physics(profile)``, computed on the first call only (the force
    and frame responses; most profiles' extensions need neither)."""
    got = []

    def phys():
        if not got:
            got.append(axis_physics(profile))
        return got[0]

    return phys


def _path_h(phys, axis, effect):
    """The response of an extension's own path (``phys``: ``_lazy_physics``), or None for
    the command path's ``h``: a friction's force response (forms ``force``, ``integral``:
    ``AxisPhysics.force``), a cross-coupling's frame response (``frame``, ``frame_command``),
    and for the loop forms of both the load's force response at the written corner
    (``AxisPhysics.load_force``). A profile whose fit has no such path (no modal physics, no
    antiresonance, no loop) cannot have been diagnosed such a form; one edited by hand to it
    gets the command path's response."""
    kind, form = effect["kind"], effect["params"].get("form")
    if kind == "friction" and form in ("force", "integral"):
        return phys()[axis].force
    if form in ("loop", "loop_command") and kind in ("friction", "cross_coupling"):
        lf = phys()[axis].load_force
        return None if lf is None else lf(2 * np.pi * effect["params"]["corner_hz"])
    if kind == "cross_coupling" and form in ("frame", "frame_command"):
        return phys()[axis].frame
    return None
