"""The modal physics (twin.modal): exact discretisation, fits on any FRF grid, warnings that
name the file and the frequency."""

import warnings

import numpy as np
import pytest
from scipy.signal import cont2discrete, oaconvolve

from gcode_feedopt.twin.modal import (AxisModal, ModalFit, ModalModel, bin_noise, ensemble_impulse,
                                      fit_axis, fit_modal)
from gcode_feedopt.twin.physics import apply_effects

TS = 0.002

#: a belt + frame machine unlike the built-ins: modes 52 and 131 Hz, a 0.4 ms lag, part of the
#: response following the command directly (d ≠ 0)
TRUTH = ModalModel(freq_hz=np.array([52.0, 131.0]), damping=np.array([0.06, 0.045]),
                   b1_rad_s=np.array([2 * 0.06 * 2 * np.pi * 52 * 0.93, 9.0]),
                   b0=np.array([0.93, 0.05]), lag_s=4e-4)


def noisy_set(model, freq, n, rng, noise=0.01, spread=0.01):
    """n FRFs of ``model`` with its modes scattered by ``spread`` and multiplicative complex
    noise of ``noise`` RMS per line (as a stepped-sine campaign gives)."""
    out = []
    for _ in range(n):
        m = ModalModel(model.freq_hz * (1 + spread * rng.standard_normal(model.n_modes)),
                       model.damping, model.b1_rad_s, model.b0, model.lag_s)
        h = m.response(freq)
        out.append(h * (1 + noise / np.sqrt(2) * (rng.standard_normal(freq.size)
                                                  + 1j * rng.standard_normal(freq.size))))
    return np.array(out)


def test_impulse_is_the_first_order_hold_equivalent():
    """Against scipy's FOH discretisation of the same state space, and against the
    triangle-pulse evaluator (two implementations), to 1e-12."""
    h = TRUTH.impulse(TS, 400)
    A, B, C, D = TRUTH.state_space()
    Ad, Bd, Cd, Dd, _ = cont2discrete((A, B, C, D), TS, method="foh")
    ref = np.empty(400)
    ref[0] = Dd[0, 0]
    x = Bd[:, 0]
    for k in range(1, 400):
        ref[k] = Cd[0] @ x
        x = Ad @ x
    body = slice(0, 400 - 40)  # the last tenth holds the folded tail
    np.testing.assert_allclose(h[body], ref[body], atol=1e-12)
    assert h.sum() == pytest.approx(1.0, abs=1e-12)  # DC gain exactly 1 (tail folded)
    np.testing.assert_allclose(TRUTH.triangle_response(TS, np.arange(400) * TS)[body], h[body],
                               atol=1e-12)


def test_a_step_settles_at_the_command():
    step = np.r_[np.zeros(10), np.ones(990)] * 50.0
    y = oaconvolve(step, TRUTH.impulse(TS, 500))[:1000]
    assert y[-1] == pytest.approx(50.0, abs=1e-9)


def test_delay_shifts_the_response():
    h = TRUTH.impulse(TS, 300)
    hd = TRUTH.delayed(2 * TS).impulse(TS, 300)
    # the same taps two samples later (the last tenth holds the folded tail, which differs)
    np.testing.assert_allclose(hd[2:270], h[:268], atol=1e-12)
    assert abs(hd[:2]).max() < 1e-12 and hd.sum() == pytest.approx(1.0, abs=1e-12)
    k = np.arange(300)
    assert k @ hd * TS == pytest.approx(k @ h * TS + 2 * TS, abs=1e-12)  # 2 samples more lag
    f = np.array([10.0, 80.0])
    np.testing.assert_allclose(TRUTH.delayed(0.003).response(f),
                               TRUTH.response(f) * np.exp(-2j * np.pi * f * 0.003))


def test_a_mode_ringing_past_the_memory_keeps_the_machines_lag():
    """The tail after n_taps·Ts is folded so that the impulse response keeps both H(0) and
    −H'(0): the axis trails a constant-speed command by its true lag. Folded onto tap 0 (the
    sum only), a 32 Hz mode at ζ 0.023 — 1 % of its ringing left after the 1 s memory, as
    tests/foreign seed 305's y — gave members 31.4–32.6 Hz lags of −2.0 … 12.4 ms where each
    trails by 1.69 ms, and a twin 4 ms off on every straight line."""
    lags = []
    for f in np.linspace(31.35, 32.56, 7):
        m = ModalModel(freq_hz=np.array([f, 88.0]), damping=np.array([0.023, 0.064]),
                       b1_rad_s=np.array([0.0, 0.0]), b0=np.array([1.01, 0.06]), lag_s=7e-4)
        h = m.impulse(TS, 500)
        k = np.arange(500)
        # the closed form of −H'(0) is the phase delay at a vanishing frequency
        f0 = 1e-5
        assert m.lag_s_total == pytest.approx(-np.angle(m.response([f0])[0]) / (2 * np.pi * f0),
                                              rel=1e-6)
        assert h.sum() == pytest.approx(1.0, abs=1e-12)
        assert k @ h * TS == pytest.approx(m.lag_s_total, abs=1e-12)
        lags.append(k @ h * TS)
        # the fold is spread thin: the folded taps differ from a response four times as
        # long by less than 1 % of its peak, and the rest not at all
        long = m.impulse(TS, 2000)
        assert np.max(np.abs(h[:450] - long[:450])) < 1e-12
        assert np.max(np.abs(h[450:] - long[450:500])) < 0.01 * np.max(np.abs(long))
        # a ramp at 100 mm/s from rest: the 500-tap response trails it as the long one does
        # but for the start's own ringing after the memory (≤ 2.2 µm of a 170 µm lag; with
        # the lag 4 ms off it was 400 µm)
        t = np.arange(3000) * TS
        ramp = 100.0 * t
        y = oaconvolve(ramp, h)[:3000]
        y_long = oaconvolve(ramp, long)[:3000]
        assert np.max(np.abs(y[600:] - y_long[600:])) < 3e-3
        assert ramp[-1] - y[-1] == pytest.approx(100.0 * m.lag_s_total, abs=1e-9)
        assert m.tail_envelope(TS, 500) == pytest.approx(np.exp(-0.023 * 2 * np.pi * f), rel=1e-9)
    assert np.ptp(lags) < 0.02 * np.mean(lags)


@pytest.mark.parametrize("grid", [
    np.arange(1.5, 230.0, 1.0),     # starts above 1 Hz, 1 Hz steps, ends below Nyquist
    np.arange(0.5, 249.9, 0.5),     # 0.5 Hz steps, no 0 Hz bin
    np.arange(2.0, 200.0, 2.0),     # 2 Hz steps
    np.arange(0.0, 250.1, 1.0),     # with a 0 Hz bin and up to Nyquist
])
def test_fit_recovers_the_modes_on_any_grid(grid):
    rng = np.random.default_rng(3)
    H = noisy_set(TRUTH, grid, 1, rng, noise=0.02, spread=0.0)[0]
    fit = fit_modal(grid[grid > 0], H[grid > 0])
    m = fit.model
    assert m.n_modes == 2
    np.testing.assert_allclose(m.freq_hz, TRUTH.freq_hz, rtol=0.01)
    np.testing.assert_allclose(m.damping, TRUTH.damping, rtol=0.12)
    assert m.dc_gain == 1.0 and m.impulse(TS, 500).sum() == pytest.approx(1.0, abs=1e-12)
    assert fit.rms_rel < 0.03


@pytest.mark.parametrize("step_hz", [1.0, 0.5])
def test_twin_of_a_foreign_machine_beats_actual_equals_command(step_hz):
    """Issue 19: 6 FRFs on a 1.5–229.5 Hz grid with 1 % noise made the raw-bin twin err by
    555 µm where "actual = command" erred by 24 µm. The modal twin's prediction of the mean
    machine is within a few per cent of its dynamic error."""
    rng = np.random.default_rng(7)
    grid = np.arange(1.5, 229.6, step_hz)
    fits = fit_axis(grid, noisy_set(TRUTH, grid, 6, rng), axis="x")
    mean, _ = ensemble_impulse(fits.models, TS, 500)
    t = np.arange(3000) * TS
    cmd = 100 + 40 * np.sin(2 * np.pi * 1.3 * t) * np.minimum(t / 0.5, 1) ** 2
    true = cmd[0] + oaconvolve(cmd - cmd[0], TRUTH.impulse(TS, 500))[:cmd.size]
    pred = cmd[0] + oaconvolve(cmd - cmd[0], mean)[:cmd.size]
    err = np.sqrt(np.mean((pred - true) ** 2))
    naive = np.sqrt(np.mean((cmd - true) ** 2))
    assert err < 0.05 * naive, (err, naive)


def test_magnitude_only_data_is_refused_with_the_file():
    grid = np.arange(1.0, 200.0, 1.0)
    mag = np.abs(TRUTH.response(grid)).astype(complex)[None, :]
    with pytest.raises(ValueError, match=r"x_1\.csv: the FRF has no phase"):
        fit_axis(grid, mag, ("x_1.csv",))


def test_inconsistent_repeat_is_named():
    rng = np.random.default_rng(1)
    grid = np.arange(2.0, 240.0, 0.5)
    R = noisy_set(TRUTH, grid, 5, rng, spread=0.002)
    odd = ModalModel(TRUTH.freq_hz * 1.3, TRUTH.damping, TRUTH.b1_rad_s, TRUTH.b0, TRUTH.lag_s)
    R = np.vstack([R, odd.response(grid)])
    fits = fit_axis(grid, R, tuple(f"x_{i}.csv" for i in range(1, 7)))
    assert any(w.startswith("x_6.csv:") and "Hz" in w for w in fits.warnings), fits.warnings
    assert not any(w.startswith("x_1.csv:") for w in fits.warnings)


def test_mode_at_the_top_of_the_band_is_reported():
    grid = np.arange(2.0, 128.0, 0.5)  # the 131 Hz mode lies above the band's end
    rng = np.random.default_rng(2)
    fits = fit_axis(grid, noisy_set(TRUTH, grid, 3, rng), ("y_1.csv", "y_2.csv", "y_3.csv"),
                    nyquist_hz=250.0)
    assert any("Hz" in w and ("top of" in w) for w in fits.warnings), fits.warnings


def test_a_clean_set_has_no_warnings():
    rng = np.random.default_rng(4)
    grid = np.arange(2.0, 240.0, 0.5)
    fits = fit_axis(grid, noisy_set(TRUTH, grid, 6, rng), nyquist_hz=250.0)
    assert fits.warnings == ()


@pytest.mark.parametrize("n", [1, 2, 3])
def test_fewer_than_three_measurements_are_said(n):
    """One FRF gives no spread, two one direction of it: the set's warning says the twin takes
    a typical machine's, naming the first file; three or more of a clean set say nothing."""
    rng = np.random.default_rng(4)
    grid = np.arange(2.0, 240.0, 0.5)
    names = tuple(f"x_{i}.csv" for i in range(1, n + 1))
    fits = fit_axis(grid, noisy_set(TRUTH, grid, n, rng), names, nyquist_hz=250.0)
    few = [w for w in fits.warnings if "typical machine's spread" in w]
    if n >= 3:
        assert fits.warnings == ()
    else:
        assert len(few) == 1 and few[0].startswith(f"x_1.csv: {n} measurement"), fits.warnings
        assert "3 or more" in few[0] and "\n" not in few[0]


@pytest.mark.parametrize("noise", [0.005, 0.01, 0.03])
@pytest.mark.parametrize("step", [0.5, 2.0])
def test_bin_noise_reads_the_noise_level_without_a_model(noise, step):
    """Against the noise put in: within 15 %, on a fine and a coarse grid (the 2 Hz grid is
    coarser than the 52 Hz mode's half-power band of 6 Hz only a little; the median ignores the
    few bins where the response bends faster than the grid)."""
    rng = np.random.default_rng(5)
    grid = np.arange(2.0, 240.0, step)
    R = noisy_set(TRUTH, grid, 4, rng, noise=noise)
    got = np.median([bin_noise(grid, row) for row in R])
    assert abs(got / noise - 1) < 0.15, (got, noise)


def _shaped(grid, centred: bool):
    """TRUTH measured through a ZV input shaper at its first mode (two pulses half a damped
    period apart, amplitudes 1/(1+K), K/(1+K)); ``centred`` shifts them so Σ a·t = 0 as
    Klipper does (the measured motion then leads the command)."""
    z, fn = 0.1, TRUTH.freq_hz[0]
    K = np.exp(-z * np.pi / np.sqrt(1 - z * z))
    a = np.array([1.0, K]) / (1 + K)
    t = np.array([0.0, 0.5 / (fn * np.sqrt(1 - z * z))])
    if centred:
        t = t - np.sum(a * t)
    return np.sum(a[None, :] * np.exp(-2j * np.pi * grid[:, None] * t[None, :]), axis=1)


@pytest.mark.parametrize("centred", [False, True])
def test_a_set_measured_through_an_input_shaper_is_named(centred):
    """An FRF set of shaper × machine is no modal response (the shaper's delayed pulses are not
    poles): the fit misses every member alike, and that is said once, with the files and a
    frequency; without the shaper the same set has no warning (test_a_clean_set...)."""
    rng = np.random.default_rng(4)
    grid = np.arange(2.0, 240.0, 0.5)
    R = noisy_set(TRUTH, grid, 4, rng) * _shaped(grid, centred)[None, :]
    fits = fit_axis(grid, R, tuple(f"x_{i}.csv" for i in range(1, 5)), nyquist_hz=250.0)
    alike = [w for w in fits.warnings if "alike" in w]
    assert len(alike) == 1, fits.warnings
    assert alike[0].startswith("x_1.csv … x_4.csv:") and "Hz" in alike[0], alike
    assert "input shaper" in alike[0]


def test_benchA_sets_are_not_flagged_as_missed_alike():
    """benchA's FRFs (another project's machine, 1 % noise) fit within their own noise."""
    import pathlib
    data = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "independent" / "frf"
    for axis in "xy":
        files = sorted(data.glob(f"{axis}_*.csv"))
        A = [np.loadtxt(p, delimiter=",", skiprows=1) for p in files]
        R = np.array([a[:, 1] + 1j * a[:, 2] for a in A])
        fits = fit_axis(A[0][:, 0], R, tuple(p.name for p in files), nyquist_hz=250.0)
        assert not any("alike" in w for w in fits.warnings), fits.warnings


def _servo_like(f_res: float, f_pair: float, zeta_pair: float):
    """A loop mode at f_res (ζ 0.43) and a pair of real poles (ζ > 1), sorted by frequency as
    a fit returns them: which comes first depends on where the member put the pair."""
    modes = [(f_res, 0.43, 20.0, 0.8), (f_pair, zeta_pair, 5.0, 0.3)]
    modes.sort(key=lambda m: m[0])
    f, z, b1, b0 = (np.array(v) for v in zip(*modes))
    return ModalFit(ModalModel(f, z, b1, b0), 0.01, 0.0)


def test_the_mean_model_matches_modes_across_members_sorted_differently():
    """Members of a servo (tests/foreign seed 31) put a pair of real poles below or above the
    loop's 19 Hz mode: index by index, the mean mixed the two into a 25.4 Hz, ζ 1.37 "mode"
    with no resonance. Matched, the mean keeps the loop mode (19.1 Hz, ζ 0.43), and each
    member's own index of it is known — a resonance shift written by diagnose moves that
    mode in every member, not the pair in one of them."""
    fits = AxisModal(fits=(_servo_like(18.9, 2.0, 1.8), _servo_like(19.3, 44.0, 4.2),
                           _servo_like(19.1, 5.9, 0.95)), labels=("a", "b", "c"))
    assert [list(ft.model.freq_hz) for ft in fits.fits][1] == [19.3, 44.0]   # the loop mode first
    mm = fits.mean_model()
    dom = mm.dominant
    assert mm.freq_hz[dom] == pytest.approx((18.9 + 19.3 + 19.1) / 3)
    assert mm.damping[dom] == pytest.approx(0.43)
    assert fits.member_modes(dom) == (1, 0, 1)
    shift = {"frequency_hz": 0.9 * mm.freq_hz[dom], "form": "mass"}
    moved = apply_effects(fits, [{"kind": "resonance_shift", "params": shift}])
    for before, after, k in zip(fits.fits, moved.fits, (1, 0, 1)):
        assert after.model.freq_hz[k] == pytest.approx(0.9 * before.model.freq_hz[k])
        other = 1 - k
        assert after.model.freq_hz[other] == before.model.freq_hz[other]


def test_the_mean_model_of_members_in_one_order_is_the_parameter_mean():
    fits = AxisModal(fits=(_servo_like(18.9, 40.0, 1.8), _servo_like(19.3, 44.0, 4.2)),
                     labels=("a", "b"))
    mm = fits.mean_model()
    np.testing.assert_array_equal(mm.freq_hz, [(18.9 + 19.3) / 2, 42.0])
    np.testing.assert_array_equal(mm.damping, [0.43, (1.8 + 4.2) / 2])


def test_the_mode_that_carries_the_axis_is_matched_not_the_nearest_small_term():
    """A corexy's members (tests/foreign seed 45): beside the 56 Hz belt mode (b0 ≈ 1) one
    fits a small term above it, another one below it. In frequency and damping alone the
    lower small term (50.8 Hz, ζ 0.04) lies nearer the first member's belt mode than the belt
    mode does; its static share says which is which."""
    a = ModalModel(np.array([56.28, 60.68]), np.array([0.103, 0.128]), np.array([0.0, 0.0]),
                   np.array([0.981, 0.012]))
    b = ModalModel(np.array([50.83, 56.36]), np.array([0.042, 0.102]), np.array([0.0, 0.0]),
                   np.array([0.022, 0.969]))
    fits = AxisModal(fits=(ModalFit(a, 0.01, 0.0), ModalFit(b, 0.01, 0.0)), labels=("a", "b"))
    mm = fits.mean_model()
    belt = int(np.argmax(mm.b0))
    assert fits.member_modes(belt) == (0, 1)
    assert mm.freq_hz[belt] == pytest.approx((56.28 + 56.36) / 2)


def test_fit_covariance_matches_the_scatter_of_refits():
    """Monte Carlo: one FRF of TRUTH (no spread between members) with 1 % noise, fitted 60
    times from TRUTH; the scatter of the fitted lag (−H'(0)), first mode and its damping
    against fit_covariance's linear prediction from one of them, and the impulse response's
    (noise_factor) against the scatter of the refits' responses."""
    from gcode_feedopt.twin.modal import _pack, fit_covariance, noise_factor

    freq = np.arange(2.0, 240.0, 1.0)
    rng = np.random.default_rng(3)
    fits = [fit_modal(freq, noisy_set(TRUTH, freq, 1, rng, spread=0.0)[0], init=TRUTH).model
            for _ in range(60)]
    p = np.array([_pack(m, False) for m in fits])
    lag = np.array([m.lag_s_total for m in fits])
    h = np.array([m.impulse(TS, 300) for m in fits])
    row = noisy_set(TRUTH, freq, 1, rng, spread=0.0)[0]
    one = fit_modal(freq, row, init=TRUTH).model
    cov = fit_covariance(freq, row, one)
    sd = np.sqrt(np.diag(cov))
    # log f1, log ζ1 (packed order: log f, log ζ, c, b0, log τ)
    for j in (0, 2):
        assert 0.7 < sd[j] / p[:, j].std(ddof=1) < 1.4, (j, sd[j], p[:, j].std(ddof=1))
    F = noise_factor(one, cov, TS, 300)
    k = np.arange(300) * TS
    assert 0.7 < np.linalg.norm(k @ F) / lag.std(ddof=1) < 1.4, (np.linalg.norm(k @ F), lag.std())
    sd_h = np.sqrt(np.einsum("ij,ij->i", F, F))
    mc_h = h.std(axis=0, ddof=1)
    big = mc_h > 0.3 * mc_h.max()
    ratio = sd_h[big] / mc_h[big]
    assert 0.7 < np.median(ratio) < 1.4, np.median(ratio)


def test_members_that_kept_the_sets_value_still_carry_the_datas_uncertainty():
    """The mean of N fits carries (1/N²)·Σ G_i C_i G_iᵀ beside the members' spread
    (ensemble_impulse with covs): with identical members (no spread at all) the response's
    covariance is the fits' own over N, less at most 0.1 % of its trace (the directions
    dropped to save columns, frf.compress_factor), and never more in any direction."""
    from gcode_feedopt.twin.modal import fit_covariance, noise_factor

    freq = np.arange(2.0, 240.0, 1.0)
    row = noisy_set(TRUTH, freq, 1, np.random.default_rng(4), spread=0.0)[0]
    one = fit_modal(freq, row, init=TRUTH).model
    cov = fit_covariance(freq, row, one)
    mean, L = ensemble_impulse([one] * 4, TS, 200, covs=[cov] * 4)
    F = noise_factor(one, cov, TS, 200)
    want = F @ F.T / 4
    lost = want - L @ L.T
    assert 0.0 <= np.trace(lost) <= 1e-3 * np.trace(want)
    assert np.linalg.eigvalsh(lost).min() > -1e-12 * np.trace(want)
    assert L.shape[1] - 3 < F.shape[1]  # three (zero) columns of the members, fewer of the fits
    mean0, L0 = ensemble_impulse([one] * 4, TS, 200)
    np.testing.assert_array_equal(mean, mean0)
    assert not np.any(L0)


@pytest.mark.parametrize("n", [1, 2])
def test_one_or_two_measurements_carry_a_typical_spread_that_covers(n):
    """A population whose modes scatter as the prior says (frequencies PRIOR_SPREAD_FREQ,
    damping PRIOR_SPREAD_DAMPING, log-normal; b1/(2πf) ∝ ζ), measured n times: the ensemble's 95 % interval
    of the response to a smooth move holds further machines of it 90–97 %, pooled over
    machines and samples (Monte Carlo, 300 machines; 91.6 % and 92.4 % here). Under 95 %: the
    spread is linearised about the members measured, whose Jacobian is one draw's, and a width
    that varies from machine to machine covers less than its mean width would (Jensen); the
    variance itself matches the Monte Carlo's within a few % along the move."""
    from gcode_feedopt.twin.modal import PRIOR_SPREAD_DAMPING, PRIOR_SPREAD_FREQ

    rng = np.random.default_rng(8)
    k = np.arange(600) * TS
    u = 20.0 * (1 - np.cos(np.pi * np.clip(k / 0.3, 0, 1))) / 2   # 20 mm in 0.3 s, then rest

    def draw():
        rf = np.exp(PRIOR_SPREAD_FREQ * rng.standard_normal(2))
        rz = np.exp(PRIOR_SPREAD_DAMPING * rng.standard_normal(2))
        return ModalModel(TRUTH.freq_hz * rf, TRUTH.damping * rz, TRUTH.b1_rad_s * rf * rz,
                          TRUTH.b0, TRUTH.lag_s)

    inside = []
    for _ in range(300):
        mean, L = ensemble_impulse([draw() for _ in range(n)], TS, 300)
        y = np.convolve(u, mean)[:u.size]
        sd = np.sqrt(np.sum(np.array([np.convolve(u, c)[:u.size] for c in L.T]) ** 2, axis=0))
        h = draw().impulse(TS, 300)
        e = np.convolve(u, h)[:u.size] - y
        moving = sd > 0.05 * sd.max()
        inside.append(np.abs(e[moving]) <= 1.959964 * sd[moving])
    cov = float(np.mean(np.concatenate(inside)))
    assert 0.90 <= cov <= 0.97, cov


#: a PID servo's fit: integral action as a real pair below the loop mode, a screw mode, a lag
SERVO = ModalModel(freq_hz=np.array([12.0, 40.0, 150.0]), damping=np.array([1.8, 0.6, 0.05]),
                   b1_rad_s=np.array([30.0, 50.0, 0.0]), b0=np.array([0.3, 0.5, 0.2]),
                   lag_s=0.002)


@pytest.mark.parametrize("ratio, corner", [(0.3, 0.0), (0.3, 200.0), (-0.2, 50.0), (1.0, 1e3)])
def test_a_loaded_loop_is_the_closed_form(ratio, corner):
    """ModalModel.loaded: 1/H' = 1/H + ratio·(1/H − 1)·s/(s + a), a ModalModel (the closed
    loop's partial fractions, odd real pole included) with the DC gain and the lag kept."""
    f = np.linspace(0.5, 300.0, 700)
    s = 2j * np.pi * f
    h = SERVO.response(f)
    fv = s / (s + corner) if corner > 0 else 1.0
    lm = SERVO.loaded(ratio, corner)
    np.testing.assert_allclose(lm.response(f), h / (1 + ratio * (1 - h) * fv), atol=1e-12)
    assert lm.dc_gain == pytest.approx(1.0, abs=1e-12)
    k = np.arange(3000)
    hi = lm.impulse(TS, 3000)
    assert hi.sum() == pytest.approx(1.0, abs=1e-12)
    # −H'(0): unchanged where the feedback has a corner (F(0) = 0), ×(1 + ratio) without
    lag = SERVO.lag_s_total * (1.0 + ratio if corner == 0 else 1.0)
    assert k @ hi * TS == pytest.approx(lag, rel=1e-9)


def test_a_heavier_mass_on_a_belt_is_its_mode_moved():
    """One mass on a belt (its damping in the belt, b1 = 2ζω·b0): 1/H − 1 = m s²/(c s + k), so
    the loaded form with a = 0 is exactly the mode moved as a mass change moves it."""
    belt = ModalModel(np.array([40.0]), np.array([0.05]), np.array([0.1 * 2 * np.pi * 40]),
                      np.array([1.0]))
    lm, mv = belt.loaded(0.3, 0.0), belt.mode_shifted(0, 1 / np.sqrt(1.3))
    np.testing.assert_allclose(lm.freq_hz, mv.freq_hz, rtol=1e-12)
    np.testing.assert_allclose(lm.damping, mv.damping, rtol=1e-9)
    np.testing.assert_allclose(lm.b1_rad_s, mv.b1_rad_s, rtol=1e-9)


def test_a_loop_loaded_past_its_stability_is_none():
    assert SERVO.loaded(-0.99, 0.0) is None or np.all(np.isfinite(SERVO.loaded(-0.99, 0.0).freq_hz))
    light = ModalModel(np.array([30.0]), np.array([0.4]), np.array([0.0]), np.array([1.0]))
    # 1/H' = 1/H − 1.2·(1/H − 1) = 1 − 0.2·(s² + 2ζωs)/ω²: a negative mass, an unstable loop
    assert light.loaded(-1.2, 0.0) is None


def test_the_fits_noise_is_carried_through_the_loading():
    """loaded_cov (J·cov·Jᵀ by forward differences) against Monte Carlo: parameter draws
    about SERVO, each loaded; the loaded impulse response's spread, tap by tap, as the twin
    carries it (``noise_factor`` of the loaded model with the carried covariance)."""
    from gcode_feedopt.twin.modal import _pack, _with_params, loaded_cov, noise_factor

    rng = np.random.default_rng(3)
    p0 = _pack(SERVO, False)
    sd = np.full(p0.size, 0.003)
    got = loaded_cov(SERVO, np.diag(sd ** 2), 0.3, 200.0)
    lm = SERVO.loaded(0.3, 200.0)
    assert got.shape == (p0.size + 4, p0.size + 4)      # a pair more: the feedback's state
    F = noise_factor(lm, got, TS, 400)
    hs = np.array([_with_params(SERVO, p0 + sd * rng.standard_normal(p0.size))
                   .loaded(0.3, 200.0).impulse(TS, 400) for _ in range(3000)])
    mc = hs.std(axis=0)
    np.testing.assert_allclose(np.sqrt(np.sum(F * F, axis=1)), mc, rtol=0.05,
                               atol=0.03 * mc.max())


def test_a_load_written_on_the_bins_is_the_closed_form():
    """The raw-bin route applies a ``load`` resonance shift bin by bin as the modal route."""
    import dataclasses

    from gcode_feedopt.profile import load_profile
    from gcode_feedopt.twin.physics import _bins

    prof = load_profile("ender3pro")
    load = {"frequency_hz": 30.0, "load_ratio": 0.3, "corner_hz": 20.0, "form": "load"}
    ax = dataclasses.replace(prof.axes["x"], effects=({"kind": "resonance_shift",
                                                       "params": load},))
    moved = dataclasses.replace(prof, axes={**prof.axes, "x": ax})
    freq, h = _bins(prof, "x")
    freq2, h2 = _bins(moved, "x")
    s = 2j * np.pi * freq
    np.testing.assert_array_equal(freq, freq2)
    np.testing.assert_allclose(h2, h / (1 + 0.3 * (1 - h) * s / (s + 2 * np.pi * 20.0)),
                               atol=1e-12)


@pytest.mark.parametrize("corner", [50.0, 300.0])
def test_the_force_on_a_loaded_loop_is_the_closed_form(corner):
    """ModalModel.load_force: (1 − H)/(s (s + a)), the construction's integrator dropped."""
    f = np.linspace(0.5, 300.0, 700)
    s = 2j * np.pi * f
    h = SERVO.response(f)
    np.testing.assert_allclose(SERVO.load_force(corner).response(f),
                               (1 - h) / (s * (s + corner)), rtol=1e-9, atol=1e-15)
    assert SERVO.load_force(0.0) is None


def test_a_pid_servos_table_force_is_washed_out_through_its_loop():
    """A PID loop with its derivative on the measurement holding a mass m:
    H = (K_p s + K_i)/(m s³ + K_d s² + K_p s + K_i). The force on the mass reaches it as
    s/(m s³ + K_d s² + K_p s + K_i) = load_force(K_d/m)/m: zero at DC (the integrator takes a
    steady force out), built from H and the corner alone."""
    m, kd, kp, ki = 3.0, 900.0, 1.5e5, 2.0e6
    den = np.array([m, kd, kp, ki])
    p = np.roots(den)
    # H as a ModalModel: its three poles (a pair and a real one) by partial fractions
    from gcode_feedopt.twin.modal import _from_state_space
    from scipy.signal import tf2ss
    A, B, C, D = tf2ss([kp, ki], den)
    H = _from_state_space(A, B[:, 0], C[0], float(D[0, 0]), 0.0)
    f = np.linspace(0.5, 200.0, 400)
    s = 2j * np.pi * f
    np.testing.assert_allclose(H.response(f), np.polyval([kp, ki], s) / np.polyval(den, s),
                               rtol=1e-9)
    assert np.all(p.real < 0)
    force = H.load_force(kd / m)
    np.testing.assert_allclose(force.response(f), m * s / np.polyval(den, s), rtol=1e-7)
    assert force.dc_gain == pytest.approx(0.0, abs=1e-12)


def test_the_pair_at_the_peak_is_a_mode_not_a_fits_needle():
    """pair_at_peak_hz: the pair nearest the peak of |H|, but not a near pole–zero
    cancellation a fit leaves (share of the DC gain < PAIR_SHARE), whose needle peak may be
    the highest (tests/foreign 402 y: 10.6 Hz, ζ 0.0035, share 0.008, beside its loop at
    24.8 Hz, ζ 0.83)."""
    loop = ModalModel(np.array([24.8, 368.0]), np.array([0.83, 0.54]),
                      np.array([1098.0, -1016.0]), np.array([1.25, -0.19]), lag_s=0.0317)
    needle = ModalModel(np.array([10.56, 24.8, 368.0]), np.array([0.0035, 0.83, 0.54]),
                        np.array([-0.088, 1098.0, -1016.0]), np.array([0.0068, 1.25, -0.19]),
                        lag_s=0.0317)
    f = np.arange(1.0, 250.0, 0.05)
    assert f[np.argmax(np.abs(needle.response(f)))] == pytest.approx(10.55, abs=0.1)
    assert needle.pair_at_peak_hz(1.0, 250.0) == pytest.approx(24.8)
    assert loop.pair_at_peak_hz(1.0, 250.0) == pytest.approx(24.8)
