"""mipnet.stereo.viz's Turbo colour map is Google's exact table (as matplotlib ships it), not an approximation."""

import numpy as np
from helpers import require
from mipnet.stereo import viz


def test_turbo_equals_matplotlib_turbo_at_every_entry():
    matplotlib = require("matplotlib")
    reference = np.rint(matplotlib.colormaps["turbo"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)
    np.testing.assert_array_equal(viz.colormap_lut("turbo"), reference)


def test_the_shipped_table_is_uint8_256x3_and_colorize_reads_it_end_to_end():
    table = np.load(viz._TURBO_PATH, allow_pickle=False)
    assert table.dtype == np.uint8 and table.shape == (256, 3)
    # 0 .. 255 over vmin=0, vmax=255 picks entry i for value i
    out = viz.colorize(np.arange(256, dtype=np.float64).reshape(16, 16), vmin=0, vmax=255)
    np.testing.assert_array_equal(out.reshape(256, 3), table)
    # Turbo's published ends: (48, 18, 59) dark blue-violet, (122, 4, 3) dark red
    assert tuple(table[0]) == (48, 18, 59) and tuple(table[255]) == (122, 4, 3)
