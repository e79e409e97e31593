"""Profile files: YAML + FRF CSVs beside it. The only module that imports yaml.

Every value goes through one bounded getter (:class:`_Section`), so every error names the
file, the key path, the value, the limit and the fix; unknown keys are refused with a
"did you mean".
"""

from __future__ import annotations

import difflib
import importlib.resources
import math
import pathlib

import numpy as np
import yaml

from ..errors import FeedOptError, OutputError, ProfileError
from ..firmware.shaper import TYPES as SHAPER_TYPES, Shaper
from ..gcode.features import check_feature_tolerance
from ..inputs import read_text
from ..outputs import check_output, make_output_folder, write_text
from .frf_io import FRF_HEADER, frf_set_from_files, read_frf_csv, write_frf_csv  # noqa: F401
from ..twin.extensions import PARAMS as EXT_PARAMS, REQUIRED as EXT_REQUIRED
from .schema import AXES, AxisModel, Firmware, FRFSet, Limits, MachineProfile, Mode, Prior, TwinSettings

SCHEMA_VERSION = 1
BUILTIN_PACKAGE = "gcode_feedopt.profiles"


class _Section:
    """A mapping read from YAML, with bounded getters and unknown-key checks."""

    def __init__(self, data, where: str, origin: str):
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ProfileError(f"{origin}: {where or 'top level'} must be a mapping, got "
                               f"{type(data).__name__}")
        self.data = data
        self.where = where
        self.origin = origin
        self.used: set[str] = set()

    def _key(self, key):
        return f"{self.where}.{key}" if self.where else key

    def _err(self, key, msg):
        return ProfileError(f"{self.origin}: {self._key(key)}: {msg}")

    def has(self, key) -> bool:
        return key in self.data

    def raw(self, key, default=...):
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                # a missing key is most often a misspelt one: name the look-alike
                close = difflib.get_close_matches(key, [str(k) for k in self.data
                                                        if k not in self.used], n=1)
                if close:
                    raise self._err(key, f"missing, but '{self._key(close[0])}' is present; "
                                         f"did you mean '{key}'? rename it")
                raise self._err(key, "missing; add it (see README, 'Machine profiles')")
            return default
        return self.data[key]

    def getfloat(self, key, default=..., *, minval=None, maxval=None, above=None, below=None,
                 allow_none=False):
        v = self.raw(key, default)
        if v is None and allow_none:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self._err(key, f"{v!r} is not a number")
        v = float(v)
        if not math.isfinite(v):
            raise self._err(key, f"{v} is not finite")
        if minval is not None and v < minval:
            raise self._err(key, f"{v:g} is below the minimum {minval:g}")
        if maxval is not None and v > maxval:
            raise self._err(key, f"{v:g} is above the maximum {maxval:g}")
        if above is not None and v <= above:
            raise self._err(key, f"{v:g} must be above {above:g}")
        if below is not None and v >= below:
            raise self._err(key, f"{v:g} must be below {below:g}")
        return v

    def getint(self, key, default=..., *, minval=None, maxval=None):
        v = self.raw(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self._err(key, f"{v!r} is not an integer")
        if minval is not None and v < minval:
            raise self._err(key, f"{v} is below the minimum {minval}")
        if maxval is not None and v > maxval:
            raise self._err(key, f"{v} is above the maximum {maxval}")
        return v

    def getbool(self, key, default=...):
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self._err(key, f"{v!r} is not true/false")
        return v

    def getchoice(self, key, choices, default=...):
        v = self.raw(key, default)
        if v not in choices:
            raise self._err(key, f"{v!r} is not one of {', '.join(map(str, choices))}")
        return v

    def getstr(self, key, default=...):
        v = self.raw(key, default)
        if not isinstance(v, str):
            raise self._err(key, f"{v!r} is not text")
        return v

    def section(self, key, default=...):
        return _Section(self.raw(key, default), self._key(key), self.origin)

    def check_unknown(self):
        for k in self.data:
            if k not in self.used:
                close = difflib.get_close_matches(str(k), sorted(self.used), n=1)
                hint = f"; did you mean '{close[0]}'?" if close else \
                    f"; known keys: {', '.join(sorted(self.used))}"
                raise ProfileError(f"{self.origin}: unknown key '{self._key(k)}'{hint}")


def _axis_dict(sec: _Section, key: str, axes=("x", "y", "z", "e"), **bounds) -> dict:
    s = sec.section(key)
    out = {a: s.getfloat(a, **bounds) for a in axes}
    s.check_unknown()
    return out


def _read_axis(sec: _Section, base_dir: pathlib.Path | None) -> AxisModel:
    frf = None
    if sec.has("frf"):
        items = sec.raw("frf")
        if not isinstance(items, list) or not items:
            raise ProfileError(f"{sec.origin}: {sec._key('frf')}: must be a list of FRF file paths")
        paths = []
        for it in items:
            if not isinstance(it, str):
                raise ProfileError(f"{sec.origin}: {sec._key('frf')}: {it!r} is not a file path")
            p = pathlib.Path(it)
            if not p.is_absolute():
                if base_dir is None:
                    raise ProfileError(f"{sec.origin}: relative FRF path {it} without a base folder")
                p = base_dir / p
            paths.append(p)
        frf = frf_set_from_files(paths, sec.origin)
    modes = []
    for k, m in enumerate(sec.raw("modes", [])):
        ms = _Section(m, f"{sec._key('modes')}[{k}]", sec.origin)
        modes.append(Mode(freq_hz=ms.getfloat("freq_hz", above=0, maxval=1e4),
                          damping=ms.getfloat("damping", above=0, maxval=10.0),  # ζ ≥ 1: real poles
                          gain=ms.getfloat("gain", 1.0)))
        ms.check_unknown()
    effects = []
    for k, e in enumerate(sec.raw("effects", [])):
        es = _Section(e, f"{sec._key('effects')}[{k}]", sec.origin)
        kind = es.getchoice("kind", tuple(EXT_PARAMS))
        ps = es.section("params")
        params = {}
        for name, spec in EXT_PARAMS[kind].items():
            if name not in ps.data and name not in EXT_REQUIRED[kind]:
                continue
            if isinstance(spec[0], str):
                params[name] = ps.getchoice(name, spec)
            else:
                params[name] = ps.getfloat(name, minval=spec[0], maxval=spec[1])
        ps.check_unknown()
        es.check_unknown()
        needs = {("resonance_shift", "load"): ("load_ratio", "corner_hz"),
                 ("friction", "loop"): ("corner_hz",),
                 ("cross_coupling", "loop"): ("corner_hz",),
                 ("cross_coupling", "loop_command"): ("corner_hz",)}.get(
                     (kind, params.get("form")), ())
        missing = [n for n in needs if n not in params]
        if missing:
            raise ProfileError(f"{ps.origin}: {ps.where}: {kind} of form {params['form']} "
                               f"needs {' and '.join(missing)}; add it or diagnose the log again")
        effects.append({"kind": kind, "params": params})
    prov = sec.raw("provenance", {})
    sec.check_unknown()
    return AxisModel(frf=frf, modes=tuple(modes), provenance=prov, effects=tuple(effects))


def _read_prior(sec: _Section, n: int) -> Prior:
    mu = np.asarray(sec.raw("mu"), dtype=float)
    cov = np.asarray(sec.raw("cov"), dtype=float)
    if mu.shape != (n,) or cov.shape != (n, n):
        raise ProfileError(f"{sec.origin}: {sec.where}: prior must have mu of length {n} and cov "
                           f"{n}x{n} (1 + n2 + 1 + n3); got {mu.shape} and {cov.shape}")
    if not np.allclose(cov, cov.T, atol=1e-12 * max(1.0, np.abs(cov).max())):
        raise ProfileError(f"{sec.origin}: {sec.where}.cov is not symmetric")
    learned = tuple(sec.raw("learned_from", []))
    sec.check_unknown()
    return Prior(mu=mu, cov=cov, learned_from=learned)


def _read_shapers(fs: _Section, flavour: str) -> dict:
    """firmware.input_shaper: axis -> Shaper (module firmware.shaper); absent: {}."""
    if not fs.has("input_shaper"):
        return {}
    sec = fs.section("input_shaper")
    out = {}
    for ax in ("x", "y"):
        if not sec.has(ax):
            continue
        a = sec.section(ax)
        kind = a.getchoice("type", SHAPER_TYPES)
        centred = a.getbool("centred", flavour == "klipper")
        if kind == "custom":
            amps, times = a.raw("amplitudes"), a.raw("times_s")
            ok = (isinstance(amps, list) and isinstance(times, list) and 1 <= len(amps) == len(times)
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                          and math.isfinite(v) for v in amps + times))
            if not ok:
                raise a._err("amplitudes", "amplitudes and times_s must be lists of numbers of "
                             "one length (a pulse each), e.g. [0.5, 0.5] and [0, 0.0125]")
            if min(amps) < 0 or sum(amps) <= 0:
                raise a._err("amplitudes", f"{amps} must be non-negative with a positive sum")
            if min(times) < 0 or max(times) > 0.5 or any(b <= c for c, b in zip(times, times[1:])):
                raise a._err("times_s", f"{times} must ascend strictly, within 0–0.5 s")
            sh = Shaper("custom", 0.0, 0.0, centred, tuple(map(float, amps)), tuple(map(float, times)))
        else:
            sh = Shaper(kind, a.getfloat("freq_hz", above=0, maxval=1000),
                        a.getfloat("damping_ratio", 0.1, minval=0, below=1), centred)
        a.check_unknown()
        out[ax] = sh
    sec.check_unknown()
    return out


def _shapers_to_yaml(shapers: dict) -> dict:
    out = {}
    for ax, sh in shapers.items():
        d = {"type": sh.type, "centred": bool(sh.centred)}
        if sh.type == "custom":
            d.update(amplitudes=[float(v) for v in sh.amplitudes],
                     times_s=[float(v) for v in sh.times_s])
        else:
            d.update(freq_hz=float(sh.freq_hz), damping_ratio=float(sh.damping_ratio))
        out[ax] = d
    return out


def _feature_tolerance(ls: _Section, origin: str) -> dict:
    """limits.feature_tolerance_mm: {feature: mm or 'none'} (gcode.features)."""
    v = ls.raw("feature_tolerance_mm", None)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ProfileError(f"{origin}: limits.feature_tolerance_mm must be a mapping "
                           f"feature: mm, e.g. {{outer_wall: 0.05, infill: 0.3}}")
    try:
        tol = check_feature_tolerance(v)
    except FeedOptError as e:
        raise ProfileError(f"{origin}: limits.feature_tolerance_mm: {e}") from None
    for k, x in tol.items():
        if x != float("inf") and x > 10:
            raise ProfileError(f"{origin}: limits.feature_tolerance_mm.{k} = {x} mm is above "
                               f"10 mm")
    return tol


def parse_profile(data, origin: str, base_dir: pathlib.Path | None) -> MachineProfile:
    """Build a MachineProfile from the YAML mapping ``data``.

    Long for a reason: one flat read per key of the schema, section after section, each
    through a bounded getter that names the key in its error (profile/schema.py's order)."""
    top = _Section(data, "", origin)
    version = top.getint("schema", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        raise ProfileError(f"{origin}: schema {version} is not supported (this version reads "
                           f"schema {SCHEMA_VERSION})")
    name = top.getstr("name")
    description = top.getstr("description", "")
    ts_s = top.getfloat("ts_s", 0.002, above=0, maxval=0.1)
    ls = top.section("limits")
    limits = Limits(
        vmax_mm_s=ls.getfloat("vmax_mm_s", above=0, maxval=5000),
        amax_mm_s2=ls.getfloat("amax_mm_s2", above=0, maxval=1e6),
        jmax_mm_s3=ls.getfloat("jmax_mm_s3", None, above=0, allow_none=True),
        axis_vmax_mm_s=_axis_dict(ls, "axis_vmax_mm_s", above=0, maxval=5000),
        axis_amax_mm_s2=_axis_dict(ls, "axis_amax_mm_s2", above=0, maxval=1e6),
        tolerance_mm=ls.getfloat("tolerance_mm", above=0, maxval=10),
        stringency=ls.getfloat("stringency", minval=0.5, maxval=0.9999),
        max_volumetric_mm3_s=ls.getfloat("max_volumetric_mm3_s", None, above=0, maxval=1000,
                                         allow_none=True),
        filament_diameter_mm=ls.getfloat("filament_diameter_mm", 1.75, above=0.5, maxval=5),
        feature_tolerance_mm=_feature_tolerance(ls, origin),
        axis_jerk_mm_s=(_axis_dict(ls, "axis_jerk_mm_s", ("x", "y"), above=0, maxval=1000)
                        if ls.has("axis_jerk_mm_s") else None),
    )
    ls.check_unknown()
    fs = top.section("firmware")
    flavour = fs.getchoice("flavour", ("marlin", "klipper"))
    firmware = Firmware(
        flavour=flavour,
        g91_relative_e=fs.getbool("g91_relative_e", flavour == "marlin"),
        accel_mm_s2=fs.getfloat("accel_mm_s2", above=0, maxval=1e6),
        travel_accel_mm_s2=fs.getfloat("travel_accel_mm_s2", above=0, maxval=1e6),
        max_accel_mm_s2=_axis_dict(fs, "max_accel_mm_s2", above=0, maxval=1e6),
        max_feed_mm_s=_axis_dict(fs, "max_feed_mm_s", above=0, maxval=5000),
        junction_deviation_mm=fs.getfloat("junction_deviation_mm", 0.013, minval=0, maxval=5),
        square_corner_velocity_mm_s=fs.getfloat("square_corner_velocity_mm_s", 5.0, minval=0,
                                                maxval=1000),
        minimum_cruise_ratio=fs.getfloat("minimum_cruise_ratio", 0.5, minval=0, below=1),
        mm_per_arc_segment=fs.getfloat("mm_per_arc_segment", 1.0, above=0, maxval=100),
        max_lines_per_s=fs.getfloat("max_lines_per_s", above=1, maxval=1e6),
        retract_mm=fs.getfloat("retract_mm", 0.0, minval=0, maxval=50),
        retract_speed_mm_s=fs.getfloat("retract_speed_mm_s", 30.0, above=0, maxval=1000),
        instantaneous_corner_velocity_mm_s=fs.getfloat("instantaneous_corner_velocity_mm_s",
                                                       1.0, minval=0, maxval=1000),
        configured_accel_mm_s2=fs.getfloat("configured_accel_mm_s2", None, above=0, maxval=1e6,
                                           allow_none=True),
        configured_max_accel_mm_s2=(_axis_dict(fs, "configured_max_accel_mm_s2", ("x", "y"),
                                               above=0, maxval=1e6)
                                    if fs.has("configured_max_accel_mm_s2") else None),
        input_shaper=_read_shapers(fs, flavour),
    )
    fs.check_unknown()
    axs = top.section("axes")
    axes = {}
    for a in AXES:
        axes[a] = _read_axis(axs.section(a), base_dir)
    axs.check_unknown()
    tw = top.section("twin")
    n2 = tw.getint("n2", minval=0, maxval=200)
    n3 = tw.getint("n3", minval=0, maxval=500)
    priors = {}
    if tw.has("priors"):
        ps = tw.section("priors")
        for a in AXES:
            if ps.has(a):
                priors[a] = _read_prior(ps.section(a), 1 + (n2 + 1) + n3)
        ps.check_unknown()
    twin = TwinSettings(
        n2=n2, n3=n3,
        sigma_eps_mm=tw.getfloat("sigma_eps_mm", above=0, maxval=10),
        coef_variance=tw.getchoice("coef_variance", ("minmax", "sample", "ensemble"), "minmax"),
        n_taps=tw.getint("n_taps", 500, minval=8, maxval=100000),
        priors=priors,
        physics=tw.getchoice("physics", ("modal", "bins"), "modal"),
        dc_gain=tw.getchoice("dc_gain", ("unit", "fitted"), "unit"),
    )
    tw.check_unknown()
    provenance = top.raw("provenance", {})
    top.check_unknown()
    return MachineProfile(name=name, description=description, ts_s=ts_s, limits=limits,
                          firmware=firmware, axes=axes, twin=twin, provenance=provenance,
                          source_path=origin)


def builtin_names() -> list[str]:
    root = importlib.resources.files(BUILTIN_PACKAGE)
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".yaml"))


def _builtin_dir() -> pathlib.Path:
    root = importlib.resources.files(BUILTIN_PACKAGE)
    return pathlib.Path(str(root))


def load_profile(name_or_path) -> MachineProfile:
    """Load a built-in profile by name (``ender3pro``, ``nomad3``) or a YAML file by path."""
    text = str(name_or_path)
    p = pathlib.Path(text)
    if not (text.endswith((".yaml", ".yml")) or p.exists() or "/" in text or "\\" in text):
        names = builtin_names()
        if text not in names:
            close = difflib.get_close_matches(text, names, n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise ProfileError(f"unknown machine '{text}'; {hint}built-in profiles: "
                               f"{', '.join(names)} (or pass a profile .yaml path)")
        p = _builtin_dir() / f"{text}.yaml"
    if not p.exists():  # a FIFO or folder: read_text says what it is
        raise ProfileError(f"{p}: profile file not found; check the path or use a built-in "
                           f"name ({', '.join(builtin_names())})")

    text = read_text(p, "a profile YAML", ProfileError)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}" if mark else ""
        raise ProfileError(f"{p}{where}: not valid YAML ({getattr(exc, 'problem', exc)}); fix "
                           "the syntax") from None
    return parse_profile(data, str(p), p.parent)


def _prior_to_yaml(pr: Prior) -> dict:
    return {"mu": [float(v) for v in pr.mu], "cov": [[float(v) for v in row] for row in pr.cov],
            "learned_from": list(pr.learned_from)}


def profile_to_dict(profile: MachineProfile, frf_paths: dict | None = None) -> dict:
    """The YAML mapping of a profile; ``frf_paths`` maps axis -> list of relative CSV paths."""
    L, F, T = profile.limits, profile.firmware, profile.twin
    d = {
        "schema": SCHEMA_VERSION, "name": profile.name, "description": profile.description,
        "ts_s": profile.ts_s,
        "limits": {"vmax_mm_s": L.vmax_mm_s, "amax_mm_s2": L.amax_mm_s2,
                   "jmax_mm_s3": L.jmax_mm_s3, "axis_vmax_mm_s": dict(L.axis_vmax_mm_s),
                   "axis_amax_mm_s2": dict(L.axis_amax_mm_s2), "tolerance_mm": L.tolerance_mm,
                   "stringency": L.stringency, "filament_diameter_mm": L.filament_diameter_mm},
        "firmware": {"flavour": F.flavour, "g91_relative_e": F.g91_relative_e,
                     "accel_mm_s2": F.accel_mm_s2, "travel_accel_mm_s2": F.travel_accel_mm_s2,
                     "max_accel_mm_s2": dict(F.max_accel_mm_s2),
                     "max_feed_mm_s": dict(F.max_feed_mm_s),
                     "junction_deviation_mm": F.junction_deviation_mm,
                     "square_corner_velocity_mm_s": F.square_corner_velocity_mm_s,
                     "minimum_cruise_ratio": F.minimum_cruise_ratio,
                     "mm_per_arc_segment": F.mm_per_arc_segment,
                     "max_lines_per_s": F.max_lines_per_s, "retract_mm": F.retract_mm,
                     "retract_speed_mm_s": F.retract_speed_mm_s},
        "axes": {},
        "twin": {"n2": T.n2, "n3": T.n3, "sigma_eps_mm": T.sigma_eps_mm,
                 "coef_variance": T.coef_variance, "n_taps": T.n_taps,
                 "physics": T.physics, "dc_gain": T.dc_gain},
        "provenance": profile.provenance,
    }
    if F.flavour == "klipper":
        d["firmware"]["instantaneous_corner_velocity_mm_s"] = F.instantaneous_corner_velocity_mm_s
    if L.max_volumetric_mm3_s is not None:
        d["limits"]["max_volumetric_mm3_s"] = L.max_volumetric_mm3_s
    if L.axis_jerk_mm_s is not None:
        d["limits"]["axis_jerk_mm_s"] = dict(L.axis_jerk_mm_s)
    if L.feature_tolerance_mm:
        d["limits"]["feature_tolerance_mm"] = {
            k: ("none" if v == float("inf") else v) for k, v in L.feature_tolerance_mm.items()}
    if F.configured_accel_mm_s2 is not None:
        d["firmware"]["configured_accel_mm_s2"] = F.configured_accel_mm_s2
    if F.configured_max_accel_mm_s2 is not None:
        d["firmware"]["configured_max_accel_mm_s2"] = dict(F.configured_max_accel_mm_s2)
    if F.input_shaper:
        d["firmware"]["input_shaper"] = _shapers_to_yaml(F.input_shaper)
    if T.priors:
        d["twin"]["priors"] = {a: _prior_to_yaml(p) for a, p in T.priors.items()}
    for a, ax in profile.axes.items():
        ad = {}
        if ax.frf is not None and frf_paths and a in frf_paths:
            ad["frf"] = list(frf_paths[a])
        if ax.modes:
            ad["modes"] = [{"freq_hz": m.freq_hz, "damping": m.damping, "gain": m.gain}
                           for m in ax.modes]
        if ax.effects:
            ad["effects"] = [{"kind": e["kind"], "params": {
                k: (v if isinstance(v, str) else float(v)) for k, v in e["params"].items()}}
                for e in ax.effects]
        if ax.provenance:
            ad["provenance"] = ax.provenance
        d["axes"][a] = ad
    return d


def check_profile_output(path, option: str = "-o", inputs=()):
    """Check that a profile can be written at ``path`` (outputs.check_output) and that its
    FRF folder (``path``'s stem, beside it) can be made and holds none of ``inputs``.
    Nothing is written; returns the outputs.Target of the YAML file."""
    inputs = [pathlib.Path(i) for i in inputs if i is not None]
    target = check_output(path, option, inputs=inputs, suffixes=(".yaml", ".yml"))
    folder = target.path.parent / target.path.stem
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{option}: {path}: its FRF folder {folder} exists and is not a "
                          "folder; choose another profile name")
    if folder.is_dir():
        real = folder.resolve()
        for i in inputs:
            if i.exists() and i.resolve().parent == real:
                raise OutputError(f"{option}: {path}: its FRFs go to {folder}/, where the input "
                                  f"{i} is; choose another profile name")
    return target


class _Dumper(yaml.SafeDumper):
    """YAML as ``yaml.safe_dump`` writes it, but a list of numbers on one (wrapped) line: a
    learned prior's weights, its covariance rows and its residual filters took one line per
    number (a 500-tap filter 500 lines, a 42 × 42 covariance 1,806)."""


def _number_list(dumper, data):
    flat = bool(data) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                              for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat)


_Dumper.add_representer(list, _number_list)


def save_profile(profile: MachineProfile, path, option: str = "-o") -> pathlib.Path:
    """Write ``path`` (YAML) and the FRF CSVs in a folder named after it, beside it; every
    file through gcode_feedopt.outputs (temp + replace). The folder ``path`` is in must
    exist; the FRF folder is made (one level)."""
    target = check_profile_output(path, option)
    path = target.path
    folder = path.parent / path.stem
    frf_paths = {}
    for a, ax in profile.axes.items():
        if ax.frf is None:
            continue
        make_output_folder(folder, option)
        rel = []
        for k in range(ax.frf.n_measurements):
            fname = f"{a}_{k + 1:02d}.csv"
            write_frf_csv(folder / fname, ax.frf.freq_hz, ax.frf.response[k])
            rel.append(f"{folder.name}/{fname}")
        frf_paths[a] = rel
    d = profile_to_dict(profile, frf_paths)
    write_text(target, yaml.dump(d, Dumper=_Dumper, sort_keys=False, width=100))
    return path
