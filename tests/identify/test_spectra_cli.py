"""identify on Klipper spectra and FRF CSVs: real Ender 3 files and a synthetic CSV."""

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.identify.modal import modal_response
from gcode_feedopt.identify.readers import detect_kind, read_spectra
from gcode_feedopt.identify.spectra import fit_spectrum
from gcode_feedopt.profile import load_profile
from gcode_feedopt.errors import ProfileError


@pytest.mark.parametrize("name,axis,lo,hi", [
    # published: Y near 36-42 Hz (39 Hz after belt tightening), X 45/59 Hz on the later test
    ("ender3_resonances_y_20210630_230110.csv", "y", 36.0, 42.0),
    ("ender3_resonances_x_20210821_152037.csv", "x", 40.0, 59.0),
])
def test_real_ender3_spectra_first_mode_in_published_band(data_dir, name, axis, lo, hi):
    freq, psd = read_spectra(data_dir / "measured" / name, axis)
    fit = fit_spectrum(freq, psd, n_modes=2)
    assert lo <= fit.freq_hz[0] <= hi
    assert 0.02 < fit.damping[0] < 0.3


def test_unknown_kind_is_one_line_error(tmp_path):
    p = tmp_path / "junk.csv"
    p.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(ProfileError, match="unknown file kind"):
        detect_kind(p)


def test_cli_from_frf_csv_recovers_modes(tmp_path):
    rng = np.random.default_rng(3)
    f = np.arange(0.0, 200.0, 0.5)
    files = []
    for k in range(3):
        h = modal_response(f, [47.0], [0.09], [1.0])
        h = h + 0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
        p = tmp_path / f"x{k}.csv"
        np.savetxt(p, np.c_[f, h.real, h.imag], delimiter=",", header="freq_hz,real,imag",
                   comments="")
        files += ["--x", str(p)]
    out = tmp_path / "prof.yaml"
    png = tmp_path / "fit.png"
    res = CliRunner().invoke(cli, ["identify", *files, "--modes", "1", "-o", str(out),
                                   "--plot", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    prof = load_profile(out)
    m = prof.axes["x"].modes[0]
    assert m.freq_hz == pytest.approx(47.0, rel=0.02)
    assert m.damping == pytest.approx(0.09, rel=0.2)
    assert prof.axes["x"].frf.n_measurements == 3


def test_cli_from_uff58_recovers_modes(tmp_path):
    import pyuff

    rng = np.random.default_rng(4)
    f = np.arange(0.0, 200.0, 0.5)
    sets = []
    for _ in range(2):
        h = modal_response(f, [36.0, 71.0], [0.1, 0.05], [0.8, 0.2])
        h = h + 0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
        sets.append(pyuff.prepare_58(func_type=4, rsp_node=1, rsp_dir=1, ref_node=1, ref_dir=1,
                                     data=h, x=f, id1="frf", abscissa_spacing=1,
                                     abscissa_spec_data_type=18, ordinate_spec_data_type=12,
                                     orddenom_spec_data_type=13))
    p = tmp_path / "y.uff"
    pyuff.UFF(str(p)).write_sets(sets, mode="overwrite")
    assert detect_kind(p) == "uff"
    out = tmp_path / "prof.yaml"
    res = CliRunner().invoke(cli, ["identify", "--y", str(p), "--modes", "2", "-o", str(out)])
    assert res.exit_code == 0, res.output
    prof = load_profile(out)
    fn = [m.freq_hz for m in prof.axes["y"].modes]
    zeta = [m.damping for m in prof.axes["y"].modes]
    np.testing.assert_allclose(fn, [36.0, 71.0], rtol=0.02)
    np.testing.assert_allclose(zeta, [0.1, 0.05], rtol=0.2)
    assert prof.axes["y"].frf.n_measurements == 2
