"""Result.plot(): one axis per parameter, value +- 2 se bands of the tracks, the truth dashed;
headless (a bare Figure, rendered by Agg)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import vibid
from conftest import EX1_TRUTH

matplotlib = pytest.importorskip("matplotlib")  # the extra `plot`; pinned in the test venv
from matplotlib.figure import Figure  # noqa: E402


@pytest.fixture(scope="module")
def tracked(example1_stand, ex1_clean):
    data, _ = ex1_clean
    return vibid.identify(example1_stand, data, method="rls", track_every=200)


def band_halfwidths(ax, gid):
    """Half the band's height at each x: the fill_between polygon holds the upper and the
    lower edge at every x of the tracks."""
    coll = next(c for c in ax.collections if c.get_gid() == gid)
    v = np.concatenate([p.vertices for p in coll.get_paths()])
    xs = np.unique(v[:, 0])
    return xs, np.array([(v[v[:, 0] == x, 1].max() - v[v[:, 0] == x, 1].min()) / 2 for x in xs])


def test_plot_tracks_has_one_axis_per_parameter_and_2se_bands(tracked):
    fig = tracked.plot()
    assert isinstance(fig, Figure)
    axes = fig.axes
    assert len(axes) == 3
    tr = tracked.tracks
    for ax, name in zip(axes, ["c1", "d", "c2"]):
        assert ax.get_ylabel().startswith(f"{name} [")
        xs, half = band_halfwidths(ax, f"band:{name}")
        ok = np.isfinite(tr[name + "_se"].to_numpy())
        np.testing.assert_allclose(xs, tr["time_s"].to_numpy()[ok], rtol=0, atol=1e-12)
        # the band is value +- 2 se of each track row (rounding of the polygon's doubles only)
        np.testing.assert_allclose(half, 2 * tr[name + "_se"].to_numpy()[ok], rtol=1e-9)
        line = next(ln for ln in ax.get_lines() if ln.get_gid() == f"track:{name}")
        np.testing.assert_array_equal(line.get_ydata(), tr[name].to_numpy())
        # the stand's true value, dashed
        truth = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
        assert len(truth) == 1 and truth[0].get_ydata()[0] == EX1_TRUTH[name]


def test_plot_renders_headless(tracked):
    # A bare Figure (no pyplot, no GUI backend) rendered by Agg into a PNG.
    from vibid._plot import figure_png_data_uri
    uri = figure_png_data_uri(tracked.plot(["c2"]))
    assert uri.startswith("data:image/png;base64,") and len(uri) > 1000


def test_plot_batch_result_one_errorbar_per_axis(example1_stand, ex1_clean):
    # A result without tracks (auto, batch): the same layout, one point with its 2-se bar.
    data, _ = ex1_clean
    r = vibid.identify(example1_stand, data)
    assert len(r.tracks) == 0
    fig = r.plot()
    assert len(fig.axes) == 3
    for ax, name in zip(fig.axes, r.parameters.index):
        assert len(ax.containers) == 1
        data_line, _, (bars,) = ax.containers[0].lines  # an ErrorbarContainer
        assert data_line.get_ydata()[0] == r.parameters.loc[name, "value"]
        # the error bar: a segment from value - 2 se to value + 2 se
        seg = bars.get_segments()[0]
        se = r.parameters.loc[name, "se"]
        assert math.isclose((seg[1][1] - seg[0][1]) / 2, 2 * se, rel_tol=1e-9)


def test_plot_unknown_parameter(tracked):
    with pytest.raises(ValueError, match="parameter 'k9'"):
        tracked.plot(["k9"])
