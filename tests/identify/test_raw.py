"""Raw Klipper recordings: synthetic resonance tests of a known modal plant (both generators,
noise, clock offset and rate error) and the real Voron files through the CLI into optimize."""

import pathlib

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import signal

from gcode_feedopt.cli import cli
from gcode_feedopt.errors import ProfileError
from gcode_feedopt.identify.excitation import CURRENT, LEGACY, pieces, sampled_accel
from gcode_feedopt.identify.raw import analyse_raw, check_clipping
from gcode_feedopt.profile import load_profile

REPO = pathlib.Path(__file__).resolve().parents[2]
FS_HI = 4000.0
PLANTS = {
    "legacy": ([42.0, 67.0], [0.08, 0.05], [0.6, 0.4]),
    "current": ([38.0, 61.0], [0.10, 0.06], [0.7, 0.3]),
}


def synthetic_recording(ex, fn, zeta, gain, *, pre_s=1.3, rate_error=3e-4, fs_sensor=400.0,
                        noise=150.0, seed=0, direction=(0.8, -0.6, 0.0), clip=None):
    """(t_s, acc (K,3)) as Klipper would write it: sensor samples at its own clock, its time
    stamps ``1000 + (1 + rate_error) * t_true`` (t_true = 0 when the test starts)."""
    rng = np.random.default_rng(seed)
    t_cmd, a_cmd = sampled_accel(ex, FS_HI, oversample=4, pad_s=pre_s + 1.0)
    y = np.zeros_like(a_cmd)
    for f0, z, g in zip(fn, zeta, gain):
        wn = 2 * np.pi * f0
        b, a = signal.bilinear([g * wn**2], [1.0, 2 * z * wn, wn**2], FS_HI)
        y += signal.lfilter(b, a, a_cmd)
    sos = signal.butter(8, 0.45 * fs_sensor, fs=FS_HI, output="sos")  # sensor anti-alias
    y = signal.sosfiltfilt(sos, y)
    t_true = -pre_s + np.arange(int((t_cmd[-1] - 1.0 + pre_s) * fs_sensor)) / fs_sensor
    a = np.interp(t_true, t_cmd, y)
    acc = np.outer(a, direction) + noise * rng.standard_normal((len(a), 3))
    acc[:, 2] -= 9806.65
    if clip is not None:
        acc = np.clip(acc, -clip, clip)
    acc = np.round(acc / 19.14) * 19.14  # ADXL345-like quantisation
    return 1000.0 + (1 + rate_error) * t_true, acc


def test_generators_follow_klipper_move_sequence():
    for ex, vmax in ((LEGACY, 75.0 / 4), (CURRENT, None)):
        edges, acc = pieces(ex)
        v = np.r_[0.0, np.cumsum(acc * np.diff(edges))]
        # every frequency step lasts 1/(4 f) per piece and |a| = A f; f rises ~ hz_per_sec
        assert edges[-1] == pytest.approx(128.36 if ex is LEGACY else 130.0, abs=0.05)
        if vmax is not None:   # legacy: peak speed A/4, rest at both ends
            assert np.max(np.abs(v)) == pytest.approx(vmax, rel=1e-9)
            assert abs(v[-1]) < 1e-6
    # cosine phase: the first lobe of both is positive
    assert pieces(LEGACY)[1][0] > 0 and pieces(CURRENT)[1][0] > 0


@pytest.mark.parametrize("gen", ["legacy", "current"])
def test_raw_recording_recovers_modes_and_clock(gen):
    ex = {"legacy": LEGACY, "current": CURRENT}[gen]
    fn, zeta, gain = PLANTS[gen]
    t, acc = synthetic_recording(ex, fn, zeta, gain, rate_error=3e-4 if gen == "legacy" else -5e-4)
    res = analyse_raw(t, acc, n_modes=2)           # generator auto-detected
    assert res.excitation.generator == gen
    assert res.clock.rate_error == pytest.approx(3e-4 if gen == "legacy" else -5e-4, abs=3e-5)
    assert res.clock.offset_s == pytest.approx(1.3, abs=0.01)
    np.testing.assert_allclose(res.fit.freq_hz, fn, rtol=0.02)
    np.testing.assert_allclose(res.fit.damping, zeta, rtol=0.20)
    for sf in res.set_fits:                       # each segment's FRF alone, too
        np.testing.assert_allclose(sf.freq_hz, fn, rtol=0.02)
        np.testing.assert_allclose(sf.damping, zeta, rtol=0.20)
    assert abs(res.direction @ np.array([0.8, -0.6, 0.0])) > 0.99
    assert np.median(res.h1.coherence[res.band]) > 0.8
    assert res.fit.scale == pytest.approx(1.0, abs=0.1)
    assert res.warnings == []


def test_warnings_short_clipped_noisy_wrong_amplitude():
    fn, zeta, gain = PLANTS["legacy"]
    t, acc = synthetic_recording(LEGACY, fn, zeta, gain, noise=20000.0, clip=6000.0)
    keep = t < t[0] + 70.0
    res = analyse_raw(t[keep], acc[keep], excitation=LEGACY.with_overrides(accel_per_hz=150.0))
    text = "\n".join(res.warnings)
    assert "clipped" in text
    assert "too short" in text
    assert "low coherence" in text
    assert "--accel-per-hz" in text
    assert all("\n" not in w for w in res.warnings)


def test_clipping_check_quiet_on_clean_data():
    rng = np.random.default_rng(1)
    assert check_clipping(np.round(rng.standard_normal((5000, 3)) * 3000 / 19.14) * 19.14) == []


def test_raw_too_short_is_one_line_error():
    t = np.arange(50) * 0.0025
    with pytest.raises(ProfileError, match="record the whole"):
        analyse_raw(t, np.zeros((50, 3)))


def _write_raw(path, t, acc):
    np.savetxt(path, np.c_[t, acc], delimiter=",", fmt="%.6f",
               header="time,accel_x,accel_y,accel_z", comments="#")


def test_cli_raw_current_with_overrides(tmp_path):
    ex = CURRENT.with_overrides(freq_start_hz=10.0, freq_end_hz=110.0, hz_per_sec=2.0)
    t, acc = synthetic_recording(ex, [48.0], [0.07], [1.0], rate_error=2e-4)
    p = tmp_path / "raw_data_x.csv"
    _write_raw(p, t, acc)
    out = tmp_path / "prof.yaml"
    res = CliRunner().invoke(cli, ["identify", "--x", str(p), "--modes", "1", "-o", str(out),
                                   "--excitation", "current", "--freq-start", "10",
                                   "--freq-end", "110", "--hz-per-sec", "2"])
    assert res.exit_code == 0, res.output
    prof = load_profile(out)
    m = prof.axes["x"].modes[0]
    assert m.freq_hz == pytest.approx(48.0, rel=0.02)
    assert m.damping == pytest.approx(0.07, rel=0.2)
    raw = prof.axes["x"].provenance["raw"][0]
    assert raw["excitation"]["generator"] == "current"
    assert raw["clock_rate_error"] == pytest.approx(2e-4, abs=3e-5)
    assert prof.axes["x"].frf.n_measurements == 4


def test_cli_overrides_need_a_generator(tmp_path):
    p = tmp_path / "r.csv"
    _write_raw(p, np.arange(10) * 0.0025, np.zeros((10, 3)))
    res = CliRunner().invoke(cli, ["identify", "--x", str(p), "-o", str(tmp_path / "o.yaml"),
                                   "--freq-end", "100"])
    assert res.exit_code != 0
    assert "--excitation legacy or current" in res.output


VORON = "voron2.4_klipper-raw-accel_belt-test_20231128_221505_{}.csv"


def test_real_voron_recordings_drive_optimize(data_dir, tmp_path):
    a, b = (data_dir / "measured" / VORON.format(s) for s in "AB")
    out = tmp_path / "built.yaml"
    res = CliRunner().invoke(cli, ["identify", "--x", str(a), "--y", str(b), "--modes", "3",
                                   "-o", str(out)])
    assert res.exit_code == 0, res.output
    prof = load_profile(out)
    for axis in "xy":
        prov = prof.axes[axis].provenance["raw"][0]
        assert prov["excitation"]["generator"] == "legacy"       # recorded Nov 2023
        assert prov["median_coherence"] > 0.6
        assert 0.85 < prov["level"] < 1.1                         # accel_per_hz 75 fits
        fn = [m.freq_hz for m in prof.axes[axis].modes]
        assert 44.0 < fn[0] < 48.0 and 64.0 < fn[1] < 68.0
    # the two belts move along orthogonal diagonals
    da = np.array(prof.axes["x"].provenance["raw"][0]["direction_sensor_xyz"])
    db = np.array(prof.axes["y"].provenance["raw"][0]["direction_sensor_xyz"])
    assert abs(da @ db) < 0.2
    g = tmp_path / "x.gcode"
    res = CliRunner().invoke(cli, ["optimize", str(REPO / "sample_gcode" / "butterfly.gcode"),
                                   "--machine", str(out), "-o", str(g), "--method", "kinematic"])
    assert res.exit_code == 0, res.output
    assert g.stat().st_size > 0


def test_real_ender3_spectra_drive_optimize(data_dir, tmp_path):
    m = data_dir / "measured"
    out = tmp_path / "built.yaml"
    res = CliRunner().invoke(cli, ["identify", "--x", str(m / "ender3_resonances_x_20210821_152037.csv"),
                                   "--y", str(m / "ender3_resonances_y_20210630_230110.csv"),
                                   "-o", str(out)])
    assert res.exit_code == 0, res.output
    prof = load_profile(out)
    assert 36.0 <= prof.axes["y"].modes[0].freq_hz <= 39.0    # published Y 36-39 Hz
    assert 40.0 <= prof.axes["x"].modes[0].freq_hz <= 59.0    # published X 40-59 Hz
    g = tmp_path / "x.gcode"
    res = CliRunner().invoke(cli, ["optimize", str(REPO / "sample_gcode" / "butterfly.gcode"),
                                   "--machine", str(out), "-o", str(g), "--method", "kinematic"])
    assert res.exit_code == 0, res.output
    assert g.stat().st_size > 0
