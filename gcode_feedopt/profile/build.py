"""A profile from measured FRF files on the limits of a base profile (``profile build``)."""

from __future__ import annotations

import dataclasses
import pathlib
import warnings

from ..errors import ModelWarning
from .frf_io import frf_set_from_files
from .schema import AxisModel, MachineProfile, Mode
from ..twin.physics import axis_modal


def build_from_frfs(base: MachineProfile, files: dict, *, name: str,
                    description: str | None = None) -> tuple[MachineProfile, list[str]]:
    """(profile, report lines): ``files`` maps axis -> FRF CSV paths; the other axes, the
    limits, the firmware and the twin settings come from ``base`` (its learned priors do not
    apply to another machine and are dropped). Each axis's FRF set is fitted with the twin's
    modal model at once (``twin.physics``), so a set the model cannot explain is reported
    here, by file and frequency, not discovered later in a run; the mean fit's modes are
    stored as the axis's ``modes``."""
    # on use: twin.modal's fitting stack (`gcode-feedopt --help` loads this module; +10 ms)

    axes = dict(base.axes)
    for axis, paths in files.items():
        if paths:
            notes = []
            frf = frf_set_from_files(paths, notes=notes)
            for n in notes:
                warnings.warn(f"axis {axis}: {n}", ModelWarning, stacklevel=2)
            axes[axis] = AxisModel(frf=frf, modes=(), provenance={
                "kind": "measured", "files": [str(pathlib.Path(f).resolve()) for f in paths],
                "n_measurements": frf.n_measurements})
    prov = dict(base.provenance)
    prov["built_from"] = {"base": base.name, **{f"frf_{a}": [str(p) for p in v] for a, v in files.items()}}
    twin = dataclasses.replace(base.twin, priors={})
    new = dataclasses.replace(base, name=name, axes=axes, provenance=prov, twin=twin,
                              description=description or f"built from measured FRFs on {base.name} limits")
    lines = []
    for axis, paths in files.items():
        if not paths:
            continue
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ModelWarning)
            fits = axis_modal(new, axis)
        for w in caught:
            warnings.warn(w.message, w.category, stacklevel=2)
        m = fits.mean_model()
        rms = max(f.rms_rel for f in fits.fits)
        lines.append(f"axis {axis}: {len(fits.fits)} FRFs, {m.n_modes} modes "
                     + ", ".join(f"{f:.1f} Hz ζ {z:.3f}" for f, z in zip(m.freq_hz, m.damping))
                     + f", lag {1000 * m.lag_s:.2f} ms, fit within {100 * rms:.1f} % RMS")
        modes = tuple(Mode(freq_hz=float(f), damping=float(z), gain=float(g))
                      for f, z, g in zip(m.freq_hz, m.damping, m.b0))
        axes[axis] = dataclasses.replace(axes[axis], modes=modes, provenance=dict(
            axes[axis].provenance, modal_fit={"modes": len(modes), "max_rms_percent": round(100 * rms, 3),
                                              "warnings": list(fits.warnings)}))
    return dataclasses.replace(new, axes=axes), lines
