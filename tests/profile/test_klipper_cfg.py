"""The input shaper a Klipper printer runs, from its printer.cfg (profile.klipper_cfg), into a
profile by `profile build --klipper-config` and `identify --klipper-config`."""

import pathlib

import pytest
import yaml
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.errors import ProfileError
from gcode_feedopt.firmware.shaper import Shaper
from gcode_feedopt.profile.klipper_cfg import read_input_shaper

BENCH_A = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "independent"

SAVED = """[printer]
kinematics: corexy
max_accel: 3000

[input_shaper]
shaper_freq_x: 40.0   # measured last year
shaper_type: ei

[include macros.cfg]

#*# <---------------------- SAVE_CONFIG ---------------------->
#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.
#*#
#*# [input_shaper]
#*# shaper_type_x = mzv
#*# shaper_freq_x = 48.2
#*# shaper_type_y = ei
#*# shaper_freq_y = 39.6
"""


def _cfg(tmp_path, text):
    p = tmp_path / "printer.cfg"
    p.write_text(text)
    return p


def test_save_configs_block_overrides_the_section_as_klipper_reads_it(tmp_path):
    got = read_input_shaper(_cfg(tmp_path, SAVED))
    assert got == {"x": Shaper("mzv", 48.2, 0.1, True), "y": Shaper("ei", 39.6, 0.1, True)}


def test_defaults_and_an_axis_left_unshaped(tmp_path):
    got = read_input_shaper(_cfg(tmp_path, "[input_shaper]\nshaper_freq_x = 52.5\n"
                                           "shaper_freq_y = 0\ndamping_ratio_x = 0.05\n"))
    assert got == {"x": Shaper("mzv", 52.5, 0.05, True)}


@pytest.mark.parametrize("text, words", [
    ("[input_shaper]\nshaper_type: 2hump_ei\nshaper_freq_x: 40\n",
     ["printer.cfg:2: shaper type '2hump_ei' has no closed form", "type: custom"]),
    ("[printer]\nmax_accel: 3000\n", ["printer.cfg: no [input_shaper] section"]),
    ("[input_shaper]\nshaper_freq_x: forty\n", ["printer.cfg:2: shaper_freq_x = 'forty' is not a number"]),
    ("[input_shaper]\nshaper_freq_x: 0\n", ["shapes no axis"]),
])
def test_a_config_we_cannot_read_is_one_line(tmp_path, text, words):
    with pytest.raises(ProfileError) as exc:
        read_input_shaper(_cfg(tmp_path, text))
    msg = str(exc.value)
    assert all(w in msg for w in words) and "\n" not in msg, msg


@pytest.mark.skipif(not BENCH_A.is_dir(), reason="needs ../shared/data/independent")
@pytest.mark.parametrize("command", ["profile build", "identify"])
def test_the_printers_shaper_goes_into_the_profile_it_builds(tmp_path, command):
    cfg = _cfg(tmp_path, SAVED)
    xs = [str(p) for p in sorted((BENCH_A / "frf").glob("x_*.csv"))[:3]]
    ys = [str(p) for p in sorted((BENCH_A / "frf").glob("y_*.csv"))[:3]]
    out = tmp_path / "mine.yaml"
    if command == "profile build":
        args = ["profile", "build", "--frf-x", *xs, "--frf-y", *ys, "--base", "voron24",
                "--klipper-config", str(cfg), "-o", str(out)]
    else:
        args = ["identify", *sum((["--x", f] for f in xs), []), *sum((["--y", f] for f in ys), []),
                "--base", "voron24", "--klipper-config", str(cfg), "-o", str(out)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    d = yaml.safe_load(out.read_text())["firmware"]["input_shaper"]
    assert d["x"] == {"type": "mzv", "centred": True, "freq_hz": 48.2, "damping_ratio": 0.1}
    assert d["y"]["type"] == "ei" and d["y"]["freq_hz"] == 39.6
    show = CliRunner().invoke(cli, ["profile", "show", str(out)])
    assert "printed through input shaper mzv 48.2 Hz" in show.output


@pytest.mark.skipif(not BENCH_A.is_dir(), reason="needs ../shared/data/independent")
@pytest.mark.parametrize("command", ["profile build", "identify"])
def test_a_printer_cfg_on_a_marlin_base_is_refused_with_the_way_round(tmp_path, command):
    cfg = _cfg(tmp_path, SAVED)
    xs = [str(p) for p in sorted((BENCH_A / "frf").glob("x_*.csv"))[:3]]
    out = tmp_path / "mine.yaml"
    args = (["profile", "build", "--frf-x", *xs] if command == "profile build" else
            ["identify", *sum((["--x", f] for f in xs), [])])
    res = CliRunner().invoke(cli, args + ["--base", "ender3pro", "--klipper-config", str(cfg),
                                          "-o", str(out)])
    assert res.exit_code == 2 and "a printer.cfg is Klipper's" in res.output, res.output
    assert not out.exists()
    if command == "identify":  # --flavour klipper says so
        res = CliRunner().invoke(cli, args + ["--base", "ender3pro", "--flavour", "klipper",
                                              "--klipper-config", str(cfg), "-o", str(out)])
        assert res.exit_code == 0, res.output
