"""FRF CSV files: round trip and one-line errors that name the file."""

import pathlib
import warnings

import numpy as np
import pytest

from gcode_feedopt.errors import ModelWarning, ProfileError
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.build import build_from_frfs
from gcode_feedopt.profile.frf_io import frf_set_from_files, read_frf_csv, write_frf_csv
from gcode_feedopt.twin.model import axis_twin
from gcode_feedopt.twin.physics import axis_modal


def test_write_read_round_trip_to_1e12(tmp_path):
    rng = np.random.default_rng(5)
    f = np.arange(0.0, 250.5, 0.5)
    h = rng.normal(size=f.size) + 1j * rng.normal(size=f.size)
    write_frf_csv(tmp_path / "a.csv", f, h)
    f2, h2 = read_frf_csv(tmp_path / "a.csv")
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_allclose(h2, h, rtol=1e-11, atol=0)


@pytest.mark.parametrize("text, match", [
    ("", "FRF file is empty"),
    ("f,re,im\n0,1,0\n", "must start with the header 'freq_hz,real,imag'"),
    ("freq_hz,real,imag\n0,1,0\n1,1,0\n1,1,0\n2,1,0\n", "strictly increasing"),
    ("freq_hz,real,imag\n0,1,0\n1,1\n", "three numbers each"),
    ("freq_hz,real,imag\n0,1,0\n1,1,0\n", "at least 4 rows"),
])
def test_bad_files_name_the_file(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(ProfileError, match=match) as exc:
        read_frf_csv(p)
    assert "bad.csv" in str(exc.value) and "\n" not in str(exc.value)


def _mode(f, fn=48.0, zeta=0.03):
    """A position axis with one lightly damped mode: H(0) = 1, a peak of ~1/(2ζ) at fn."""
    s = 2j * np.pi * np.asarray(f, float)
    wn = 2 * np.pi * fn
    return wn ** 2 / (s ** 2 + 2 * zeta * wn * s + wn ** 2)


def test_members_on_different_grids_share_the_common_band(tmp_path):
    """A stepped sine re-planned between runs: 1–200 Hz every 1 Hz, 2.5–240 Hz every 2 Hz,
    0.5–180 Hz every 0.5 Hz. The set is the band all cover (2.5–180 Hz) on the grid with the
    most points there (the 0.5 Hz one); the others interpolated, which keeps the 48 Hz peak
    (ζ 0.03, 1 Hz from 2 Hz samples) to 1 %, where a chord loses 20 % and a spline of H 23 %."""
    grids = {"a.csv": np.arange(1.0, 200.5, 1.0), "b.csv": np.arange(2.5, 240.5, 2.0),
             "c.csv": np.arange(0.5, 180.25, 0.5)}
    for name, f in grids.items():
        write_frf_csv(tmp_path / name, f, _mode(f))
    notes = []
    s = frf_set_from_files([tmp_path / n for n in grids], notes=notes)
    assert s.freq_hz[0] == pytest.approx(2.5) and s.freq_hz[-1] == pytest.approx(180.0)
    np.testing.assert_allclose(np.diff(s.freq_hz), 0.5)
    true = _mode(s.freq_hz)
    np.testing.assert_allclose(s.response[2], true, rtol=1e-10)  # the reference, as read
    for k in (0, 1):
        err = np.abs(s.response[k] - true) / np.abs(true)
        assert err.max() < 0.01, (k, err.max())
    chord = np.interp(s.freq_hz, grids["b.csv"], np.abs(_mode(grids["b.csv"])))
    assert np.max(np.abs(chord - np.abs(true)) / np.abs(true)) > 0.1  # why not a chord
    assert len(notes) == 1 and "c.csv's grid" in notes[0] and "2.5–180 Hz" in notes[0]


def test_an_antiresonance_is_interpolated_as_well_as_a_peak(tmp_path):
    """The member's own samples choose between a spline of H and of 1/H: a notch (H = 1/mode)
    is kept to 1 % as a peak is (the spline of 1/H would be the one to miss it)."""
    fine, coarse = np.arange(1.0, 150.5, 0.5), np.arange(1.0, 151.0, 2.0)
    write_frf_csv(tmp_path / "a.csv", fine, 1.0 / _mode(fine))
    write_frf_csv(tmp_path / "b.csv", coarse, 1.0 / _mode(coarse))
    s = frf_set_from_files([tmp_path / "a.csv", tmp_path / "b.csv"])
    true = 1.0 / _mode(s.freq_hz)
    assert np.max(np.abs(s.response[1] - true) / np.abs(true)) < 0.01


def test_members_that_share_no_band_are_refused_in_one_line(tmp_path):
    write_frf_csv(tmp_path / "low.csv", np.arange(1.0, 50.0), _mode(np.arange(1.0, 50.0)))
    write_frf_csv(tmp_path / "high.csv", np.arange(60.0, 200.0), _mode(np.arange(60.0, 200.0)))
    with pytest.raises(ProfileError, match="share fewer than 4 frequencies") as exc:
        frf_set_from_files([tmp_path / "low.csv", tmp_path / "high.csv"])
    msg = str(exc.value)
    assert "high.csv" in msg and "low.csv" in msg and "\n" not in msg and len(msg) < 300


def test_same_grid_is_kept_as_is(tmp_path):
    f = np.arange(0.0, 10.0, 0.5)
    write_frf_csv(tmp_path / "a.csv", f, np.ones(f.size, complex))
    notes = []
    s = frf_set_from_files([tmp_path / "a.csv", tmp_path / "a.csv"], notes=notes)
    assert s.response.shape == (2, f.size) and s.labels == ("a.csv", "a.csv")
    np.testing.assert_array_equal(s.freq_hz, f)
    assert notes == []


BENCH_A = pathlib.Path(__file__).resolve().parents[3] / "shared" / "data" / "independent" / "frf"


@pytest.mark.skipif(not BENCH_A.is_dir(), reason="needs ../shared/data/independent")
def test_profile_build_on_mixed_grids_matches_the_one_grid_build(tmp_path):
    """benchA's FRFs (0.5 Hz steps from 2 Hz, 1 % noise) with every other member re-measured
    on a 2 Hz grid from 2.5 Hz: `profile build` says what it did and fits the same machine —
    the modes to 0.1 %, the step response to 1e-3, the impulse response's spread to 5 %.
    (A spline of H alone read y's 36 Hz peak as two modes, 35.9 and 36.6 Hz.)"""
    files = {}
    for ax in "xy":
        files[ax] = []
        for k in range(1, 7):
            f, h = read_frf_csv(BENCH_A / f"{ax}_{k}.csv")
            if k % 2 == 0:
                f, h = f[1::4], h[1::4]
            write_frf_csv(tmp_path / f"{ax}_{k}.csv", f, h)
            files[ax].append(tmp_path / f"{ax}_{k}.csv")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mixed, _ = build_from_frfs(load_profile("ender3pro"), files, name="mixed")
    said = [str(w.message) for w in caught if issubclass(w.category, ModelWarning)]
    for ax in "xy":
        assert any(s.startswith(f"axis {ax}: 6 FRFs on different frequency grids") for s in said)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        same, _ = build_from_frfs(load_profile("ender3pro"),
                                  {ax: sorted(BENCH_A.glob(f"{ax}_*.csv")) for ax in "xy"},
                                  name="same")
    for ax in "xy":
        a, b = axis_modal(same, ax, warn=False).mean_model(), axis_modal(mixed, ax, warn=False).mean_model()
        assert a.freq_hz.size == b.freq_hz.size, (ax, a.freq_hz, b.freq_hz)
        np.testing.assert_allclose(b.freq_hz, a.freq_hz, rtol=1e-3)
        np.testing.assert_allclose(b.damping, a.damping, rtol=0.02)
        ta, tb = axis_twin(same, ax), axis_twin(mixed, ax)
        assert np.max(np.abs(np.cumsum(ta.ir.mean) - np.cumsum(tb.ir.mean))) < 1e-3
        assert abs(np.sqrt(tb.ir.var.sum() / ta.ir.var.sum()) - 1) < 0.05


def test_a_mode_that_outlasts_the_twins_memory_is_named_with_the_memory_it_needs(tmp_path):
    """A 20 Hz mode at ζ 0.01 still rings at 28 % of its amplitude after the 500-sample (1 s)
    memory: the impulse response keeps the axis's lag (twin.modal) but not that ringing, so
    the build says which mode, by how much, and what twin.n_taps would hold it to 1 %; with
    that memory the line is gone. A well-damped machine (ζ 0.06) gets no such line."""
    import dataclasses

    from gcode_feedopt.twin.modal import ModalModel

    f = np.arange(1.0, 200.0, 0.5)
    rng = np.random.default_rng(2)

    def build(zeta, n_taps=None):
        files = {}
        for ax, z in (("x", zeta), ("y", 0.06)):
            files[ax] = []
            for k in range(3):
                m = ModalModel(freq_hz=np.array([20.0 * (1 + 0.003 * rng.standard_normal())]),
                               damping=np.array([z]), b1_rad_s=np.zeros(1), b0=np.ones(1))
                write_frf_csv(tmp_path / f"{ax}_{zeta}_{k}.csv", f, m.response(f))
                files[ax].append(tmp_path / f"{ax}_{zeta}_{k}.csv")
        base = load_profile("ender3pro")
        if n_taps:
            base = dataclasses.replace(base, twin=dataclasses.replace(base.twin, n_taps=n_taps))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            prof, _ = build_from_frfs(base, files, name=f"ring{zeta}-{n_taps}")
            for ax in "xy":
                axis_modal(prof, ax)
        return [str(w.message) for w in caught if "still rings" in str(w.message)]

    said = build(0.01)
    import re
    got = re.search(r"axis x: x_0\.01_\d\.csv: a mode at 20\.0 Hz \(ζ 0\.010\) still rings at "
                    r"(\d+) % of its amplitude after the twin's memory of 500 samples \(1 s\)",
                    said[0]) if len(said) == 1 else None
    assert got and 27 <= int(got.group(1)) <= 30, said  # e^(−ζω·1 s) = 28 % at 20.0 Hz
    need = int(said[0].split("set twin.n_taps to at least ")[1].split()[0])
    assert 1800 <= need <= 1900  # ln(100) / (ζω·Ts) = 1832
    assert build(0.01, n_taps=need) == []
    assert build(0.06) == []
