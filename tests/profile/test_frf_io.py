"""FRF CSV files: round trip and one-line errors that name the file."""

import numpy as np
import pytest

from gcode_feedopt.errors import ProfileError
from gcode_feedopt.profile.frf_io import frf_set_from_files, read_frf_csv, write_frf_csv


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


def test_grids_must_agree(tmp_path):
    f = np.arange(0.0, 10.0, 0.5)
    write_frf_csv(tmp_path / "a.csv", f, np.ones(f.size, complex))
    write_frf_csv(tmp_path / "b.csv", f * 1.01, np.ones(f.size, complex))
    with pytest.raises(ProfileError, match="b.csv: frequency grid differs from a.csv"):
        frf_set_from_files([tmp_path / "a.csv", tmp_path / "b.csv"])
    s = frf_set_from_files([tmp_path / "a.csv", tmp_path / "a.csv"])
    assert s.response.shape == (2, f.size) and s.labels == ("a.csv", "a.csv")
