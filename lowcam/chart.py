"""The printable calibration chart: one page with every target the calibrations need (``lowcam chart``).

The targets are those of the paper's calibrations (Klein & Murray 2010, sec. 4). Layout (A4 or A3 landscape;
millimetres from the page's top-left corner, y down), described in a JSON file that travels with the chart:

- a ChArUco board (OpenCV ``aruco``, dictionary DICT_5X5_100): pose and lens calibration;
- a grey white-noise field: chromatic aberration and demosaic identification;
- slanted squares (5 degrees) in several regions and orientations: edge spread, MTF, sharpening;
- grey steps and colour patches: tone curve, noise against brightness, colour matrix.

Contents
--------
- :data:`PAGES_MM`: page sizes (landscape width, height in mm) by name
- :data:`COLOURS`: the colour patches (sRGB 0-255)
- :func:`make_chart`: the chart as a uint8 RGB raster at ``dpi``, and its layout description
- :func:`write_chart`: write the chart (``.pdf`` or ``.png``) and its layout ``<name>.json`` beside it

References
----------
- [Klein2010] G. Klein and D. W. Murray, "Simulating Low-Cost Cameras for Augmented Reality Compositing", IEEE
  Transactions on Visualization and Computer Graphics 16(3), 369-380, 2010.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np

from .captures import DICTIONARY, charuco_board
from .errors import LowcamError
from .outputs import atomic_write_bytes, write_png

PAGES_MM = {"a4": (297.0, 210.0), "a3": (420.0, 297.0)}
#: Colour patches (sRGB 0-255): primaries, secondaries, skin and foliage tones, and a few mixed colours.
COLOURS = [(200, 40, 40), (40, 160, 60), (40, 60, 190), (220, 200, 40), (200, 60, 170), (40, 170, 190),
           (190, 140, 110), (110, 130, 60), (240, 140, 30), (90, 60, 140), (150, 190, 60), (60, 90, 120)]


def make_chart(size: str = "a4", dpi: int = 300, seed: int = 7) -> tuple[np.ndarray, dict]:
    """The chart as a greyscale-or-colour uint8 RGB raster at ``dpi``, and its layout description."""
    if size not in PAGES_MM:
        raise LowcamError(f"chart size must be one of {', '.join(PAGES_MM)}, got {size!r}")
    if not 50 <= dpi <= 1200:
        raise LowcamError(f"chart dpi must lie in [50, 1200], got {dpi}")
    page_w, page_h = PAGES_MM[size]
    s = PAGES_MM[size][0] / 297.0  # everything scales with the page
    px = dpi / 25.4
    img = np.full((int(round(page_h * px)), int(round(page_w * px)), 3), 255, np.uint8)

    def rect(x, y, w, h):
        return int(round(x * px)), int(round(y * px)), int(round(w * px)), int(round(h * px))

    layout = {"format": "lowcam-chart", "version": 1, "size": size, "page_mm": [page_w, page_h], "dpi": dpi,
              "elements": []}
    margin = 12 * s
    # ChArUco board, left.
    squares, square_mm = (7, 5), 25.0 * s
    board = charuco_board(squares, square_mm, 0.75 * square_mm)
    bw, bh = squares[0] * square_mm, squares[1] * square_mm
    x, y, w, h = rect(margin, margin, bw, bh)
    img[y:y + h, x:x + w] = board.generateImage((w, h), marginSize=0, borderBits=1)[..., None]
    layout["elements"].append({"type": "charuco", "rect_mm": [margin, margin, bw, bh], "squares": list(squares),
                               "square_mm": square_mm, "marker_mm": 0.75 * square_mm, "dictionary": DICTIONARY})
    # Grey white-noise field, right of the board.
    nx0 = 2 * margin + bw
    nw, nh = page_w - nx0 - margin, bh
    cell_mm = 1.5 * s
    rng = np.random.default_rng(seed)
    cells = rng.integers(40, 216, (int(nh / cell_mm), int(nw / cell_mm)), dtype=np.uint8)
    x, y, w, h = rect(nx0, margin, nw, nh)
    img[y:y + h, x:x + w] = cv2.resize(cells, (w, h), interpolation=cv2.INTER_NEAREST)[..., None]
    layout["elements"].append({"type": "noise_field", "rect_mm": [nx0, margin, nw, nh], "cell_mm": cell_mm,
                               "seed": seed})
    # Slanted squares along the bottom-left, rotated +5 and -5 degrees.
    row_y = 2 * margin + bh
    side = 18 * s
    edges = []
    for k in range(5):
        cx_mm, cy_mm = margin + side * (0.8 + 1.7 * k), row_y + side * 0.75
        angle = 5.0 if k % 2 == 0 else -5.0
        pts = cv2.boxPoints(((cx_mm * px, cy_mm * px), (side * px, side * px), angle))
        cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], (20, 20, 20), lineType=cv2.LINE_AA, shift=4)
        edges.append({"centre_mm": [cx_mm, cy_mm], "side_mm": side, "angle_deg": angle})
    layout["elements"].append({"type": "slanted_squares", "squares": edges})
    # Grey steps and colour patches, bottom right.
    gx0 = margin + side * 8.6
    patch = (page_w - gx0 - margin) / 12
    steps = []
    for k in range(12):
        value = int(round(240 * k / 11))
        x, y, w, h = rect(gx0 + k * patch, row_y, patch, patch)
        img[y:y + h, x:x + w] = value
        steps.append({"rect_mm": [gx0 + k * patch, row_y, patch, patch], "value": value})
    layout["elements"].append({"type": "grey_steps", "patches": steps})
    colours = []
    for k, c in enumerate(COLOURS):
        x, y, w, h = rect(gx0 + k * patch, row_y + 1.2 * patch, patch, patch)
        img[y:y + h, x:x + w] = c
        colours.append({"rect_mm": [gx0 + k * patch, row_y + 1.2 * patch, patch, patch], "srgb": list(c)})
    layout["elements"].append({"type": "colour_patches", "patches": colours})
    return img, layout


def write_chart(path, size: str = "a4", dpi: int = 300) -> tuple[Path, Path]:
    """Write the chart (``.pdf`` or ``.png``) and its layout ``<name>.json`` beside it."""
    path = Path(path)
    img, layout = make_chart(size, dpi)
    if path.suffix.lower() == ".pdf":
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        w_in, h_in = (v / 25.4 for v in layout["page_mm"])
        fig = plt.figure(figsize=(w_in, h_in), dpi=dpi)
        fig.figimage(img, resize=False)
        buf = io.BytesIO()
        fig.savefig(buf, format="pdf", dpi=dpi)
        plt.close(fig)
        atomic_write_bytes(path, buf.getvalue())
    elif path.suffix.lower() == ".png":
        write_png(path, img)
    else:
        raise LowcamError(f"{path}: the chart is written as .pdf or .png")
    layout_path = path.with_suffix(".json")
    atomic_write_bytes(layout_path, json.dumps(layout, indent=1).encode())
    return path, layout_path
