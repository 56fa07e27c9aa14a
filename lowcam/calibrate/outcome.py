"""What a calibration gives: its outcome (fitted values, textures, numbers, figures), the profile it updates and
the report it adds to.

Contents
--------
- :class:`Texture`: a fitted texture for an effect's path parameter, written beside the profile
- :class:`Calibration`: one calibration's outcome: summary, fitted values, textures, numbers and figures
- :func:`apply_to_profile`: a copy of a profile with every calibration's values, textures written beside it
- :func:`write_report`: an HTML page with every calibration's summary, numbers and plots

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..effects.chromatic_aberration import write_ca_grid
from ..outputs import write_png
from ..reports import image, numbers_block, write_page


@dataclass
class Texture:
    """A fitted texture for the effect parameter ``param`` (a path): :func:`apply_to_profile` saves ``data`` as
    ``file`` beside the profile with ``write(path, data, camera)`` and points the parameter at it."""

    param: str
    data: np.ndarray
    file: str
    write: Callable[[Path, np.ndarray, Any], None]


@dataclass
class Calibration:
    """One calibration's outcome: ``summary`` (one line), fitted ``values`` per effect, ``textures`` per effect
    (:class:`Texture`), ``numbers`` for the report, ``figures`` (PNG paths), ``provenance`` entries for the
    profile's ``[provenance]`` table (``"effect.param"``: where the number came from), ``notes`` (lines for the
    terminal and the report) and ``table`` (rows of a table in the report, one dict of column: text each)."""

    what: str
    summary: str
    values: dict[str, dict] = field(default_factory=dict)
    numbers: dict = field(default_factory=dict)
    figures: list[Path] = field(default_factory=list)
    textures: dict[str, Texture] = field(default_factory=dict)
    provenance: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    table: list[dict] = field(default_factory=list)


def _write_gain_png(path: Path, gain: np.ndarray, camera) -> None:
    write_png(path, np.round(gain * 65535).astype(np.uint16))


def _write_ca_csv(path: Path, grid: np.ndarray, camera) -> None:
    write_ca_grid(path, grid, camera.width, camera.height)


def apply_to_profile(profile, calibrations, out_path: Path):
    """A copy of ``profile`` with every calibration's values, textures written beside ``out_path``."""
    out_path = Path(out_path).resolve()
    tex_dir = out_path.parent / out_path.stem
    new = profile
    for cal in calibrations:
        for name in list(cal.values) + [n for n in cal.textures if n not in cal.values]:
            values = dict(cal.values.get(name, {}))
            if name == "video":  # how the footage was coded, read from its bitstream (a record)
                new = new.copy()
                new.video = dict(values)
                continue
            if name == "camera":  # the camera's own settings (a plate profile's name)
                new = new.copy()
                for key, value in values.items():
                    setattr(new.camera, key, value)
                continue
            if values.get("enabled", True) is False:  # an effect the calibration turns off
                new = new.without(name) if new.effect(name) is not None else new
                continue
            texture = cal.textures.get(name)
            if texture is not None:
                path = tex_dir / texture.file
                texture.write(path, texture.data, new.camera)
                values[texture.param] = str(path)
            new = new.with_effect(name, replace=(name == "lens_distortion"), source=str(out_path),
                                  base_dir=out_path.parent, **values)
        new.provenance.update(cal.provenance)
    new = new.copy()
    new.path = out_path
    return new


def write_report(calibrations, folder) -> Path:
    """An HTML page with every calibration's summary, numbers and plots."""
    sections = []
    for cal in calibrations:
        sections.append(f"<h2>{html.escape(cal.what)}</h2><p><b>{html.escape(cal.summary)}</b></p>")
        if cal.notes:
            sections.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in cal.notes) + "</ul>")
        if cal.table:
            head = "".join(f"<th>{html.escape(k)}</th>" for k in cal.table[0])
            rows = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row.values()) + "</tr>"
                           for row in cal.table)
            sections.append(f"<table border='1' cellpadding='4' style='border-collapse:collapse;font-size:90%'>"
                            f"<tr>{head}</tr>{rows}</table>")
        sections.extend(image(folder, fig, cal.what) for fig in cal.figures)
        sections.append(numbers_block(cal.numbers, "numbers and fit quality"))
    return write_page(folder, "Lowcam calibration", "Lowcam calibration report", sections)
