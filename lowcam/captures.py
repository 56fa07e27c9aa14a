"""Captures and targets: reading what a real camera delivered and finding the printed targets in it.

Used by the calibrations (:mod:`lowcam.calibrate`) and the measurements (:mod:`lowcam.measure`) alike.

Contents
--------
Capture input and output:

- :func:`expand_paths`: file names and glob patterns to sorted paths (a pattern matching nothing stays as given)
- :func:`load_frames`: capture frames (PNG/JPEG) as RGB ``uint8``, every problem naming the frame
- :func:`refuse_saturated`: refuse clipped flat fields and noise stacks, naming the first clipped frame
- :data:`PATCH_COLUMNS`: the header of a patch table
- :func:`read_patches_csv`: a table of ideal (render units 0-1) and measured (DN 0-255) patch colours
- :func:`srgb_to_linear`: printed sRGB code values (0-255) to linear light (0-1), IEC 61966-2-1

Targets:

- :data:`DICTIONARY`: the ArUco dictionary of the chart's ChArUco board
- :func:`charuco_board`: the ChArUco board of the chart (:mod:`lowcam.chart`); sizes in metres
- :func:`parse_target`: ``"checkerboard:9x6:0.025"``, ``"charuco"`` or ``"colorchecker"`` to a target description
- :func:`detect_target`: the target's object points (metres) and image points (pixels) in one frame, or None
- :func:`read_chart_layout`: the chart layout JSON's board and patches, every value checked
- :func:`chart_patch_colours`: the chart's patch colours, ideal and measured, from frames of it

References
----------
- [IEC61966-2-1] IEC 61966-2-1:1999, "Multimedia systems and equipment - Colour measurement and management -
  Part 2-1: Default RGB colour space - sRGB".
"""
from __future__ import annotations

import glob
from pathlib import Path

import cv2
import numpy as np

from . import schema
from .errors import LowcamError
from .io import read_image

#: The ArUco dictionary of the chart's ChArUco board.
DICTIONARY = "DICT_5X5_100"
#: The header of a patch table (:func:`read_patches_csv`).
PATCH_COLUMNS = ["ideal_r", "ideal_g", "ideal_b", "measured_r", "measured_g", "measured_b"]


# --- captures ------------------------------------------------------------------------------------------------------

def expand_paths(patterns) -> list[Path]:
    """Each pattern's matches, sorted; a pattern that matches nothing stays as given (reading it names it)."""
    out = []
    for p in patterns:
        matches = sorted(glob.glob(str(p)))
        out.extend(Path(m) for m in matches) if matches else out.append(Path(p))
    return out


def load_frames(patterns, min_frames: int = 1, what: str = "calibration") -> tuple[list[np.ndarray], list[str]]:
    """Read capture frames (PNG/JPEG, RGB uint8); every problem names the frame."""
    paths = expand_paths(patterns)
    missing = next((p for p in paths if not p.exists()), None)
    if missing is not None:
        raise LowcamError(f"{missing}: no such file" + (", and no file matches it" if glob.has_magic(str(missing))
                                                         else ""))
    if len(paths) < min_frames:
        raise LowcamError(f"{what}: {len(paths)} frame(s) given, at least {min_frames} needed")
    frames, names = [], []
    for p in paths:
        img = read_image(p)
        if img.dtype.kind == "f":
            raise LowcamError(f"{p}: a frame of floating-point values; frames are 8- or 16-bit images as a camera "
                              "writes them")
        if img.dtype != np.uint8:
            img = np.round(img / 257.0).astype(np.uint8)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        if frames and img.shape != frames[0].shape:
            raise LowcamError(f"{p}: the frame is {img.shape[1]}x{img.shape[0]}, the first frame ({names[0]}) is "
                              f"{frames[0].shape[1]}x{frames[0].shape[0]}: mixed sizes")
        frames.append(img)
        names.append(str(p))
    return frames, names


def refuse_saturated(frames, names, fraction: float = 0.01) -> None:
    """Flat fields and noise stacks must not clip: name the first frame with over ``fraction`` pixels at 255."""
    for f, n in zip(frames, names):
        clipped = float((f >= 255).any(axis=-1).mean())
        if clipped > fraction:
            raise LowcamError(f"{n}: {100 * clipped:.1f} % of the pixels are saturated (255); lower the exposure")


def read_patches_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Patch colours: header ``ideal_r,ideal_g,ideal_b,measured_r,measured_g,measured_b`` (ideal in render units
    0-1, measured in DN 0-255), one row per patch, at least 4. Returns (ideal x 255, measured), each (N, 3)."""
    ideal, measured = PATCH_COLUMNS[:3], PATCH_COLUMNS[3:]
    table, _ = schema.read_number_csv(path, PATCH_COLUMNS, "patch table", min_rows=4,
                                      low=0.0, high={**{c: 1.0 for c in ideal}, **{c: 255.0 for c in measured}})
    return table[:, :3] * 255.0, table[:, 3:]


def srgb_to_linear(v):
    """sRGB code values (0-255) to linear light (0-1).

    >>> srgb_to_linear([0, 255]).tolist()
    [0.0, 1.0]
    """
    v = np.asarray(v, np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


# --- targets -------------------------------------------------------------------------------------------------------

def charuco_board(squares=(7, 5), square_mm: float = 30.0, marker_mm: float = 22.0):
    """The chart's ChArUco board (OpenCV ``aruco``, :data:`DICTIONARY`); sizes in metres on the board."""
    aruco = cv2.aruco
    dictionary = aruco.getPredefinedDictionary(getattr(aruco, DICTIONARY))
    return aruco.CharucoBoard(squares, square_mm / 1000.0, marker_mm / 1000.0, dictionary)


def parse_target(spec: str, where: str = ""):
    """``"checkerboard:9x6:0.025"`` (inner corners, square in metres), ``"charuco"`` (the chart's board) or
    ``"colorchecker"`` (a ColorChecker Classic, :mod:`lowcam.colour_checker`). ``where`` starts the messages (the
    file and key that gave ``spec``).

    >>> parse_target("checkerboard:9x6:0.025")
    ('checkerboard', (9, 6), 0.025)
    """
    where = where or "target"
    spec = schema.string(spec, where, "target")
    here = f"{where} {schema.shown(spec)}"
    kind, _, rest = spec.partition(":")
    if kind in ("checkerboard", "chessboard"):
        try:
            size, square = rest.split(":")
            cols, rows = (int(v) for v in size.lower().split("x"))
            square = float(square)
        except ValueError:
            raise LowcamError(f"{here}: use checkerboard:COLSxROWS:SQUARE_M, e.g. checkerboard:9x6:0.025") from None
        cols = schema.integer(cols, here, "columns", 2, 100)
        rows = schema.integer(rows, here, "rows", 2, 100)
        return ("checkerboard", (cols, rows), schema.number(square, here, "square", 1e-4, 10.0, "m"))
    if kind == "charuco":
        return ("charuco", None, None)
    if kind in ("colorchecker", "colourchecker") and not rest:
        return ("colorchecker", None, None)
    raise LowcamError(f"{here}: unknown (use checkerboard:9x6:0.025, charuco or colorchecker)")


def detect_target(image: np.ndarray, target) -> tuple[np.ndarray, np.ndarray] | None:
    """(object points (N, 3) in metres, image points (N, 2) in pixels) of the target in one frame, or None."""
    kind, size, square = target
    if kind == "colorchecker":
        raise LowcamError("colorchecker: a ColorChecker gives colours, not points (use a checkerboard or charuco "
                          "target for the lens)")
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if kind == "checkerboard":
        ok, corners = cv2.findChessboardCorners(grey, size, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            return None
        corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        obj = np.zeros((size[0] * size[1], 3))
        obj[:, :2] = np.mgrid[0:size[0], 0:size[1]].T.reshape(-1, 2) * square
        return obj, corners.reshape(-1, 2).astype(np.float64)
    board = charuco_board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(grey)
    if ids is None or len(ids) < 8:
        return None
    obj = board.getChessboardCorners()[ids.ravel()]
    return np.asarray(obj, np.float64), corners.reshape(-1, 2).astype(np.float64)


def read_chart_layout(path) -> tuple[dict, list]:
    """The chart layout JSON (written by ``lowcam chart``): its ChArUco board element (``rect_mm`` and
    ``square_mm`` checked) and its colour patches and grey steps as (rect_mm, sRGB 0-255) pairs."""
    path = Path(path)
    src = str(path)
    layout = schema.read_json(path, "chart layout")
    if not isinstance(layout, dict) or layout.get("format") != "lowcam-chart":
        raise LowcamError(f"{path}: not a lowcam chart layout (expected \"format\": \"lowcam-chart\")")
    elements = schema.array_of(layout.get("elements"), src, "elements")
    board, patches = None, {"colour_patches": [], "grey_steps": []}
    for i, element in enumerate(elements):
        where = f"{path}: elements[{i}]"
        kind = schema.string(schema.table(element, where, required=("type",))["type"], where, "type")
        if kind == "charuco":
            if board is not None:
                raise LowcamError(f"{where}: a second charuco board (the chart has one)")
            schema.table(element, where, required=("rect_mm", "square_mm"))
            board = {"rect_mm": _rect_mm(element["rect_mm"], where),
                     "square_mm": schema.number(element["square_mm"], where, "square_mm", 1.0, 1000.0, "mm")}
        elif kind in ("colour_patches", "grey_steps"):
            colour_key = "srgb" if kind == "colour_patches" else "value"
            listed = schema.table(element, where, required=("patches",))["patches"]
            for k, patch in enumerate(schema.array_of(listed, where, "patches")):
                at = f"{where}: patches[{k}]"
                schema.table(patch, at, required=("rect_mm", colour_key))
                colour = (schema.numbers(patch["srgb"], at, "srgb", 3, 0.0, 255.0) if kind == "colour_patches"
                          else [schema.number(patch["value"], at, "value", 0.0, 255.0)] * 3)
                patches[kind].append((_rect_mm(patch["rect_mm"], at), colour))
    patches = patches["colour_patches"] + patches["grey_steps"]
    if board is None:
        raise LowcamError(f"{path}: the layout has no charuco element")
    if not patches:
        raise LowcamError(f"{path}: the layout has no colour_patches or grey_steps")
    return board, patches


def _rect_mm(value, where: str) -> list[float]:
    """``[x, y, width, height]`` on the page (mm): x, y in [0, 2000], width and height in (0, 2000]."""
    x, y, w, h = schema.numbers(value, where, "rect_mm", 4, 0.0, 2000.0, "mm")
    if w <= 0 or h <= 0:
        raise LowcamError(f"{where}: 'rect_mm' must have a positive width and height, got {[x, y, w, h]}")
    return [x, y, w, h]


def chart_patch_colours(patterns, layout_path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Find the chart (its ChArUco board) in each frame and read the mean colour of every colour patch and grey
    step. Returns (ideal linear colours x 255 from the printed sRGB, measured DN averaged over frames, notes)."""
    board, patches = read_chart_layout(layout_path)
    frames, names = load_frames(patterns, 1, "colour calibration")
    spec = parse_target("charuco")
    sums, count, notes = np.zeros((len(patches), 3)), 0, []
    for f, n in zip(frames, names):
        found = detect_target(f, spec)
        if found is None:
            notes.append(f"{n}: the chart's ChArUco board not found, frame skipped")
            continue
        obj, img = found
        # board metres (origin at the board's outer top-left corner, y down) -> page millimetres
        x0, y0 = board["rect_mm"][:2]
        scale = board["square_mm"] / (1000.0 * charuco_board().getSquareLength())
        mm = obj[:, :2] * 1000.0 * scale + [x0, y0]
        h, _ = cv2.findHomography(mm.astype(np.float32), img.astype(np.float32))
        for k, (rect, _) in enumerate(patches):
            x, y, w, hh = rect
            inner = np.array([[x + 0.3 * w, y + 0.3 * hh], [x + 0.7 * w, y + 0.3 * hh], [x + 0.7 * w, y + 0.7 * hh],
                              [x + 0.3 * w, y + 0.7 * hh]], np.float32)
            poly = cv2.perspectiveTransform(inner[None], h)[0]
            mask = np.zeros(f.shape[:2], np.uint8)
            cv2.fillConvexPoly(mask, np.round(poly).astype(np.int32), 1)
            if mask.sum() < 4:
                raise LowcamError(f"{n}: the chart's patches are too small in the frame (move closer)")
            sums[k] += f[mask > 0].reshape(-1, 3).mean(axis=0)
        count += 1
    if count == 0:
        shown = " ".join(names[:3]) + (f" ... ({len(names)} frames)" if len(names) > 3 else "")
        raise LowcamError(f"{shown}: the chart's ChArUco board was found in none of the frames (colour calibration)")
    ideal = srgb_to_linear([c for _, c in patches]) * 255.0
    return ideal, sums / count, notes
