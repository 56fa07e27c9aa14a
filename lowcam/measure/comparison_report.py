"""Pictures of a comparison: residual maps, where the error lives, probes per effect, the error history.

Measured-versus-model probes are drawn for each physical effect; the error history is kept per measurement set.

Contents
--------
- :func:`masked_shares`: per capture, the share of pixels masked and of the residual energy they hold
- :func:`probe_figures`: every probe as (title, PNG path)
- :func:`history_path`: where a set keeps its comparison history
- :func:`read_history`: the set's comparison history; a damaged file is a one-line error
- :func:`record_history`: append this comparison to the set's history (``<set>/.lowcam/history.json``)
- :func:`history_figure`: the error against model versions, as a PNG
- :func:`candidate_sections`: a diagnosis's candidates: errors in sample and held out, fitted numbers with their
  standard errors, flags, and why the others could not be fitted
- :func:`write_compare_report`: the HTML comparison report
"""
from __future__ import annotations

import html
import json
import time
from pathlib import Path

import cv2
import numpy as np

from ..effects.bayer import block_correlations
from ..effects.blur import edge_sigma, find_edges
from ..effects.chromatic_aberration import channel_shifts
from ..effects.fixed_pattern import row_noise_variance
from ..effects.yuv import rgb_to_yuv
from ..errors import LowcamError
from ..outputs import atomic_write_bytes, make_output_folder
from ..reports import figure, image, numbers_block, write_page


def _rgb2yuv(x):
    return rgb_to_yuv(np.asarray(x, np.float32))


def _pick(stats, key):
    """The capture with the most of something: texture ('texture'), flatness ('flat'), motion (None)."""
    scores = [float(s.measured.mean(0).std()) for s in stats]
    return stats[int(np.argmax(scores) if key == "texture" else np.argmin(scores))]


def _full_noise(stats) -> np.ndarray:
    """(H, W, 3): the noise variance of the difference of the means at every pixel, masked ones included (the
    comparison's own noise map is 0 where it does not compare): the measured frames' per-pixel variance (or the
    one assumed for them) x (1 / frames + 1 / simulated frames)."""
    return stats.sums["variance_map"] * (1 / len(stats.measured) + 1 / len(stats.simulated))


def _residual_energy(stats) -> tuple[float, float]:
    """(in the masked pixels, in all): the sum of |residual|^2 / noise of one capture."""
    energy = (stats.residual ** 2 / _full_noise(stats)).sum(-1)
    mask = stats.sums.get("mask")
    return (0.0 if mask is None else float(energy[~mask].sum())), float(energy.sum())


def masked_shares(cmp) -> dict:
    """Per capture with pixels left out of the comparison: their share (``pixels``) and the share of its residual
    energy they hold (``residual``: the sum of |residual|^2 / noise over the masked pixels, over all its pixels)."""
    out = {}
    for s in cmp.captures:
        if s.sums.get("mask") is not None and not s.sums["mask"].all():
            masked, total = _residual_energy(s)
            out[s.name] = {"pixels": float((~s.sums["mask"]).mean()), "residual": masked / max(total, 1e-12)}
    return out


def _square_grid_columns(count: int, cell_aspect: float) -> int:
    """The columns of a grid of ``count`` cells (each ``cell_aspect`` wide to high) that make it most nearly
    square: the Match panel shows a picture in a square box, the report at the page's width."""
    return min(range(1, count + 1), key=lambda c: abs(np.log(c * cell_aspect / -(-count // c))))


def probe_figures(cmp, folder: Path) -> list[tuple[str, Path]]:
    """Every probe as (title, PNG path)."""
    stats = cmp.captures
    out = []

    def fig(name, title, draw, size=(7, 4)):
        out.append((title, figure(folder / f"{name}.png", draw, size)))

    # residual maps, in units of the noise of the means, one panel per capture; masked regions tinted
    shares = masked_shares(cmp)
    cols = _square_grid_columns(len(stats), 4.2 / 3.2)
    rows = -(-len(stats) // cols)

    def residual_maps(f):
        maps = [np.sqrt((s.residual ** 2).sum(-1) / _full_noise(s).sum(-1)) for s in stats]
        top = max(3.0, float(np.percentile(np.concatenate([z.ravel() for z in maps]), 99)))
        for k, (s, z) in enumerate(zip(stats, maps)):
            ax = f.add_subplot(rows, cols, k + 1)
            im = ax.imshow(z, cmap="magma", vmin=0, vmax=top)
            title = s.name
            mask = s.sums.get("mask")
            if mask is not None and not mask.all():
                tint = np.zeros(mask.shape + (4,), np.float32)
                tint[~mask] = (0.0, 0.9, 1.0, 0.45)
                ax.imshow(tint)
                ax.contour(~mask, [0.5], colors="cyan", linewidths=0.6)
                share = shares[s.name]
                title += f": masked {share['pixels']:.1%} of pixels, {share['residual']:.0%} of residual"
            ax.set_title(title, fontsize=10)
            ax.axis("off")
            f.colorbar(im, ax=ax, fraction=0.035, pad=0.02).ax.tick_params(labelsize=9)
    fig("residual_maps", "Residual maps (|residual| / noise; masked regions tinted, not compared)", residual_maps,
        (4.2 * cols, 3.2 * rows))

    w = cmp.where

    def where_bars(f):
        for k, (key, label) in enumerate((("channels", "channel"), ("regions", "region"), ("bands", "band"),
                                          ("intensities", "range_dn"))):
            ax = f.add_subplot(1, 4, k + 1)
            names = [str(e[label]) if label != "range_dn" else f"{e[label][0]:.0f}-{e[label][1]:.0f}" for e in w[key]]
            ax.barh(names, [e["error"] for e in w[key]], color="tab:blue")
            ax.axvline(1.0, color="k", lw=0.8)
            ax.set_title(f"error by {label}", fontsize=9)
            ax.tick_params(labelsize=7)
    fig("where", "Per channel, region, band and intensity", where_bars, (14, 4))

    def spectra(f):
        for k, axis in enumerate((1, 0)):
            ax = f.add_subplot(1, 2, k + 1)
            p = np.zeros(0)
            for s in stats:
                r = s.residual.mean(-1)
                spec = (np.abs(np.fft.rfft(r, axis=axis)) ** 2).mean(axis=1 - axis)
                p = spec if p.size == 0 else p + spec
            freq = np.fft.rfftfreq(stats[0].residual.shape[axis])
            ax.semilogy(freq[1:], p[1:] / len(stats))
            ax.set_xlabel("cycles / pixel")
            ax.set_title(["horizontal", "vertical"][k] + " residual power", fontsize=9)
    fig("spectrum", "Residual power spectrum", spectra, (10, 3.5))

    flat = _pick(stats, "flat")

    def falloff(f):
        ax = f.add_subplot(1, 1, 1)
        h, wd = flat.residual.shape[:2]
        yy, xx = np.mgrid[0:h, 0:wd]
        rad = np.hypot(xx - wd / 2, yy - h / 2) / np.hypot(wd / 2, h / 2)
        bins = np.clip((rad * 20).astype(int), 0, 19)
        for data, label in ((flat.measured, "measured"), (flat.simulated, "model")):
            m = data.astype(np.float64).mean(0).mean(-1)
            prof = np.bincount(bins.ravel(), m.ravel(), 20) / np.maximum(np.bincount(bins.ravel(), minlength=20), 1)
            ax.plot((np.arange(20) + 0.5) / 20, prof / max(prof[0], 1e-6), "o-", label=label)
        ax.set_xlabel("radius / corner radius")
        ax.set_ylabel("brightness / centre")
        ax.set_title(f"radial fall-off ({flat.name})", fontsize=9)
        ax.legend()
    fig("probe_vignetting", "Radial brightness fall-off", falloff)

    tex = _pick(stats, "texture")

    def lateral(f):
        ax = f.add_subplot(1, 1, 1)
        for data, label, mk in ((tex.measured, "measured", "o"), (tex.simulated, "model", "x")):
            img = data.astype(np.float32).mean(0)
            h, wd = img.shape[:2]
            cx, cy = np.meshgrid(np.linspace(40, wd - 40, 8), np.linspace(40, h - 40, 6))
            red = channel_shifts(img, cx, cy)[..., :2]
            ok = np.isfinite(red[..., 0])
            ax.plot(np.hypot(cx - wd / 2, cy - h / 2)[ok], np.hypot(red[..., 0], red[..., 1])[ok], mk,
                    label=f"{label}: red vs green")
        ax.set_xlabel("radius (px)")
        ax.set_ylabel("shift (px)")
        ax.set_title(f"lateral colour shift ({tex.name})", fontsize=9)
        ax.legend()
    fig("probe_chromatic_aberration", "Lateral colour shift against radius", lateral)

    def edges(f):
        ax = f.add_subplot(1, 1, 1)
        for data, label, off in ((tex.measured, "measured", -0.2), (tex.simulated, "model", 0.2)):
            grey = data.astype(np.float64).mean(0).mean(-1)
            found = {"vertical": [], "horizontal": []}
            for x0, y0, x1, y1, o in find_edges(grey):
                try:
                    found[o].append(edge_sigma(grey, x0, y0, x1, y1)[0])
                except (RuntimeError, ValueError, ZeroDivisionError):
                    pass
            shown = [(k, o) for k, o in enumerate(("vertical", "horizontal")) if found[o]]
            for k, o in shown:  # the label on the first bar shown (the vertical edges may have none)
                ax.bar(k + off, np.median(found[o]), 0.4, label=label if (k, o) == shown[0] else None,
                       color="tab:orange" if label == "model" else "tab:blue")
        ax.set_xticks([0, 1], ["across vertical edges (x)", "across horizontal edges (y)"])
        ax.set_ylabel("edge-spread sigma (px)")
        ax.set_title("edge spread by direction", fontsize=9)
        if ax.get_legend_handles_labels()[1]:
            ax.legend()
    fig("probe_edges", "Edge spread by direction", edges)

    def noise_mean(f):
        for c, channel in enumerate(("red", "green", "blue")):
            ax = f.add_subplot(1, 3, c + 1)
            for key, label in (("measured", "measured"), ("simulated", "model")):
                mu, sd = [], []
                for s in stats:
                    d = getattr(s, key).astype(np.float32)
                    mu.append(d.mean(0)[..., c].ravel())
                    sd.append(d.std(0, ddof=1)[..., c].ravel())
                mu, sd = np.concatenate(mu), np.concatenate(sd)
                bins = np.clip((mu / 16).astype(int), 0, 15)
                cnt = np.bincount(bins, minlength=16)
                ok = cnt > 50
                m = np.bincount(bins, sd ** 2, 16)[ok] / cnt[ok]
                ax.plot((np.arange(16)[ok] + 0.5) * 16, np.sqrt(m), "o-", label=label)
            ax.set_title(channel, fontsize=9)
            ax.set_xlabel("mean (DN)")
            ax.legend(fontsize=7)
        f.axes[0].set_ylabel("sigma (DN)")
    fig("probe_noise", "Noise against mean, per channel", noise_mean, (11, 3.5))

    def covariance(f):
        for k, (key, label) in enumerate((("measured", "measured"), ("simulated", "model"))):
            ax = f.add_subplot(1, 2, k + 1)
            ax.imshow(block_correlations(getattr(flat, key), 0), vmin=-1, vmax=1, cmap="RdBu_r")
            ax.set_title(f"{label}: red noise correlation, 4x4 block", fontsize=9)
    fig("probe_covariance", "Noise covariance in 4x4 blocks", covariance, (8, 4))

    def tone(f):
        ax = f.add_subplot(1, 1, 1)
        m = np.concatenate([s.measured.astype(np.float32).mean(0).ravel() for s in stats])
        s_ = np.concatenate([s.simulated.astype(np.float32).mean(0).ravel() for s in stats])
        bins = np.clip(s_.astype(int) // 8, 0, 31)
        cnt = np.bincount(bins, minlength=32)
        ok = cnt > 20
        ax.plot((np.arange(32)[ok] + 0.5) * 8, np.bincount(bins, m, 32)[ok] / cnt[ok], "o-", label="measured")
        ax.plot([0, 255], [0, 255], "k--", lw=0.8, label="model")
        ax.set_xlabel("model (DN)")
        ax.set_ylabel("measured (DN)")
        ax.set_title("tone curve", fontsize=9)
        ax.legend()
    fig("probe_tone", "Tone curve", tone, (5, 4.5))

    def chroma(f):
        ax = f.add_subplot(1, 1, 1)
        for key, label in (("measured", "measured"), ("simulated", "model")):
            yuv = _rgb2yuv(getattr(tex, key).astype(np.float32).mean(0))
            spec = (np.abs(np.fft.rfft(yuv[..., 1], axis=1)) ** 2).mean(0)
            ax.semilogy(np.fft.rfftfreq(yuv.shape[1])[1:], spec[1:], label=label)
        ax.set_xlabel("cycles / pixel (horizontal)")
        ax.set_title("chroma (U) bandwidth", fontsize=9)
        ax.legend()
    fig("probe_chroma", "Chroma bandwidth", chroma)

    def levels(f):
        ax = f.add_subplot(1, 1, 1)
        for key, label in (("measured", "measured"), ("simulated", "model")):
            hist = np.bincount(getattr(tex, key)[..., 1].ravel(), minlength=256)
            ax.plot(hist, label=f"{label} ({int((hist > 0).sum())} levels)")
        ax.set_xlabel("green value (DN)")
        ax.set_title("quantisation levels", fontsize=9)
        ax.legend()
    fig("probe_levels", "Quantisation levels", levels)

    def fixed(f):
        ax = f.add_subplot(1, 1, 1)
        names = [s.name for s in stats]
        hp = []
        for s in stats:
            r = s.residual.astype(np.float32)
            hp.append(float(np.sqrt(((r - cv2.GaussianBlur(r, (0, 0), 3)) ** 2).mean() / s.sums["noise_map"].mean())))
        ax.barh(names, hp)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xlabel("high-pass residual of the means / noise")
        ax.set_title("fixed pattern over frames", fontsize=9)
    fig("probe_fixed_pattern", "Fixed pattern over frames", fixed)

    def rows(f):
        ax = f.add_subplot(1, 1, 1)
        for key, label in (("measured", "measured"), ("simulated", "model")):
            vals = [np.sqrt(row_noise_variance(getattr(s, key))) for s in stats]
            ax.bar(np.arange(3) + (-0.2 if label == "measured" else 0.2), np.mean(vals, 0), 0.4, label=label)
        ax.set_xticks(range(3), ["red", "green", "blue"])
        ax.set_ylabel("std of row means of the noise (DN)")
        ax.set_title("row statistics", fontsize=9)
        ax.legend()
    fig("probe_rows", "Row statistics", rows)
    return out


def history_path(mset_path) -> Path:
    return Path(mset_path) / ".lowcam" / "history.json"


def read_history(mset_path) -> list[dict]:
    """The set's comparison history (``<set>/.lowcam/history.json``); a damaged file is a one-line error."""
    path = history_path(mset_path)
    try:
        entries = json.loads(path.read_text()) if path.is_file() else []
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise LowcamError(f"{path}: the comparison history is not valid JSON ({e}); move it away to start "
                          "afresh") from None
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise LowcamError(f"{path}: the comparison history is not a list of entries; move it away to start afresh")
    return entries


def record_history(mset_path, profile_name: str, cmp) -> list[dict]:
    """Append this comparison to the set's history (``<set>/.lowcam/history.json``) and return it."""
    path = history_path(mset_path)
    entries = read_history(mset_path)
    entries.append({"time": time.strftime("%Y-%m-%d %H:%M:%S"), "profile": profile_name,
                    "error": round(cmp.error, 4), "families": {k: round(v, 4) for k, v in cmp.families.items()}})
    atomic_write_bytes(path, json.dumps(entries, indent=1).encode())
    return entries


def history_figure(entries, folder: Path) -> Path:
    def draw(f):
        ax = f.add_subplot(1, 1, 1)
        ax.plot(range(len(entries)), [e["error"] for e in entries], "o-", lw=2, ms=8)
        ax.axhline(1.0, color="k", lw=1, label="noise floor")
        ax.axhline(1.1, color="grey", lw=1, ls="--", label="explained")
        ax.set_xticks(range(len(entries)), [Path(e["profile"]).stem for e in entries], rotation=30, ha="right",
                      fontsize=12)
        ax.tick_params(axis="y", labelsize=12)
        ax.set_ylabel("error (1 = noise)", fontsize=13)
        ax.set_title("error against model version", fontsize=14)
        ax.legend(fontsize=12)
    return figure(folder / "history.png", draw, (6, 5))   # near square, large type: also the Match panel's


def _with_uncertainty(params: dict, uncertainty: dict) -> str:
    """``key value +- standard error`` for each fitted number (vectors and matrices by their entries)."""
    def shown(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(shown(x) for x in v) + "]"
        return str(v)

    return "; ".join(f"{k} {shown(v)}" + (f" &plusmn; {uncertainty[k]:.2g}" if k in uncertainty else "")
                     for k, v in params.items() if not (isinstance(v, str) and v.endswith(".npy")))


def candidate_sections(candidates: list[dict], not_fitted: list[dict], folder: Path,
                       title: str = "Candidates", error: float | None = None) -> list[str]:
    """HTML sections for a diagnosis (``Diagnosis.as_json()``'s ``candidates`` and ``not_fitted``): a figure of
    each candidate's error in sample beside its error on held-out captures (and the profile's own ``error``), a table with its fitted numbers and
    their standard errors, flags and evidence, and why each other candidate could not be fitted."""
    if not candidates and not not_fitted:
        return []
    parts = [f"<h2>{html.escape(title)}</h2>"]
    if candidates:
        def bars(f):
            ax = f.add_subplot(1, 1, 1)
            names = [c["effect"] for c in candidates][::-1]
            y = np.arange(len(names))
            ax.barh(y + 0.2, [c["error_in_sample"] for c in candidates][::-1], 0.4, label="in sample",
                    color="tab:grey")
            ax.barh(y - 0.2, [c["error_held_out"] if c["error_held_out"] is not None else np.nan
                              for c in candidates][::-1], 0.4, label="held out", color="tab:blue")
            ax.set_yticks(y, names, fontsize=7)
            ax.axvline(1.0, color="k", lw=0.8)
            ax.axvline(1.25, color="grey", lw=0.8, ls="--")
            if error is not None:
                ax.axvline(error, color="tab:red", lw=1.0, label="the profile's own error")
            ax.set_xlabel("error (1 = noise)")
            ax.legend(fontsize=8)
        path = figure(folder / "candidates.png", bars, (8, 1.5 + 0.25 * len(candidates)))
        parts.append(image(folder, path, "errors in sample and held out"))
        rows = "".join(
            f"<tr><td>{html.escape(c['effect'])}</td><td>{c['error_in_sample']:.3f}</td><td>"
            + ("&ndash;" if c["error_held_out"] is None else f"{c['error_held_out']:.3f}")
            + f"</td><td>{html.escape(c['held_out'])}</td><td>{_with_uncertainty(c['params'], c['uncertainty'])}"
            f"</td><td>{html.escape('; '.join(c['flags']))}</td><td>{html.escape(c['evidence'])}</td></tr>"
            for c in candidates)
        parts.append("<table border=1 cellpadding=3 style='border-collapse:collapse;font-size:small'><tr>"
                     "<th>candidate</th><th>in sample</th><th>held out</th><th>how held out</th>"
                     "<th>fitted (&plusmn; standard error)</th><th>flags</th><th>evidence</th></tr>"
                     f"{rows}</table>")
    if not_fitted:
        parts.append("<h3>Not fitted</h3><ul>" + "".join(
            f"<li><b>{html.escape(x['effect'])}</b>: {html.escape(x['reason'])}</li>" for x in not_fitted) + "</ul>")
    return parts


def write_compare_report(cmp, folder, title: str, history=None, extra: dict | None = None) -> Path:
    """The HTML comparison report: the verdict, the error history, the diagnosis's candidates (``extra``'s
    ``candidates`` and ``not_fitted``) or the steps that added effects (``extra``'s ``steps``), and every probe."""
    folder = make_output_folder(folder)
    figures = probe_figures(cmp, folder)
    if history:
        figures.insert(0, ("Error history", history_figure(history, folder)))
    texture = cmp.noise_texture
    numbers = {"error": cmp.error, "error_unmasked": cmp.error_unmasked, "noise_floor": cmp.noise_floor,
               "verdict": cmp.verdict, "families": cmp.families, "where": cmp.where, "noise_texture": texture}
    shares = masked_shares(cmp)
    if shares:
        numbers["masked"] = shares
    if extra:
        numbers.update(extra)
    parts = [f"<p><b>error {cmp.error:.3f}</b> (1.0 = the noise floor; explained below 1.1): "
             f"{html.escape(cmp.verdict)}. Families: " +
             ", ".join(f"{k} {v:.3f}" for k, v in cmp.families.items()) + "</p>"]
    if shares:
        pixels = sum(v["pixels"] for v in shares.values()) / len(cmp.captures)
        masked, total = np.sum([_residual_energy(s) for s in cmp.captures], axis=0)
        held = masked / max(total, 1e-12)
        parts.append(f"<p>Left out of the comparison (tinted on the residual maps): {pixels:.1%} of the pixels, in "
                     f"{len(shares)} of {len(cmp.captures)} captures, holding {held:.0%} of the residual energy: "
                     "where the frames show something other than the chart (it changes between frames, or its "
                     "colour is not the paper's) or the capture's own mask. <b>With those pixels compared too, the "
                     f"error is {cmp.error_unmasked:.3f}</b>.</p>")
    if texture:
        f, m = texture["measured"], texture["model"]
        parts.append(f"<p>Noise texture (the frames' against the model's): neighbours correlated "
                     f"{f['lag1_x']:.2f} / {f['lag1_y']:.2f} across / down (model {m['lag1_x']:.2f} / "
                     f"{m['lag1_y']:.2f}), {f['bands']['high']:.0%} of the noise's power in the high band (model "
                     f"{m['bands']['high']:.0%}), correlated {f['lag1_t']:.2f} from frame to frame (model "
                     f"{m['lag1_t']:.2f}). Higher correlation and less high-band power than the model's: the camera "
                     "denoises (in space or over frames) where the model does not.</p>")
    extra = extra or {}
    parts += candidate_sections(extra.get("candidates", []), extra.get("not_fitted", []), folder, error=cmp.error)
    added = [(s["step"], c) for s in extra.get("steps", []) for c in s["candidates"][:1] if s.get("added")]
    if added:
        parts += candidate_sections([c for _, c in added], [], folder, "Effects added, step by step")
    for name, path in figures:
        parts.append(f"<h2>{html.escape(name)}</h2>{image(folder, path, name)}")
    parts.append("<h2>Numbers</h2>" + numbers_block(numbers))
    return write_page(folder, "Lowcam comparison", title, parts)
