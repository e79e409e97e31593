import json

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.errors import ProfileError
from gcode_feedopt.profile import builtin_names, load_profile, save_profile
from gcode_feedopt.profile.builtin import BUILTINS


def test_builtins_load_and_are_in_published_ranges():
    assert set(builtin_names()) >= {"ender3pro", "nomad3"}
    p = load_profile("ender3pro")
    assert p.axes["x"].frf.n_measurements == 9 and p.axes["y"].frf.n_measurements == 9
    f = p.axes["y"].frf.freq_hz
    peaks = f[np.argmax(np.abs(p.axes["y"].frf.response), axis=1)]
    assert np.all((peaks > 30) & (peaks < 45))  # bed mode 36–42 Hz, softened by amplitude


def test_regeneration_is_identical(tmp_path):
    """voron24's FRFs are estimated from measured data; their last digits follow the CPU's FFT
    and BLAS kernels (3.7e-8 apart on two machines): 1e-6 for it, 1e-10 for the synthetic ones."""
    for name, make in BUILTINS.items():
        path = save_profile(make(), tmp_path / f"{name}.yaml")
        a, b = load_profile(path), load_profile(name)
        rtol = 1e-6 if name == "voron24" else 1e-10
        for ax in "xy":
            np.testing.assert_allclose(a.axes[ax].frf.response, b.axes[ax].frf.response, rtol=rtol)
        assert a.limits == b.limits and a.firmware == b.firmware


def test_unknown_key_did_you_mean(tmp_path):
    src = load_profile("nomad3").source_path
    d = yaml.safe_load(open(src))
    d["limits"]["vmax_mm_sec"] = d["limits"].pop("vmax_mm_s")
    d["axes"] = {"x": {}, "y": {}}
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(ProfileError, match="vmax_mm_s"):
        load_profile(p)


def test_out_of_bounds_and_missing_frf(tmp_path):
    d = yaml.safe_load(open(load_profile("nomad3").source_path))
    d["limits"]["stringency"] = 1.5
    d["axes"] = {"x": {}, "y": {}}
    p = tmp_path / "b.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(ProfileError, match=r"limits.stringency: 1.5 is above the maximum"):
        load_profile(p)
    d["limits"]["stringency"] = 0.95
    d["axes"] = {"x": {"frf": ["nowhere/x.csv"]}, "y": {}}
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(ProfileError, match="x.csv: FRF file not found"):
        load_profile(p)


def test_profile_build_show_check(tmp_path):
    p = load_profile("ender3pro")
    files = []
    for k in range(3):
        f = tmp_path / f"x{k}.csv"
        with open(f, "w") as fh:
            fh.write("freq_hz,real,imag\n")
            for fr, h in zip(p.axes["x"].frf.freq_hz, p.axes["x"].frf.response[k]):
                fh.write(f"{fr},{h.real},{h.imag}\n")
        files.append(str(f))
    out = tmp_path / "plant.yaml"
    r = CliRunner().invoke(cli, ["profile", "build", "--frf-x", *files, "--base", "ender3pro",
                                 "-o", str(out)])
    assert r.exit_code == 0, r.output
    q = load_profile(out)
    assert q.axes["x"].frf.n_measurements == 3 and q.limits == p.limits
    # its own name and description, not the base's
    assert q.name == "plant" and "built from measured FRFs" in q.description
    r = CliRunner().invoke(cli, ["profile", "build", "--frf-x", *files, "--name", "mine",
                                 "--description", "my Ender, belts tightened", "-o", str(out)])
    assert r.exit_code == 0, r.output
    q = load_profile(out)
    assert (q.name, q.description) == ("mine", "my Ender, belts tightened")
    r = CliRunner().invoke(cli, ["profile", "build", "--help"])
    for opt in ("--frf-x", "--frf-y", "--base", "--name", "--description", "--output"):
        assert opt in r.output
    r = CliRunner().invoke(cli, ["profile", "show", str(out), "--json"])
    d = json.loads(r.output)
    assert d["axes"]["x"]["frf_measurements"] == 3
    r = CliRunner().invoke(cli, ["profile", "show", "ender3pro", "--json"])
    modes = json.loads(r.output)["axes"]["x"]["modes"]
    assert modes[0]["freq_hz"] == 42.0 and "damping" in modes[0]
    r = CliRunner().invoke(cli, ["profile", "check", "nomad3"])
    assert r.exit_code == 0 and "ok" in r.output


def test_voron24_is_a_klipper_corexy_from_the_measured_belt_test():
    p = load_profile("voron24")
    assert p.firmware.flavour == "klipper" and p.firmware.configured_accel_mm_s2 == 3000.0
    x, y = p.axes["x"].frf, p.axes["y"].frf
    assert x.n_measurements == 4 and np.array_equal(x.response, y.response)  # (G_A + G_B)/2
    modes = [m.freq_hz for m in p.axes["x"].modes]  # belts A / B: 46.0 / 45.2, 66.1 / 64.8 Hz
    assert abs(modes[0] - 45.6) < 1.0 and abs(modes[1] - 65.5) < 1.5, modes
    assert p.axes["x"].provenance["source"].startswith("GitHub agravelot/voron2-config")


def test_identify_names_describes_and_sets_the_flavour(tmp_path):
    import subprocess
    import sys

    from gcode_feedopt.profile.builtin import MEASURED, VORON_BELTS

    if not MEASURED.is_dir():
        pytest.skip("needs ../shared/data/measured")
    out = tmp_path / "mine.yaml"
    cmd = [sys.executable, "-m", "gcode_feedopt", "identify", "--x", str(MEASURED / VORON_BELTS[0]),
           "-o", str(out), "--flavour", "klipper"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    p = load_profile(out)
    assert p.name == "mine" and p.firmware.flavour == "klipper" and not p.firmware.g91_relative_e
    assert p.description.startswith("identified from voron2.4_") and "ender3pro" in p.description
    r = subprocess.run(cmd + ["--name", "v", "--description", "my Voron"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    p = load_profile(out)
    assert (p.name, p.description) == ("v", "my Voron")
