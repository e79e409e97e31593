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
    for name, make in BUILTINS.items():
        path = save_profile(make(), tmp_path / f"{name}.yaml")
        a, b = load_profile(path), load_profile(name)
        for ax in "xy":
            np.testing.assert_allclose(a.axes[ax].frf.response, b.axes[ax].frf.response, rtol=1e-10)
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
