"""twin.physics beyond the impulse response itself: how long a machine rings and settles."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest

from gcode_feedopt.optimize.slowdown import SlowdownSettings
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.builtin import modal_frf
from gcode_feedopt.profile.schema import FRFSet, Mode
from gcode_feedopt.twin.modal import ModalModel
from gcode_feedopt.twin.physics import (RING_FRACTION, AxisPhysics, memory_time_s,
                                        mode_scan_band, ring_time_s, settle_time_s)


def _one_mode_profile(freq_hz, zeta):
    """ender3pro with both axes measured as one mode (four FRFs scattered by 0.1 % in
    frequency, 1–249 Hz in 0.5 Hz steps)."""
    prof = load_profile("ender3pro")
    f = np.arange(1.0, 249.5, 0.5)
    resp = np.vstack([modal_frf(f, [Mode(freq_hz * (1 + 1e-3 * k), zeta, 1.0)])
                      for k in (-1.5, -0.5, 0.5, 1.5)])
    frf = FRFSet(freq_hz=f, response=resp, labels=tuple(f"m{k}" for k in range(4)))
    axes = {ax: dataclasses.replace(prof.axes[ax], frf=frf) for ax in "xy"}
    return dataclasses.replace(prof, axes=axes)


@pytest.mark.parametrize("freq_hz, zeta", [(30.0, 0.03), (45.0, 0.06)])
def test_ring_time_of_one_mode_is_its_envelopes_decay(freq_hz, zeta):
    """One mode rings while e^(−ζωt) is above RING_FRACTION of where |h| peaks (a quarter
    period in): ln(1/RING_FRACTION)/(ζω), give or take half a period."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = ring_time_s(_one_mode_profile(freq_hz, zeta))
    w = 2 * math.pi * freq_hz
    expected = math.log(1 / RING_FRACTION) / (zeta * w)
    assert abs(got - expected) <= 0.5 / freq_hz + 0.004


def test_an_overdamped_mode_settles_as_its_slow_pole_decays():
    """(2ζωs + ω²)/(s² + 2ζωs + ω²) at ζ 2 has real poles; its step response creeps in on
    the slow one long after the impulse response has died down: settle_time_s is the last
    time the step response is off 1 by RING_FRACTION (scipy's continuous step response,
    within 2 samples), longer than ring_time_s."""
    from scipy import signal

    freq_hz, zeta = 10.0, 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof = _one_mode_profile(freq_hz, zeta)
        got, ring = settle_time_s(prof), ring_time_s(prof)
    w = 2 * math.pi * freq_hz
    t = np.arange(0.0, 2.0, 1e-4)
    _, y = signal.step(([2 * zeta * w, w * w], [1.0, 2 * zeta * w, w * w]), T=t)
    expected = t[np.flatnonzero(np.abs(y - 1.0) > RING_FRACTION)[-1]]
    assert abs(got - expected) <= 2 * prof.ts_s, (got, expected)
    assert got > 1.5 * ring
    assert memory_time_s(prof) == got


def test_the_built_in_machines_ring_for_less_than_the_slow_downs_defaults():
    """The slow-down's defaults (0.3 s of history, 0.5 s of look-back) were measured on these;
    `SlowdownSettings.seeing_out` leaves them as they are there (they settle as they stop
    ringing)."""
    for name in ("ender3pro", "voron24"):
        st = SlowdownSettings()
        prof = load_profile(name)
        assert settle_time_s(prof) <= ring_time_s(prof) == memory_time_s(prof)
        assert st.seeing_out(memory_time_s(prof)) == st


def _members_around(freq_hz, spread, zeta=0.05):
    """Three one-mode members at freq_hz·(1 − spread, 1, 1 + spread), their parameter mean the
    representative model (as ``ModalSet.mean_model`` takes it)."""
    ms = tuple(ModalModel(np.array([freq_hz * r]), np.array([zeta]), np.array([0.0]),
                          np.array([1.0])) for r in (1 - spread, 1.0, 1 + spread))
    return AxisPhysics(np.zeros(8), np.zeros((8, 0)), freq_hz, model=ms[1], members=ms,
                       band_hz=np.arange(2.0, 150.0, 0.5))


@pytest.mark.parametrize("form", ["mass", "scale"])
def test_a_move_inside_the_members_spread_is_no_change_of_the_machine(form):
    """Members 1 % apart: a move of a fifth of that stays inside their spread at every
    frequency; a 5 % move does not (it leaves the spread at the peak, tens of times over)."""
    phys = _members_around(50.0, 0.01)
    assert phys.move_inside_spread(form, 50.1, 50.0)
    assert phys.move_inside_spread(form, 49.9, 50.0)
    assert not phys.move_inside_spread(form, 47.5, 50.0)
    assert not phys.move_inside_spread(form, 52.5, 50.0)


def test_one_member_is_compared_with_a_typical_machines_spread():
    """One FRF gives no spread: a typical machine's (modal.PRIOR_SPREAD_FREQ, 1.5 %) stands in,
    so a 0.2 % move is a machine of the profile's population and a 5 % one is not; without a
    band nothing is compared and every move is a change."""
    one = _members_around(50.0, 0.01)
    one = dataclasses.replace(one, members=one.members[:1])
    assert one.move_inside_spread("mass", 50.1, 50.0)
    assert not one.move_inside_spread("mass", 47.5, 50.0)
    assert not one.move_inside_spread("mass", 52.5, 50.0)
    assert not dataclasses.replace(_members_around(50.0, 0.01), band_hz=None).move_inside_spread(
        "mass", 50.1, 50.0)


def test_another_measurement_of_the_same_machine_is_inside_its_spread():
    """Four members of a population whose mode scatters by 0.5 % in frequency: a further
    machine of that population, the representative mode moved to it, is inside in about
    P(|t₃| ≤ √F₀.₉₅(2, 6)) = 0.89 of draws (one parameter moves every bin alike: the complex
    bound of one more member is then a t bound; 0.86 measured here). The furthest member's
    deviation, the bound until seed 31 (tests/foreign), holds a further draw only where it
    falls inside the four members' range about their mean: 0.63 of these draws. A move ten
    times the scatter is never inside."""
    rng = np.random.default_rng(3)
    f0, sd, n = 40.0, 0.005, 4
    inside, far = [], []
    for _ in range(300):
        fs = f0 * (1 + sd * rng.standard_normal(n + 1))
        ms = tuple(ModalModel(np.array([f]), np.array([0.05]), np.array([0.0]), np.array([1.0]))
                   for f in fs[:n])
        rep = ModalModel(np.array([fs[:n].mean()]), np.array([0.05]), np.array([0.0]),
                         np.array([1.0]))
        phys = AxisPhysics(np.zeros(8), np.zeros((8, 0)), f0, model=rep, members=ms,
                           band_hz=np.arange(2.0, 150.0, 0.5))
        inside.append(phys.move_inside_spread("mass", fs[n], f0))
        far.append(phys.move_inside_spread("mass", fs[:n].mean() * (1 - 10 * sd), f0))
    assert 0.83 <= np.mean(inside) <= 0.95, np.mean(inside)
    assert not any(far)


def test_the_band_a_mode_is_scanned_over():
    """``mode_scan_band``: three or more members' range widened by half its width on each
    side; fewer also cover the 95 % band of one more draw of a typical machine's spread. A
    machine whose mode scatters as PRIOR_SPREAD_FREQ says, measured once or twice: a further
    draw of it (the plant of the logs) falls in the band ≈ 95 % of the time either way (the
    band is that closed form: the plant and the members' mean differ by σ·√(1 + 1/n)); the
    members' widened range adds a little when there are two (measured: 95.2 % both)."""
    from gcode_feedopt.twin.modal import PRIOR_SPREAD_FREQ

    assert mode_scan_band((49.0, 50.4), 49.7, 4) == pytest.approx((48.3, 51.1))
    assert mode_scan_band((49.0, 50.4), 49.7, 3) == pytest.approx((48.3, 51.1))
    w = 1.959964 * PRIOR_SPREAD_FREQ * math.sqrt(2)
    assert mode_scan_band((50.0, 50.0), 50.0, 1) == pytest.approx((50 * math.exp(-w),
                                                                    50 * math.exp(w)))
    rng = np.random.default_rng(11)
    for n, lo_cov, hi_cov in ((1, 0.94, 0.96), (2, 0.945, 0.965)):
        fs = 40.0 * np.exp(PRIOR_SPREAD_FREQ * rng.standard_normal((20000, n + 1)))
        inside = [lo <= f[n] <= hi for f in fs
                  for lo, hi in [mode_scan_band((f[:n].min(), f[:n].max()), f[:n].mean(), n)]]
        assert lo_cov <= np.mean(inside) <= hi_cov, (n, np.mean(inside))


def test_the_residual_filter_is_the_ridge_least_squares_of_the_lagged_command():
    """twin.residual.fit_filter builds its normal equations from correlations (no K × N
    matrix): equal to the explicit regression on the same lags (in increments plus the oldest
    position, with its ridge), with and without a warm-up; and a residual that is a filter of
    the command is recovered tap for tap."""
    from numpy.lib.stride_tricks import sliding_window_view

    from gcode_feedopt.twin.residual import filter_series, fit_filter

    rng = np.random.default_rng(3)
    for K, n, start in ((400, 25, 0), (400, 25, 60), (60, 80, 5)):
        w = np.cumsum(rng.standard_normal(K))
        r = rng.standard_normal(K)
        X = sliding_window_view(np.concatenate([np.zeros(n - 1), w]), n)[:, ::-1][start:]
        dw = np.diff(w, prepend=0.0)
        Z = np.column_stack([sliding_window_view(np.concatenate([np.zeros(n - 2), dw]),
                                                 n - 1)[:, ::-1][start:], X[:, n - 1]])
        A = Z.T @ Z
        c = np.linalg.solve(A + 1e-6 * np.trace(A[:-1, :-1]) / (n - 1) * np.eye(n),
                            Z.T @ r[start:])
        np.testing.assert_allclose(X @ fit_filter(w, r, n, start, ridge=1e-6), Z @ c, rtol=1e-8,
                                   atol=1e-10 * np.abs(Z @ c).max())
    w = np.cumsum(np.cumsum(rng.standard_normal(3000)))
    g = np.exp(-np.arange(40) / 8.0) * np.sin(np.arange(40) / 3.0)
    got = fit_filter(w, filter_series(g[:, None], w)[0], 40, start=100, ridge=0.0)
    np.testing.assert_allclose(got, g, atol=1e-8)


def test_the_residual_filters_ridge_is_chosen_on_the_logs_second_half():
    """With the ridge chosen on held-out data (twin.residual.fit_filter), a residual of 1 µm
    white noise alone leaves no filter: the best ridge explains under half of the held-out
    variance (a fixed ridge of 1e-8 leaves a filter whose output is 8.9 % of the noise on the
    log and 25 % on another command: the noise's fit, largest where the log's command never
    went); a residual that is a filter of the command (4.3 µm RMS) plus that noise gives the
    filter's output back to 0.2 µm (measured 0.03 µm)."""
    from gcode_feedopt.twin.residual import filter_series, fit_filter

    rng = np.random.default_rng(5)
    K, n = 8000, 200
    w = np.cumsum(np.cumsum(np.repeat(rng.standard_normal(K // 100), 100))) * 1e-3
    noise = 0.001 * rng.standard_normal(K)
    true = 2e-6 * np.exp(-np.arange(n) / 30.0)
    true -= true.mean()
    signal = filter_series(true[:, None], w)[0]
    assert not np.any(fit_filter(w, noise, n))
    fixed = fit_filter(w, noise, n, ridge=1e-8)
    other = np.cumsum(np.cumsum(np.repeat(rng.standard_normal(80), 100))) * 3e-3
    assert np.sqrt(np.mean(filter_series(fixed[:, None], other)[0] ** 2)) > 0.1 * 0.001
    got = filter_series(fit_filter(w, signal + noise, n)[:, None], w)[0]
    assert np.sqrt(np.mean(signal ** 2)) > 4 * 0.001
    assert np.sqrt(np.mean((got - signal) ** 2)) < 0.2 * 0.001


def test_a_grid_too_coarse_for_the_raw_bins_is_the_profiles_error():
    """`twin.physics: bins` on a 2 Hz grid at Ts 2 ms (250 taps determined, 500 asked): a
    ProfileError naming the profile and the axis, not an internal error."""
    import dataclasses

    from gcode_feedopt.errors import ProfileError
    from gcode_feedopt.profile import load_profile
    from gcode_feedopt.profile.schema import FRFSet
    from gcode_feedopt.twin.physics import axis_impulse, member_impulses, with_physics

    prof = with_physics(load_profile("ender3pro"), "bins")
    f = np.arange(1.0, 150.0, 2.0)
    resp = np.array([1.0 / (1 + 2j * np.pi * f * 0.002 + (1j * f / 40.0) ** 2)] * 3)
    ax = dataclasses.replace(prof.axes["x"], frf=FRFSet(freq_hz=f, response=resp,
                                                        labels=("a", "b", "c")))
    prof = dataclasses.replace(prof, axes={**prof.axes, "x": ax})
    assert prof.twin.n_taps == 500 and prof.ts_s == 0.002
    for call in (axis_impulse, member_impulses):
        with pytest.raises(ProfileError, match=r"axis x \(twin.physics: bins\): n_taps 500 "
                                               r"exceeds the estimable length N_h = 250"):
            call(prof, "x")


def _pairs_model(num, poles_hz_zeta):
    """ModalModel of num(s)/Π(s² + 2ζωs + ω²) (strictly proper) from scipy's partial
    fractions: a pair of residues r, r̄ at p, p̄ is (2 Re r·s − 2 Re(r p̄))/(s² + 2ζωs + ω²)."""
    from scipy.signal import residue

    den = np.array([1.0])
    for f, z in poles_hz_zeta:
        w = 2 * math.pi * f
        den = np.polymul(den, [1.0, 2 * z * w, w * w])
    r, p, _ = residue(num, den)
    f = np.array([pz[0] for pz in poles_hz_zeta])
    zeta = np.array([pz[1] for pz in poles_hz_zeta])
    b1 = np.zeros(f.size)
    b0 = np.zeros(f.size)
    for ri, pi in zip(r, p):
        if pi.imag <= 0:
            continue
        k = int(np.argmin(np.abs(np.abs(pi) - 2 * math.pi * f)))
        b1[k] = 2 * ri.real
        b0[k] = -2 * (ri * np.conj(pi)).real / (2 * math.pi * f[k]) ** 2
    dc = float(np.polyval(num, 0.0) / np.polyval(den, 0.0))
    return ModalModel(f, zeta, b1, b0, lag_s=0.0, dc_gain=dc)


def test_a_force_on_the_frame_rings_without_the_commands_antiresonance():
    """A chain whose command enters beside the frame has a zero pair at the frame's own
    frequency: H = ω₁²ω₂²/ω_z² (s² + 2ζ_z ω_z s + ω_z²)/(D₁D₂). A force at the frame's end
    of the chain reaches the carriage as ω₁²ω₂²/(D₁D₂): ``frame_model`` takes that pair out
    (the closed form to 1e-9 over 1–200 Hz), keeps the real zero of a damper (a far one,
    s = −k/c), and is None where the pair lies above the measured band or is no
    antiresonance (ζ_z ≥ ANTIRESONANCE_ZETA)."""
    from gcode_feedopt.twin.physics import ANTIRESONANCE_ZETA, frame_model

    (f1, z1), (f2, z2), (fz, zz), fc = (31.0, 0.05), (95.0, 0.07), (78.0, 0.04), 400.0
    w1, w2, wz, wc = (2 * math.pi * f for f in (f1, f2, fz, fc))
    k = (w1 * w2) ** 2 / wz ** 2
    num = k * np.polymul([1.0, 2 * zz * wz, wz * wz], [1.0 / wc, 1.0])
    mm = _pairs_model(num, [(f1, z1), (f2, z2)])
    f = np.linspace(1.0, 200.0, 60)
    s = 2j * math.pi * f
    assert np.allclose(mm.response(f), np.polyval(num, s) / (
        (s * s + 2 * z1 * w1 * s + w1 * w1) * (s * s + 2 * z2 * w2 * s + w2 * w2)), rtol=1e-9)
    want = (w1 * w2) ** 2 * (1 + s / wc) / ((s * s + 2 * z1 * w1 * s + w1 * w1)
                                            * (s * s + 2 * z2 * w2 * s + w2 * w2))
    got = frame_model(mm, band_hi_hz=150.0)
    assert got is not None
    assert np.allclose(got.response(f), want, rtol=1e-9, atol=1e-12)
    assert got.response(np.array([0.0]))[0] == pytest.approx(1.0, abs=1e-12)
    assert frame_model(mm, band_hi_hz=70.0) is None           # the pair above the band
    num_damped = k * np.polymul([1.0, 2 * ANTIRESONANCE_ZETA * wz, wz * wz], [1.0 / wc, 1.0])
    assert frame_model(_pairs_model(num_damped, [(f1, z1), (f2, z2)]), 150.0) is None


def test_the_frame_response_of_a_fitted_belt_and_hotend_is_its_force_path():
    """tests/foreign's belt + hotend chain (rotor lag → belt → carriage → hotend, the motor
    on a sprung frame), its exact FRF fitted as ``profile build`` fits one: the fit's frame
    response is the chain's response to a force on its frame to 1e-4 over 5–60 Hz (the
    command path's own differs from it by up to 53 % there)."""
    from gcode_feedopt.twin.modal import fit_modal
    from gcode_feedopt.twin.physics import frame_model
    from tests.foreign.machines import make_machine

    ch = make_machine(805).chans["x"]
    assert ch.kind == "belt_hotend"
    f = np.arange(2.0, 240.0, 0.5)
    fit = fit_modal(f, ch.frf(f))
    got = frame_model(fit.model, band_hi_hz=float(f[-1]))
    assert got is not None
    fb = np.arange(5.0, 60.0, 1.0)
    want = ch.frf(fb, inp=1) / ch.frf(np.array([1e-4]), inp=1)[0]
    ratio = got.response(fb) / want
    assert np.max(np.abs(ratio - 1)) < 1e-4, ratio
    assert np.max(np.abs(np.abs(ch.frf(fb) / want) - 1)) > 0.5


def test_each_axis_loads_its_own_loop():
    """``AxisPhysics.loaded``, ``loaded_hz`` and ``load_force`` of each axis are its own
    representative model's (ModalModel.loaded, load_force) laid on its members' mean, as
    written out here: the closures of the two axes share no state (a cache bound late once
    gave x the y axis's loaded models), and a second ``axis_physics`` of the same profile is
    the cached one, its scans kept."""
    from gcode_feedopt.twin.physics import axis_physics, mean_model, nominal_impulse

    prof = load_profile("ender3pro")
    phys = axis_physics(prof)
    assert axis_physics(prof)["x"] is phys["x"]
    ratio, a = 0.3, 2 * math.pi * 25.0
    got = {}
    for ax in "xy":
        mm = mean_model(prof, ax)
        mean = nominal_impulse(prof)[ax][0]
        n, ts = mean.size, prof.ts_s
        h_mm = mm.impulse(ts, n)
        want = mean - h_mm / np.sum(h_mm) + mm.loaded(ratio, a).impulse(ts, n) / np.sum(h_mm)
        want /= np.sum(want)
        got[ax] = phys[ax].loaded(ratio, a)
        np.testing.assert_allclose(got[ax], want, rtol=0, atol=1e-12)
        f_top = min(400.0, 0.5 / ts)
        assert phys[ax].loaded_hz(ratio, a) == mm.loaded(ratio, a).pair_at_peak_hz(1.0, f_top)
        hf = mm.load_force(a).impulse(ts, n)
        np.testing.assert_allclose(phys[ax].load_force(a),
                                   hf / np.max(np.abs(np.cumsum(hf))), rtol=0, atol=1e-12)
    assert np.max(np.abs(got["x"] - got["y"])) > 1e-3 * np.max(np.abs(got["x"]))
