"""Plots and HTML reports: the pictures and pages that calibration and measurement write.

Used by :func:`lowcam.calibrate.write_report` and
:func:`lowcam.measure.comparison_report.write_compare_report`.

Contents
--------
- :data:`STYLE`: the pages' CSS
- :func:`figure`: draw one matplotlib figure (headless, 100 dpi) and save it as PNG
- :func:`image`: an ``<img>`` of a PNG, copied into the page's folder when it lies elsewhere
- :func:`json_value`: what JSON cannot take as it is (a NumPy value, a path) as a list, float or text
- :func:`numbers_block`: numbers (NumPy values allowed) as indented JSON in a ``<pre>``, optionally folded
- :func:`write_page`: ``index.html`` in a folder: title, style and heading around HTML sections; returns its path
"""
from __future__ import annotations

import html
import io
import json
from pathlib import Path

import numpy as np  # the doctests' NumPy values

from .outputs import atomic_write_bytes, make_output_folder

STYLE = ("body{font-family:sans-serif;max-width:1200px;margin:auto}img{max-width:100%}"
         "pre{background:#f4f4f4;padding:8px;overflow:auto}")


def figure(path: Path, draw, size=(7, 4.5)) -> Path:
    """Call ``draw(fig)`` on a new ``size`` (inches, 100 dpi) figure and save it as the PNG ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=size, dpi=100)
    draw(fig)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    return atomic_write_bytes(make_output_folder(path.parent) / path.name, buffer.getvalue())


def image(folder, path, alt: str) -> str:
    """An ``<img>`` of the PNG ``path`` for a page in ``folder``, copying the file there if it lies elsewhere."""
    path, folder = Path(path), Path(folder)
    target = folder / path.name
    if path.resolve() != target.resolve():
        atomic_write_bytes(make_output_folder(folder) / path.name, path.read_bytes())
    return f"<img src='{html.escape(path.name)}' alt='{html.escape(alt)}'>"


def json_value(value):
    """What ``json.dumps`` cannot take as it is (``default=``): a NumPy number or array as a float or list; anything
    else (a path) as its text."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def numbers_block(numbers, summary: str | None = None) -> str:
    """``numbers`` (NumPy values allowed) as indented JSON in a ``<pre>``; folded under ``summary`` if given.

    >>> numbers_block(np.float32(0.5), "fit")
    '<details><summary>fit</summary><pre>0.5</pre></details>'
    """
    pre = f"<pre>{html.escape(json.dumps(numbers, indent=1, default=json_value))}</pre>"
    return f"<details><summary>{html.escape(summary)}</summary>{pre}</details>" if summary else pre


def write_page(folder, title: str, heading: str, sections) -> Path:
    """Write ``folder/index.html``: a page titled ``title`` with the heading ``heading`` over ``sections`` (HTML
    fragments, in order); returns its path."""
    folder = make_output_folder(folder)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{STYLE}</style></head><body>", f"<h1>{html.escape(heading)}</h1>", *sections, "</body></html>"]
    page = folder / "index.html"
    atomic_write_bytes(page, "\n".join(parts).encode())
    return page
