"""The comparison report shows masked regions: residual maps one panel per capture in a grid, the masked pixels
tinted, and the share of pixels and of residual energy they hold. Frames made here with numpy: a noisy grey
field, a 40 x 60 px block 30 DN off in the measured frames and masked, thirteen captures as in a chart set."""
import html
import json

import numpy as np
import pytest

from lowcam.measure.compare import Comparison, capture_stats, combine
from lowcam.measure.comparison_report import masked_shares, write_compare_report


@pytest.fixture(scope="module")
def masked_comparison():
    rng = np.random.default_rng(5)
    h, w = 120, 160
    stats = []
    for k in range(13):
        truth = np.full((4, h, w, 3), 100.0)
        measured = truth + rng.normal(0, 2, truth.shape)
        measured[:, 10:50, 20:80] += 30.0
        simulated = truth + rng.normal(0, 2, truth.shape)
        mask = np.ones((h, w), bool)
        if k % 2 == 0:
            mask[10:50, 20:80] = False
        stats.append(capture_stats(np.clip(np.rint(measured), 0, 255).astype(np.uint8),
                                   np.clip(np.rint(simulated), 0, 255).astype(np.uint8), f"view{k:02d}", mask=mask))
    error, families = combine(stats)
    return Comparison(error, families, stats)


def test_masked_shares_count_pixels_and_residual(masked_comparison):
    shares = masked_shares(masked_comparison)
    assert sorted(shares) == [f"view{k:02d}" for k in range(0, 13, 2)]
    for share in shares.values():
        assert share["pixels"] == pytest.approx(40 * 60 / (120 * 160))
        # the block's residual (30 DN against a noise of ~2 DN per mean of 4) is nearly all of the capture's
        assert share["residual"] > 0.95, share


@pytest.mark.slow  # over 4 s: the fast tier stays within minutes
def test_the_report_draws_a_grid_of_residual_maps_and_names_the_masked_share(masked_comparison, tmp_path):
    from PIL import Image

    page = write_compare_report(masked_comparison, tmp_path / "report", "masks")
    width, height = Image.open(tmp_path / "report" / "residual_maps.png").size
    assert width <= 1800 and height >= 1000, (width, height)  # 3 columns, 5 rows: near square, not a strip
    text = page.read_text()
    assert "Left out of the comparison" in text and "of the residual energy" in text
    numbers = json.loads(html.unescape(text.split("<pre>")[-1].split("</pre>")[0]))
    assert numbers["masked"]["view00"]["pixels"] == pytest.approx(0.125)


def test_the_rows_family_reads_only_the_pixels_a_mask_keeps():
    """A mask keeps pixels out of every family, the rows family too: an occluder (or the other half of a held-out
    chequerboard) whose rows flicker from frame to frame is not read as the camera's row noise."""
    rng = np.random.default_rng(7)
    truth = np.full((6, 96, 128, 3), 100.0)
    measured, simulated = truth + rng.normal(0, 2, truth.shape), truth + rng.normal(0, 2, truth.shape)
    measured[:, :, :64] += rng.normal(0, 6, (6, 96, 1, 1))  # rows that flicker, left half only
    keep = np.zeros((96, 128), bool)
    keep[:, 64:] = True
    as_u8 = lambda a: np.clip(np.rint(a), 0, 255).astype(np.uint8)  # noqa: E731
    whole = capture_stats(as_u8(measured), as_u8(simulated)).sums["rows"]
    right = capture_stats(as_u8(measured), as_u8(simulated), mask=keep).sums["rows"]
    assert min(whole) > 1.5 and max(abs(r) for r in right) < 0.5, (whole, right)
