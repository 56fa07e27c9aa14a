"""Profile against footage without a chart: the plate probes' statistics, model against footage.

``lowcam compare --plate-only FOOTAGE --profile P`` has no ideal view of the footage's scene, so it cannot compare
pixels as :func:`lowcam.measure.compare.compare` does. It compares the no-reference statistics of the plate probes
(:func:`lowcam.measure.plate.plate_probes`: noise level function, edge profile, radial fall-off, JPEG blockiness,
chroma bandwidth, ...) measured on the footage with the same statistics measured on the profile filming similar
content.

Similar content
---------------
The footage's own frames: their temporal median (:func:`lowcam.measure.plate.similar_content`, which removes the
noise) at the profile's render size (``1 / DOWNSCALE`` of it, scaled back up, when ``DOWNSCALE > 1``), as an opaque
ideal render through :mod:`lowcam.pipeline` at the profile's resolution. The scene (its colours, its texture,
where it is bright) is the footage's, so the statistics' dependence on the scene cancels between the two; the
bundled sample photo would not cancel it. Halving first (``DOWNSCALE = 2``) was tried: it softens the scene
further and left the true profile at an error of about 2.0 against 1.7 without it (before the bias correction
below), so the median is used as it is.

The error
---------
The model films content the footage's camera has already softened, coded and subsampled, so its statistics carry
that camera's effects twice. A parametric-bootstrap bias correction takes this out: the profile also films its
own frames (a third application), and the model's value of a statistic is ``2 s(model) - s(model of the
model)``, the linear extrapolation from two and three applications back to one. On the engine's own footage
(Fire-i plus JPEG, three scenes, two codec settings, codec probes) the true profile's error is 0.7-1.9 (about 2
without the correction), a quality 10 off gives 2.6-4.8 and no JPEG 13-28: what is left is the extrapolation's
own error, so read errors below about 2 as explained by this method even where the verdict says otherwise.
(Estimating that floor by comparing the model's own frames with the profile was tried: it did not track the
true profile's error.)

Temporal statistics (the noise level function: a probe with ``pairs``) compare frame pairs registered once for
the whole frame (:func:`lowcam.plate_estimate.register_footage`: consecutive footage frames, the model's frames)
and then cut into tiles, so that a panning camera's footage is measured like the model's still frames; only a
probe's ``compared`` values are compared (the noise's sigma at 64, 128 and 192 DN, not its per-bin lists), and a
value a tile did not measure (a level it lacks) is left out, never made up. A JPEG-coded pan still reads its
codec's changing coding error as noise (:data:`lowcam.effects.noise.CODEC_FLICKER`), which the model's still
frames do not show.

Both stacks are cut into the same :data:`TILES` grid (by relative position, so each tile holds the same part of
the scene in both). Every numeric value ``s`` of every probe's statistic is measured per tile on the footage and
on the (bias-corrected) model; the paired difference ``d_t = s_footage(t) - s_model(t)`` has its mean over tiles
and that mean's
standard error from :data:`BOOTSTRAP` bootstrap resamplings of the tiles. The statistic's error is
``|mean d| / se`` (1.0: as large as the scene's tile-to-tile spread alone would make it), a probe's error the root
mean square over its values, and the overall error the root mean square over the probes (each probe weighs the
same, however many values its statistic has, as ``compare``'s families do): 1.0 is the noise floor,
``explained`` up to :data:`lowcam.measure.compare.EXPLAINED_BELOW`, as for ``compare``. ``where`` ranks the
probes (and their effects) by error, the largest first.

Contents
--------
- :data:`DOWNSCALE`: the similar content is the footage's median at ``1 / DOWNSCALE`` of the render size, scaled up
- :data:`TILES`: (rows, columns) of the tile grid the uncertainty comes from
- :data:`BOOTSTRAP`: bootstrap resamplings of the tiles
- :class:`PlateStatistic`: one value of one probe's statistic: footage, model, uncertainty, error
- :class:`PlateComparison`: the error, per probe, per value; ``where`` and ``verdict``
- :func:`flatten_statistic`: a probe's statistic dict as ``{dotted.name: number}``
- :func:`model_frames`: the profile's frames of similar content (T, H, W, 3) float32 DN
- :func:`tile_slices`: the tile grid of a frame size, each tile's corner on the 16 px grid
- :func:`compare_plate`: compare a profile with footage through the plate probes' statistics
- :func:`write_plate_report`: the HTML report of a :class:`PlateComparison`
"""
from __future__ import annotations

import html
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..errors import LowcamError
from ..outputs import make_output_folder
from ..pipeline import prepare, render_camera, resume_sequence
from ..plate_estimate import register_footage
from ..registration import register_frames
from ..reports import figure, image, numbers_block, write_page
from .compare import EXPLAINED_BELOW
from .plate import Footage, plate_probes, similar_content

DOWNSCALE = 1
TILES = (3, 4)
BOOTSTRAP = 400


@dataclass
class PlateStatistic:
    """One value of one probe's statistic: the means over tiles of the footage and of the model, the bootstrap
    standard error of their paired difference, and the error ``|footage - model| / uncertainty``."""

    name: str
    probe: str
    effect: str
    footage: float
    model: float
    uncertainty: float
    error: float

    def as_dict(self) -> dict:
        return {"statistic": self.name, "probe": self.probe, "effect": self.effect, "footage": self.footage,
                "model": self.model, "uncertainty": self.uncertainty, "error": self.error}


@dataclass
class PlateComparison:
    """``error``: root mean square of the probes' errors (1.0: the noise floor); ``statistics``: the
    :class:`PlateStatistic` list; ``skipped``: probe -> why it measured nothing."""

    error: float
    statistics: list
    skipped: dict = field(default_factory=dict)
    noise_floor: float = 1.0

    @property
    def families(self) -> dict:
        """Probe -> its error (root mean square over its values), as ``compare``'s families."""
        out: dict = {}
        for s in self.statistics:
            out.setdefault(s.probe, []).append(s.error ** 2)
        return {k: float(np.sqrt(np.mean(v))) for k, v in out.items()}

    @property
    def where(self) -> dict:
        """The probes by error, largest first (with their effect and worst value), and the worst of them."""
        rows = []
        for probe, err in sorted(self.families.items(), key=lambda kv: -kv[1]):
            mine = [s for s in self.statistics if s.probe == probe]
            worst = max(mine, key=lambda s: s.error)
            rows.append({"probe": probe, "effect": worst.effect, "error": err, "worst_statistic": worst.name,
                         "footage": worst.footage, "model": worst.model})
        return {"probes": rows, "worst": rows[0] if rows else None}

    def error_of_probes(self) -> float:
        """The root mean square of the probes' errors (:attr:`families`)."""
        return float(np.sqrt(np.mean([e ** 2 for e in self.families.values()])))

    @property
    def verdict(self) -> str:
        return "explained" if self.error <= EXPLAINED_BELOW * self.noise_floor else "not explained"


def flatten_statistic(stat, prefix: str = "") -> dict:
    """A probe's statistic (nested dicts and lists of numbers) as ``{dotted.name: float}``; strings, None and
    non-finite numbers are left out."""
    out = {}
    if isinstance(stat, dict):
        for k, v in stat.items():
            out.update(flatten_statistic(v, f"{prefix}{k}."))
    elif isinstance(stat, (list, tuple, np.ndarray)):
        for i, v in enumerate(stat):
            out.update(flatten_statistic(v, f"{prefix}{i}."))
    elif isinstance(stat, (int, float, np.integer, np.floating)) and not isinstance(stat, bool):
        if np.isfinite(stat):
            out[prefix[:-1]] = float(stat)
    return out


def model_frames(footage, profile, frames: int = 4, seed: int = 0, downscale: int = DOWNSCALE) -> np.ndarray:
    """``frames`` frames (T, H, W, 3) float32 DN of ``profile`` filming similar content (module docstring): the
    footage's median at ``1 / downscale`` of the render size (scaled back up, bilinear, when ``downscale > 1``)
    as an opaque ideal; a still camera; noise frames ``0..frames-1`` of ``seed``. The noise-free front of the
    chain runs once."""
    cam = render_camera(profile, profile.camera.width)
    w, h = int(cam["width"]), int(cam["height"])
    small = similar_content(footage, max(16, w // downscale), max(16, h // downscale))
    ideal = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    token = prepare(ideal, profile)
    return resume_sequence(token, seed, frames, profile).astype(np.float32)


def tile_slices(height: int, width: int, tiles: tuple[int, int] = TILES) -> list[tuple[slice, slice]]:
    """The (rows x columns) tile grid of a ``height`` x ``width`` frame; tile corners on the 16 px grid (so a
    tile keeps the frame's 8x8 JPEG grid and chroma phase), by relative position."""
    rows = [int(round(height * i / tiles[0] / 16)) * 16 for i in range(tiles[0] + 1)]
    cols = [int(round(width * j / tiles[1] / 16)) * 16 for j in range(tiles[1] + 1)]
    rows[-1], cols[-1] = height, width
    return [(slice(rows[i], rows[i + 1]), slice(cols[j], cols[j + 1]))
            for i in range(tiles[0]) for j in range(tiles[1])]


def _tile_values(probe, stack, tiles) -> list[dict]:
    """Each tile's statistic, flattened, only its ``probe.compared`` keys (all where empty)."""
    out = []
    for sy, sx in tiles:
        try:
            stat = probe.statistic(stack[:, sy, sx])
        except (ValueError, ArithmeticError, np.linalg.LinAlgError, LowcamError, NotImplementedError):
            stat = {}  # this tile cannot show the statistic (too flat, too small)
        if probe.compared:
            stat = {k: v for k, v in stat.items() if k in probe.compared}
        out.append(flatten_statistic(stat))
    return out


def _paired(probe, feet, tf, model, again, tg, rng) -> list[PlateStatistic]:
    """One probe's values, footage ``feet`` (tiles ``tf``) against the model (tiles ``tg``), bias-corrected with
    ``again`` (the model filming its own frames) when given."""
    vf, vg = _tile_values(probe, feet, tf), _tile_values(probe, model, tg)
    if again is not None:  # 2 s(model) - s(model of the model), per tile
        v2 = _tile_values(probe, again, tg)
        vg = [{k: 2 * a[k] - b[k] for k in a if k in b} for a, b in zip(vg, v2)]
    out = []
    for name in sorted(set().union(*vf) & set().union(*vg)):
        pairs = [(a[name], b[name]) for a, b in zip(vf, vg) if name in a and name in b]
        if len(pairs) < max(4, len(tf) // 2):
            continue
        p = np.asarray(pairs)
        d = p[:, 0] - p[:, 1]
        boot = d[rng.integers(0, len(d), (BOOTSTRAP, len(d)))].mean(axis=1)
        se = float(max(boot.std(ddof=1), 1e-9 * max(1.0, float(np.abs(p).mean()))))
        out.append(PlateStatistic(name, probe.name, probe.effect, float(p[:, 0].mean()), float(p[:, 1].mean()),
                                  se, float(abs(d.mean()) / se)))
    return out


def compare_plate(footage, profile, probes=None, frames: int = 4, max_footage_frames: int = 8,
                  tiles: tuple[int, int] = TILES, seed: int = 0, progress: bool = True,
                  bias_correction: bool = True) -> PlateComparison:
    """Compare ``profile`` with ``footage`` (:class:`lowcam.measure.plate.Footage`) through the statistics of
    ``probes`` (default :func:`lowcam.measure.plate.plate_probes`); see the module docstring for the error.
    ``frames`` model frames are simulated (twice as many with ``bias_correction``, the model filming its own
    frames, module docstring); up to ``max_footage_frames`` footage frames (evenly thinned) are measured. A probe
    whose statistic is empty on both is listed in ``skipped``."""
    probes = plate_probes() if probes is None else probes
    if progress:
        print(f"simulating {frames} frames of {profile.name} filming similar content ...", file=sys.stderr,
              flush=True)
    model = model_frames(footage, profile, frames, seed)
    again = model_frames(Footage(model, footage.fps, f"{footage.path} (model)"), profile, frames, seed + 1) \
        if bias_correction else None
    feet = footage.stack(max_frames=max_footage_frames)
    tf, tg = tile_slices(*feet.shape[1:3], tiles), tile_slices(*model.shape[1:3], tiles)
    rng = np.random.default_rng(seed)
    stats, skipped, registered = [], {}, None
    for i, probe in enumerate(probes):
        if progress:
            print(f"[{i + 1}/{len(probes)}] {probe.name}", file=sys.stderr, flush=True)
        if probe.pairs:  # registered once, cut into tiles after
            if registered is None:
                registered = (register_footage(footage, max_footage_frames - 1), register_frames(model),
                              None if again is None else register_frames(again))
            mine = _paired(probe, registered[0], tf, registered[1], registered[2], tg, rng)
        else:
            mine = _paired(probe, feet, tf, model, again, tg, rng)
        if not mine:
            skipped[probe.name] = "not measurable on enough tiles of both the footage and the model"
            continue
        stats += mine
    if not stats:
        raise LowcamError(f"{footage.path}: no plate statistic could be measured on both the footage and the model "
                          "(frames too small or too flat)")
    out = PlateComparison(0.0, stats, skipped)
    out.error = out.error_of_probes()
    return out


def write_plate_report(cmp: PlateComparison, folder, title: str) -> "Path":
    """The HTML report of a :class:`PlateComparison`: each probe's error as a bar chart, the values footage
    against model with their uncertainty, and the numbers."""
    folder = make_output_folder(folder)
    fam = cmp.families

    def bars(f):
        ax = f.add_subplot(1, 1, 1)
        names = list(fam)
        ax.barh(range(len(names)), [fam[n] for n in names], color="tab:red")
        ax.axvline(1.0, color="k", lw=0.8, label="noise floor")
        ax.axvline(EXPLAINED_BELOW, color="grey", lw=0.8, ls="--", label="explained")
        ax.set_yticks(range(len(names)), names, fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("error (1 = the scene's tile-to-tile spread)")
        ax.legend(fontsize=7)

    worst = sorted(cmp.statistics, key=lambda s: -s.error)[:12]

    def values(f):
        ax = f.add_subplot(1, 1, 1)
        y = np.arange(len(worst))
        ax.errorbar([s.footage - s.model for s in worst], y, xerr=[2 * s.uncertainty for s in worst], fmt="o")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yticks(y, [f"{s.probe}: {s.name}" for s in worst], fontsize=7)
        ax.set_xlabel("footage - model (bars: 2 uncertainties)")

    pages = [("Error per probe", figure(folder / "plate_probes.png", bars, (7, 3.5))),
             ("The worst values, footage against model", figure(folder / "plate_values.png", values, (7, 4.5)))]
    where = cmp.where["worst"]
    parts = [f"<p><b>error {cmp.error:.3f}</b> (1.0 = the noise floor; explained below {EXPLAINED_BELOW}): "
             f"{html.escape(cmp.verdict)}." + (f" Where: {html.escape(where['probe'])} "
                                               f"({html.escape(where['effect'])}), error {where['error']:.2f}."
                                               if where else "") + "</p>"]
    for name, path in pages:
        parts.append(f"<h2>{html.escape(name)}</h2>{image(folder, path, name)}")
    parts.append("<h2>Numbers</h2>" + numbers_block({"error": cmp.error, "verdict": cmp.verdict,
                                                     "families": fam, "where": cmp.where, "skipped": cmp.skipped,
                                                     "statistics": [s.as_dict() for s in cmp.statistics]}))
    return write_page(folder, "Lowcam plate comparison", title, parts)
