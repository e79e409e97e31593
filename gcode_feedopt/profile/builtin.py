"""Generator of the built-in profiles ``ender3pro`` and ``nomad3``.

No measured FRF *sets* (several FRFs with phase) of these exact machines are public, so the
FRFs are **modelled** from published facts and say so in their provenance:

- Ender 3 / 3 Pro: bed (Y) mode 36–42 Hz in every published Klipper measurement, X 30–95 Hz
  by toolhead mass, damping ratio 0.07–0.15 (../shared/data/PROVENANCE.md). The measured
  Ender 3 spectra in ../shared/data/measured/ put the stock X peaks at 40/51 Hz (45/59 Hz after
  a change) with nearly equal power, and Y at 36 Hz (39 Hz after belt tightening) with a
  weaker second peak; the modes below follow them.
- Nomad 3: a stepper / lead-screw desktop mill, stiffer than a belt printer; modes modelled at
  55–110 Hz, lightly damped (ball/lead-screw drives with linear rails).

Each axis gets N_H = 9 FRFs = 3 excitation amplitudes (2, 3, 4 m/s², as the paper's FRF
campaign) × 3 repeats. The modes soften with amplitude (frequency −2.5 % and damping +10 % per
amplitude step, the trend of the paper's Figs. 7–8 and 15–16) and scatter from repeat to
repeat (frequency ±1 %, damping ±5 %, 1σ; seeded, so the files are reproducible).

Model, commanded → actual position of a base-excited mode (the motor drives the load through
a belt or screw stiffness k and damping c):  H(s) = Σ g_i (2ζ_i ω_i s + ω_i²)/(s² + 2ζ_i ω_i s
+ ω_i²), Σ g_i = 1, so the DC gain is exactly 1 (a stepper machine reaches the commanded
position at rest).

Run ``python -m gcode_feedopt.profile.builtin [OUTDIR]`` to regenerate profiles/.
"""

from __future__ import annotations

import copy
import dataclasses
import pathlib
import sys

import numpy as np

from .io import save_profile
from .schema import AxisModel, Firmware, FRFSet, Limits, MachineProfile, Mode, Prior, TwinSettings

#: Frequency grid of the modelled FRFs: 0 to the Nyquist frequency of Ts = 2 ms in 0.5 Hz
#: steps, so the impulse response is N_h = 1/(Ts·Δf) = 1000 taps (2 s) long, far beyond the
#: decay of the slowest mode (ζω ≈ 21 1/s → e^-42 after 2 s).
DF_HZ = 0.5
TS_S = 0.002
AMPLITUDES_MM_S2 = (2000.0, 3000.0, 4000.0)
REPEATS = 3
SOFTEN_PER_STEP = 0.025
DAMP_PER_STEP = 0.10
SCATTER_FREQ = 0.01
SCATTER_DAMP = 0.05


def modal_frf(freq_hz: np.ndarray, modes) -> np.ndarray:
    """Σ g (2ζω s + ω²)/(s² + 2ζω s + ω²) at s = j2πf."""
    s = 2j * np.pi * freq_hz
    h = np.zeros_like(s)
    for m in modes:
        w = 2 * np.pi * m.freq_hz
        h += m.gain * (2 * m.damping * w * s + w * w) / (s * s + 2 * m.damping * w * s + w * w)
    return h


def frf_campaign(modes, seed: int, ts_s: float = TS_S, df_hz: float = DF_HZ):
    """9 FRFs (3 amplitudes × 3 repeats) of a modal axis; returns (FRFSet, per-FRF modes)."""
    rng = np.random.default_rng(seed)
    freq = np.arange(0.0, 0.5 / ts_s + df_hz / 2, df_hz)
    resp, labels, used = [], [], []
    for ka, amp in enumerate(AMPLITUDES_MM_S2):
        for r in range(REPEATS):
            ms = []
            for m in modes:
                f = m.freq_hz * (1 - SOFTEN_PER_STEP * ka) * (1 + SCATTER_FREQ * rng.standard_normal())
                z = m.damping * (1 + DAMP_PER_STEP * ka) * (1 + SCATTER_DAMP * rng.standard_normal())
                ms.append(Mode(freq_hz=float(f), damping=float(z), gain=m.gain))
            resp.append(modal_frf(freq, ms))
            labels.append(f"a{amp / 1000:g}ms2_r{r + 1}")
            used.append(ms)
    return FRFSet(freq_hz=freq, response=np.vstack(resp), labels=tuple(labels)), used


def _axis(modes, seed, source):
    frf, used = frf_campaign(modes, seed)
    prov = {
        "kind": "modelled",
        "model": "sum of base-excited 2nd-order modes, unit DC gain",
        "source": source,
        "campaign": f"{len(AMPLITUDES_MM_S2)} excitation amplitudes {list(AMPLITUDES_MM_S2)} mm/s^2 x "
                    f"{REPEATS} repeats; softening {SOFTEN_PER_STEP:.1%} freq and +{DAMP_PER_STEP:.0%} "
                    f"damping per amplitude step; repeat scatter {SCATTER_FREQ:.0%} freq, "
                    f"{SCATTER_DAMP:.0%} damping (1 sigma), seed {seed}",
        "measurements": [{"label": lab, "modes": [[round(m.freq_hz, 3), round(m.damping, 4)] for m in ms]}
                         for lab, ms in zip(frf.labels, used)],
    }
    return AxisModel(frf=frf, modes=tuple(modes), provenance=prov)


def ender3pro() -> MachineProfile:
    limits = Limits(vmax_mm_s=70.0, amax_mm_s2=3000.0, jmax_mm_s3=None,
                    axis_vmax_mm_s={"x": 500.0, "y": 500.0, "z": 5.0, "e": 25.0},
                    axis_amax_mm_s2={"x": 3000.0, "y": 3000.0, "z": 100.0, "e": 5000.0},
                    tolerance_mm=0.1, stringency=0.95, max_volumetric_mm3_s=12.0,
                    filament_diameter_mm=1.75, axis_jerk_mm_s={"x": 20.0, "y": 20.0})
    firmware = Firmware(
        flavour="marlin", g91_relative_e=True, accel_mm_s2=3000.0, travel_accel_mm_s2=3000.0,
        max_accel_mm_s2={"x": 3000.0, "y": 3000.0, "z": 100.0, "e": 5000.0},
        max_feed_mm_s={"x": 500.0, "y": 500.0, "z": 5.0, "e": 25.0},
        junction_deviation_mm=0.013, square_corner_velocity_mm_s=5.0, minimum_cruise_ratio=0.5,
        mm_per_arc_segment=1.0, max_lines_per_s=300.0, retract_mm=3.0, retract_speed_mm_s=45.0,
        configured_accel_mm_s2=500.0, configured_max_accel_mm_s2={"x": 500.0, "y": 500.0})
    axes = {
        "x": _axis([Mode(42.0, 0.10, 0.55), Mode(54.0, 0.08, 0.45)], 3101,
                   "Ender 3 Klipper spectra ../shared/data/measured/ender3_resonances_x_*.csv "
                   "(peaks 40/51 Hz, later 45/59 Hz, nearly equal power)"),
        "y": _axis([Mode(37.0, 0.09, 0.80), Mode(51.0, 0.10, 0.20)], 3102,
                   "Ender 3 Klipper spectra ../shared/data/measured/ender3_resonances_y_*.csv "
                   "(bed mode 36 Hz, 39 Hz after belt tightening; published 36-42 Hz)"),
    }
    twin = TwinSettings(n2=10, n3=30, sigma_eps_mm=0.01, coef_variance="ensemble", n_taps=500)
    return MachineProfile(
        name="ender3pro",
        description="Creality Ender 3 Pro (Marlin 2), limits of Kim & Okwudire Sec. 6.1; FRFs modelled",
        ts_s=TS_S, limits=limits, firmware=firmware, axes=axes, twin=twin,
        provenance={
            "limits": "Kim & Okwudire Sec. 6.1: V_max 70 mm/s, A_max 3 m/s^2, E_max 0.1 mm, eta 95 %. "
                      "max_volumetric_mm3_s 12: what the stock MK8-style hotend is commonly quoted to "
                      "melt in PLA at 200-210 C (10-15 mm^3/s); set yours (it only acts under "
                      "--speed machine). axis_jerk_mm_s 20: the largest instantaneous X/Y speed "
                      "change Marlin lets M205 set on its Ender-3 configurations "
                      "(LIMITED_JERK_EDITING: MAX_JERK_EDIT_VALUES 20, twice the default classic "
                      "jerk of 10 mm/s); the plan's junctions stay within it (classic jerk 20, "
                      "junction deviation 20^2/(8*3000) = 0.016 mm) where the twin allows",
            "firmware": "Marlin 2 defaults of the Ender-3 Pro configuration for feed (X/Y 500, Z 5, "
                        "E 25 mm/s) and firmware retraction (3 mm at 45 mm/s); the stock firmware "
                        "limits X/Y acceleration to 500 mm/s^2 (configured_*): the plan is timed at "
                        "3000 mm/s^2 (the paper's A_max), which the written file sets with M201/M204 "
                        "before its first re-timed move and takes back to 500 after its last. "
                        "Junction deviation 0.013 mm (Marlin 2 default). max_lines_per_s 300: "
                        "115200-baud serial carries ~11.5 kB/s, ~35 bytes per G1 line.",
            "frf": "modelled (no measured FRF set of this machine is public); see axes.*.provenance",
            "twin": "n2 10, n3 30, sigma_eps 0.01 mm as in Kim & Okwudire Sec. 6.1",
            "priors": PRIORS_NOTE,
            "generator": "python -m gcode_feedopt.profile.builtin",
        })


def nomad3() -> MachineProfile:
    limits = Limits(vmax_mm_s=30.0, amax_mm_s2=5000.0, jmax_mm_s3=None,
                    axis_vmax_mm_s={"x": 100.0, "y": 100.0, "z": 20.0, "e": 25.0},
                    axis_amax_mm_s2={"x": 5000.0, "y": 5000.0, "z": 1000.0, "e": 5000.0},
                    tolerance_mm=0.4, stringency=0.95)
    firmware = Firmware(
        flavour="marlin", g91_relative_e=True, accel_mm_s2=5000.0, travel_accel_mm_s2=5000.0,
        max_accel_mm_s2={"x": 5000.0, "y": 5000.0, "z": 1000.0, "e": 5000.0},
        max_feed_mm_s={"x": 100.0, "y": 100.0, "z": 20.0, "e": 25.0},
        junction_deviation_mm=0.01, square_corner_velocity_mm_s=5.0, minimum_cruise_ratio=0.5,
        mm_per_arc_segment=0.5, max_lines_per_s=500.0, retract_mm=0.0, retract_speed_mm_s=30.0)
    axes = {
        "x": _axis([Mode(68.0, 0.06, 1.0)], 3201,
                   "modelled: stepper + lead-screw gantry of a desktop mill, single dominant mode"),
        "y": _axis([Mode(55.0, 0.05, 0.85), Mode(110.0, 0.04, 0.15)], 3202,
                   "modelled: stepper + lead-screw table of a desktop mill, table mode + screw mode"),
    }
    twin = TwinSettings(n2=3, n3=10, sigma_eps_mm=0.01, coef_variance="ensemble", n_taps=500)
    return MachineProfile(
        name="nomad3",
        description="Carbide 3D Nomad 3 desktop mill, limits of Kim & Okwudire Sec. 5; FRFs modelled",
        ts_s=TS_S, limits=limits, firmware=firmware, axes=axes, twin=twin,
        provenance={
            "limits": "Kim & Okwudire Sec. 5: V_max 30 mm/s, A_max 5 m/s^2, E_max 0.4 mm, eta 95 %",
            "firmware": "planned as a trapezoidal, junction-deviation firmware (the 'marlin' model); "
                        "the real Nomad 3 runs Grbl, which plans the same way",
            "frf": "modelled (no measured FRF set of this machine is public); see axes.*.provenance",
            "twin": "n2 3, n3 10, sigma_eps 0.01 mm as in Kim & Okwudire Sec. 5",
            "priors": PRIORS_NOTE,
            "generator": "python -m gcode_feedopt.profile.builtin",
        })


#: The measured data behind ``voron24`` (read, never copied: the profile holds FRFs derived from it)
MEASURED = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "measured"
VORON_BELTS = ("voron2.4_klipper-raw-accel_belt-test_20231128_221505_A.csv",
               "voron2.4_klipper-raw-accel_belt-test_20231128_221505_B.csv")


def _names_only(text: str, files) -> str:
    for f in files:
        for form in {str(f), str(pathlib.Path(f).resolve())}:
            text = text.replace(form, pathlib.Path(f).name)
    return text


def voron24(measured_dir=MEASURED) -> MachineProfile:
    """A Voron 2.4 (CoreXY, Klipper) from a published raw belt test: Klipper's resonance test
    along belt A (direction (1, 1)) and belt B ((1, −1)), identified as ``identify`` does
    (H1 with coherence, 4 FRFs per recording, 3 modes). On a CoreXY x = (a + b)/2 and
    y = (a − b)/2, so a move along X or Y drives both belts and each axis's response is
    (G_A + G_B)/2: the axes' FRF sets are the means of A's and B's segments, pair by pair. What
    the two belts' difference does ((G_A − G_B)/2 of the other axis's command) is not in a
    per-axis FRF; ``diagnose`` names it as cross_coupling, form ``belt`` (twin.extensions)."""
    # identify's stack on use (this module is loaded by every profile load)
    from ..identify.axis import identify_axis

    files = [pathlib.Path(measured_dir) / f for f in VORON_BELTS]
    a, _, warn_a = identify_axis("x", files[:1], 3)
    b, _, warn_b = identify_axis("y", files[1:], 3)
    resp = 0.5 * (a.frf.response + b.frf.response)
    labels = tuple(f"(A{i + 1}+B{i + 1})/2" for i in range(resp.shape[0]))
    modes = tuple(Mode(0.5 * (ma.freq_hz + mb.freq_hz), 0.5 * (ma.damping + mb.damping),
                       0.5 * (ma.gain + mb.gain)) for ma, mb in zip(a.modes, b.modes))
    prov = {"kind": "measured: Klipper raw accelerometer belt test (identify)",
            "source": "GitHub agravelot/voron2-config, commit f2cff10d, K-ShakeTune_results/belts/ "
                      "(../shared/data/PROVENANCE.md)",
            "belt_modes_hz": {"A": [round(m.freq_hz, 2) for m in a.modes],
                              "B": [round(m.freq_hz, 2) for m in b.modes]},
            "combination": "corexy: each axis's FRF is (G_A + G_B)/2, segment i of A with segment i of B",
            # file names only: the generated profile must not depend on where the data sits
            "warnings": [_names_only(w, files) for w in warn_a + warn_b]}
    axes = {ax: AxisModel(frf=FRFSet(a.frf.freq_hz, resp, labels), modes=modes, provenance=prov)
            for ax in ("x", "y")}
    limits = Limits(vmax_mm_s=300.0, amax_mm_s2=5000.0, jmax_mm_s3=None,
                    axis_vmax_mm_s={"x": 300.0, "y": 300.0, "z": 15.0, "e": 120.0},
                    axis_amax_mm_s2={"x": 5000.0, "y": 5000.0, "z": 350.0, "e": 5000.0},
                    tolerance_mm=0.1, stringency=0.95, max_volumetric_mm3_s=24.0,
                    filament_diameter_mm=1.75)
    firmware = Firmware(
        flavour="klipper", g91_relative_e=False, accel_mm_s2=5000.0, travel_accel_mm_s2=5000.0,
        max_accel_mm_s2={"x": 5000.0, "y": 5000.0, "z": 350.0, "e": 5000.0},
        max_feed_mm_s={"x": 300.0, "y": 300.0, "z": 15.0, "e": 120.0},
        junction_deviation_mm=0.013, square_corner_velocity_mm_s=5.0, minimum_cruise_ratio=0.5,
        mm_per_arc_segment=1.0, max_lines_per_s=2000.0, retract_mm=0.0, retract_speed_mm_s=35.0,
        configured_accel_mm_s2=3000.0, configured_max_accel_mm_s2={"x": 3000.0, "y": 3000.0})
    twin = TwinSettings(n2=10, n3=30, sigma_eps_mm=0.01, coef_variance="ensemble", n_taps=500)
    return MachineProfile(
        name="voron24",
        description="Voron 2.4 CoreXY (Klipper); FRFs identified from a published raw belt test",
        ts_s=TS_S, limits=limits, firmware=firmware, axes=axes, twin=twin,
        provenance={
            "limits": "what a stock Voron 2.4 (LDO 0.9 deg motors, 24 V) commonly runs: 300 mm/s, "
                      "5000 mm/s^2 X/Y (hardware), Z 15 mm/s at 350 mm/s^2; max_volumetric 24 "
                      "mm^3/s (a Revo/Dragon-class hotend in PLA); set yours",
            "firmware": "Klipper, printer.cfg as ../shared/tools/klipper-referee/ runs it: "
                        "max_accel 3000 (configured_*; the plan's 5000 is set with "
                        "SET_VELOCITY_LIMIT before the first re-timed move and taken back after "
                        "the last), square_corner_velocity 5, minimum_cruise_ratio 0.5. "
                        "max_lines_per_s 2000: Klipper's host-side queue, not a serial line. "
                        "Input shaping and pressure advance run below our plan (README, Klipper)",
            "frf": "measured (see axes.*.provenance)",
            "twin": "n2 10, n3 30, sigma_eps 0.01 mm (as ender3pro)",
            "priors": PRIORS_NOTE,
            "generator": "python -m gcode_feedopt.profile.builtin (needs ../shared/data/measured)",
        })


BUILTINS = {"ender3pro": ender3pro, "nomad3": nomad3, "voron24": voron24}

#: Why the shipped built-ins carry no learned prior: the twin learns the plant draw as a latent
#: variable, so a prior fitted to the same FRF spread would count it twice (docs/twin.md §6).
PRIORS_NOTE = ("not learned (absent on purpose): the twin starts from its physics prior and "
               "learns the plant draw as a latent variable; an Appendix-A MLE prior fitted to "
               "the same FRF spread would count it twice (docs/twin.md). "
               "'python -m gcode_feedopt.profile.builtin --with-priors' stores one")


def with_learned_priors(prof: MachineProfile) -> MachineProfile:
    """The profile with (μ_β, Σ_β) per axis by the twin's Appendix-A MLE and a record of it."""
    # the twin's physics on use: twin.modal's fitting stack is not needed to load a profile
    # (`gcode-feedopt --help` loads this module; +10 ms at top)
    from ..twin.physics import axis_impulse, member_impulses
    from ..twin.prior import init_prior

    T = prof.twin
    priors = {}
    for ax, model in prof.axes.items():
        mu, cov, record = init_prior(axis_impulse(prof, ax), member_impulses(prof, ax), prof.ts_s,
                                     T.n2, T.n3, T.sigma_eps_mm)
        record = dict(record, frf=f"{prof.name} axis {ax}: {model.frf.n_measurements} FRFs",
                      function="gcode_feedopt.twin.prior.init_prior")
        priors[ax] = Prior(mu=np.asarray(mu, float), cov=np.asarray(cov, float),
                           learned_from=(record,))
    prov = dict(prof.provenance, priors="learned by python -m gcode_feedopt.profile.builtin "
                                        "--with-priors (see twin.priors.*.learned_from)")
    return dataclasses.replace(prof, twin=dataclasses.replace(T, priors=priors), provenance=prov)


def write_builtins(outdir, learn_priors: bool = False) -> list[pathlib.Path]:
    outdir = pathlib.Path(outdir)
    written = []
    for name, make in BUILTINS.items():
        if name == "voron24" and not MEASURED.is_dir():
            print(f"voron24: skipped, its measured data is not at {MEASURED}", file=sys.stderr)
            continue
        prof = make()
        if learn_priors:
            prof = with_learned_priors(prof)
        written.append(save_profile(prof, outdir / f"{name}.yaml"))
    return written


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--with-priors"]
    out = args[0] if args else pathlib.Path(__file__).resolve().parents[2] / "profiles"
    for p in write_builtins(out, learn_priors="--with-priors" in sys.argv[1:]):
        print(p)
