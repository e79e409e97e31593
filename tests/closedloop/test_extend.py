"""The extended model goes into a profile: the axis's extensions reproduce the linear effect
in the twin's physics; saved and loaded back exactly; the diagnose CLI writes it."""

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.twin.physics import nominal_impulse
from gcode_feedopt.closedloop.extend import extend_profile
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.io import save_profile
from gcode_feedopt.twin.physics import axis_impulse, mean_model
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import respond

P = load_profile("ender3pro")
CMD = 10 + 0.1 * np.cumsum(np.r_[np.zeros(100), np.ones(200), np.zeros(300)])


@pytest.mark.parametrize("effect, truth, limit", [
    ({"kind": "delay", "axis": "x", "params": {"delay_s": 0.008}},
     lambda h: fx.delay_signal(respond(CMD, h), 0.008, P.ts_s), 0.005),
    ({"kind": "gain", "axis": "x", "params": {"scale": 1.02}},
     lambda h: CMD[0] + 1.02 * (respond(CMD, h) - CMD[0]), 1e-9),
    ({"kind": "resonance_shift", "axis": "x", "params": {"frequency_hz": 32.0}},
     lambda h: respond(CMD, _shifted_mean(32.0)), 0.05),
    ({"kind": "resonance_shift", "axis": "x",
      "params": {"frequency_hz": 30.0, "load_ratio": 0.3, "corner_hz": 25.0, "form": "load"}},
     lambda h: respond(CMD, _loaded_mean(0.3, 2 * np.pi * 25.0)), 1e-9),
])
def test_linear_effect_applied_to_the_model(effect, truth, limit):
    h0 = nominal_impulse(P)["x"][0]
    ext = extend_profile(P, [effect])
    hm = axis_impulse(ext, "x").mean
    y = truth(h0)
    before = np.max(np.abs(respond(CMD, h0) - y))
    after = np.max(np.abs(respond(CMD, hm) - y))
    assert after <= limit * before
    rec = ext.provenance["closed_loop"][-1]["applied_to_the_model"]
    assert rec[0]["kind"] == effect["kind"]


def _shifted_mean(f1):
    """The representative model's dominant mode moved to f1 Hz as a mass change moves it."""
    m = mean_model(P, "x")
    return m.mode_shifted(m.dominant, f1 / m.freq_hz[m.dominant]).impulse(P.ts_s, P.twin.n_taps)


def _loaded_mean(ratio, a):
    """The members' mean impulse response with each member's loop loaded
    (ModalModel.loaded): the twin's mean is its members' (twin.modal.ensemble_impulse)."""
    from gcode_feedopt.twin.physics import axis_modal

    return np.mean([m.loaded(ratio, a).impulse(P.ts_s, P.twin.n_taps)
                    for m in axis_modal(P, "x").models], axis=0)


@pytest.mark.parametrize("kind, params, missing", [
    ("resonance_shift", {"frequency_hz": 30.0, "load_ratio": 0.3, "form": "load"}, "corner_hz"),
    ("friction", {"magnitude_mm": 0.01, "form": "loop"}, "corner_hz"),
    ("cross_coupling", {"from_axis": "y", "mm_per_mm_s2": 1e-6, "form": "loop_command"},
     "corner_hz")])
def test_a_form_without_its_parameter_is_refused_by_name(kind, params, missing, tmp_path):
    """A profile whose extension of form ``load`` / ``loop`` lacks the corner (edited by
    hand) is refused with the key that is missing, not run with a default."""
    import yaml

    from gcode_feedopt.errors import ProfileError

    ext = extend_profile(P, [{"kind": kind, "axis": "x",
                              "params": {**params, missing: 25.0}}])
    path = save_profile(ext, tmp_path / "ext.yaml")
    data = yaml.safe_load(path.read_text())
    del data["axes"]["x"]["effects"][0]["params"][missing]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ProfileError, match=f"axes.x.effects.0.?.params.*needs {missing}"):
        load_profile(path)
    assert load_profile(save_profile(ext, tmp_path / "ok.yaml")).axes["x"].effects == \
        ext.axes["x"].effects


def test_extended_profile_round_trip(tmp_path):
    ext = extend_profile(P, [{"kind": "delay", "axis": "y", "params": {"delay_s": 0.004}},
                             {"kind": "backlash", "axis": "x", "params": {"magnitude_mm": 0.05}}],
                         source="test")
    path = save_profile(ext, tmp_path / "ext.yaml")
    back = load_profile(path)
    np.testing.assert_allclose(back.axes["y"].frf.response, ext.axes["y"].frf.response, rtol=1e-9)
    assert back.axes["y"].effects == ext.axes["y"].effects == ({"kind": "delay", "params": {"delay_s": 0.004}},)
    np.testing.assert_allclose(axis_impulse(back, "y").mean, axis_impulse(ext, "y").mean, atol=1e-12)
    assert back.provenance["closed_loop"] == ext.provenance["closed_loop"]
    assert back.axes["x"].effects == ext.axes["x"].effects
    assert back.axes["x"].effects[0]["params"]["magnitude_mm"] == 0.05
    changes = {r["kind"]: r["changes"] for r in back.provenance["closed_loop"][0]["applied_to_the_model"]}
    assert changes == {"delay": "physics", "backlash": "mean"}


def test_diagnose_cli_writes_profile(tmp_path):
    from .test_logs import make_log

    p = tmp_path / "d.csv"
    make_log(p, effects=[fx.Delay("x", delay_s=0.006), fx.SensorNoise("x", std_mm=0.001)])
    out = tmp_path / "ext.yaml"
    r = CliRunner().invoke(cli, ["diagnose", "-m", "ender3pro", str(p), "-o", str(out)])
    assert r.exit_code == 0, r.output
    ext = load_profile(out)
    rec = ext.provenance["closed_loop"][-1]["applied_to_the_model"][0]
    assert rec["kind"] == "delay" and abs(rec["params"]["delay_s"] - 0.006) < 0.00012


@pytest.mark.parametrize("name", ["log_04.csv", "log_05.csv", "log_06.csv", "log_08.csv",
                                  "log_09.csv", "log_10.csv", "log_11.csv"])
def test_written_profile_predicts_what_diagnose_reported(tmp_path, bench_a, name):
    """Issue 19, point 4: the profile ``diagnose -o`` writes, loaded back from its YAML and run
    by ``predict --no-learn``, has the held-out RMS ``diagnose`` reported, within 10 %."""
    from tests.conftest import INDEPENDENT_DIR
    from tests.written_extension import diagnose_then_predict

    prof, _ = bench_a
    base = save_profile(prof, tmp_path / "benchA.yaml")
    d, got = diagnose_then_predict(base, INDEPENDENT_DIR / "logs" / name, tmp_path)
    for ax in "xy":
        rms = got[ax]
        want = d["holdout_rms_mm"]["after"][ax]
        assert abs(rms - want) <= 0.1 * want, (ax, rms, want)
        # and the extension helps where the effect is
        assert d["holdout_rms_mm"]["after"][ax] <= d["holdout_rms_mm"]["before"][ax] * 1.001
