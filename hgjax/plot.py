"""Pictures of a resampling: the original cloud and the kept points, one panel each, in a grid.

Needs matplotlib, which is not a runtime dependency: install the ``plot`` extra
(``pip install ".[plot]"`` in the source folder). matplotlib is imported only when a function here is
called, and figures are built without pyplot (no global state, any backend).
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

__all__ = ["show_resampling"]

CONTEXT_POINTS = 5000
"""At most about this many points (an index stride) draw the grey cloud behind kept points."""


def _matplotlib():
    from hgjax import _validate

    try:
        from matplotlib.figure import Figure
    except ImportError as err:
        raise ImportError(f"hgjax.plot needs matplotlib: {_validate.install_hint('plot')}") from err
    return Figure


def _rank_colours(scores: np.ndarray) -> np.ndarray:
    """Scores mapped to [0, 1] by rank, so +inf and heavy tails do not wash out the map."""
    order = np.argsort(np.nan_to_num(scores, nan=-np.inf, posinf=np.finfo(np.float64).max), kind="stable")
    ranks = np.empty(scores.shape[0])
    ranks[order] = np.arange(scores.shape[0])
    return ranks / max(scores.shape[0] - 1, 1)


def _marker_size(n: int) -> float:
    return float(np.clip(4000.0 / max(n, 1), 0.3, 8.0))


def show_resampling(points, kept, *, scores=None, colors=None, view: Sequence[float] = (25.0, -60.0),
                    fig=None, title: str | None = None, path=None, cmap: str = "viridis",
                    panel_size: float = 4.0, columns: int | None = None, context: bool = False,
                    zoom: float = 1.0):
    """Draw the original cloud and the kept points in a grid of panels, with equal axes.

    Args:
      points: (N, 3) the original cloud.
      kept: (M,) indices of the kept points (e.g. from :func:`hgjax.resample`), or a mapping
        from panel titles to such index arrays to draw one panel per method.
      scores: optional (N,) per-point scores; when given, points are coloured by the
        score's rank (dark = low) in every panel.
      colors: optional (N, 3) or (N, 4) per-point colours of the scan (uint8 0-255, uint16
        0-65535 as in LAS, or floats in [0, 1]), used when ``scores`` is None. Without
        either, the original is grey and the kept points red.
      view: (elevation, azimuth) of the camera in degrees (default (25, -60)).
      fig: a ``matplotlib.figure.Figure`` to draw into (default: a new one).
      title: figure title (default none).
      path: when given, the figure is also saved there (format from the extension).
      cmap: matplotlib colour map used with ``scores`` (default ``"viridis"``).
      panel_size: width and height of each panel in inches (default 4).
      columns: panels per row (default ceil(sqrt(panels)), a near-square grid).
      context: draw the cloud in light grey (every point, or an index stride of about
        ``CONTEXT_POINTS``) behind the kept points, which are then red in every panel but
        the original, whatever ``scores`` or ``colors`` say (default False).
      zoom: magnification about the cloud's centre, > 0 (default 1: the whole cloud).

    Returns:
      The ``matplotlib.figure.Figure``, with one 3D axes per panel: the original first.

    Raises:
      ImportError: matplotlib is not installed (install the ``plot`` extra).
      TypeError, ValueError: invalid points, indices out of range, scores or colours of
        the wrong shape, or columns < 1.

    Examples:
      >>> import numpy as np
      >>> pts = np.random.default_rng(0).random((100, 3))
      >>> fig = show_resampling(pts, np.arange(20), title="first 20")
      >>> len(fig.axes)
      2
    """
    from hgjax import _validate

    zoom = _validate.check_positive(zoom, "zoom")
    Figure = _matplotlib()
    pts = np.asarray(_validate.check_points(points), dtype=np.float64)
    n = pts.shape[0]
    panels: Mapping[str, np.ndarray] = kept if isinstance(kept, Mapping) else {"kept": kept}
    panels = {name: _check_indices(idx, n, name) for name, idx in panels.items()}
    colours = None
    if scores is not None:
        scores = np.asarray(scores, dtype=np.float64)
        if scores.shape != (n,):
            raise ValueError(f"scores must have shape (N,) = ({n},); got {scores.shape}")
        colours = _rank_colours(scores)
    elif colors is not None:
        colours = _rgba(colors, n)
    entries = [(f"original ({n} points)", np.arange(n))]
    entries += [(f"{name} ({idx.size} points)", idx) for name, idx in panels.items()]
    if columns is None:
        columns = math.ceil(math.sqrt(len(entries)))
    elif isinstance(columns, bool) or not isinstance(columns, int) or columns < 1:
        raise ValueError(f"columns must be an integer >= 1; got {columns!r}")
    columns = min(columns, len(entries))
    rows = math.ceil(len(entries) / columns)
    if fig is None:
        fig = Figure(figsize=(panel_size * columns, panel_size * rows + 0.5 * bool(title)))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-12) / zoom
    for i, (label, idx) in enumerate(entries):
        ax = fig.add_subplot(rows, columns, i + 1, projection="3d")
        sub = pts[idx]
        style = dict(s=_marker_size(idx.size), linewidths=0, depthshade=False)
        if context and i > 0:
            grey = pts[::max(1, n // CONTEXT_POINTS)]
            ax.scatter(grey[:, 0], grey[:, 1], grey[:, 2], color="0.85", s=_marker_size(grey.shape[0]),
                       linewidths=0, depthshade=False)
            ax.scatter(sub[:, 0], sub[:, 1], sub[:, 2], color="C3", **style)
        elif scores is not None:
            ax.scatter(sub[:, 0], sub[:, 1], sub[:, 2], c=colours[idx], cmap=cmap, vmin=0.0, vmax=1.0, **style)
        elif colours is not None:
            ax.scatter(sub[:, 0], sub[:, 1], sub[:, 2], color=colours[idx], **style)
        else:
            ax.scatter(sub[:, 0], sub[:, 1], sub[:, 2], color="0.55" if i == 0 else "C3", **style)
        for axis, c in zip("xyz", centre):
            getattr(ax, f"set_{axis}lim")(c - half, c + half)
        ax.set_box_aspect((1.0, 1.0, 1.0))
        ax.view_init(elev=float(view[0]), azim=float(view[1]))
        ax.set_axis_off()
        ax.set_title(label, fontsize=10)
    top = 1.0 - 0.35 / fig.get_figheight()  # room for the panel titles
    if title:
        fig.suptitle(title, y=1.0 - 0.08 / fig.get_figheight(), va="top")
        top -= 0.45 / fig.get_figheight()
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=top, wspace=0.0, hspace=0.35 / panel_size)
    if path is not None:
        fig.savefig(path, dpi=150)
    return fig


def _rgba(colors, n: int) -> np.ndarray:
    """Colours (N, 3|4) as floats in [0, 1]: uint8 / 255, other integers / their maximum."""
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise ValueError(f"colors must have shape (N, 3) or (N, 4) with N = {n}; got {c.shape}")
    if c.dtype.kind in "iu":
        return c / (255.0 if c.dtype.itemsize == 1 or (c.size and c.max() <= 255) else 65535.0)
    return np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)


def _check_indices(indices, n: int, name: str) -> np.ndarray:
    idx = np.asarray(indices)
    if idx.dtype.kind not in "iu" or idx.ndim != 1:
        raise TypeError(f"kept[{name!r}] must be a 1-D integer index array; got dtype {idx.dtype},"
                        f" shape {idx.shape}")
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(f"kept[{name!r}] has indices outside [0, {n}); got range [{idx.min()}, {idx.max()}]")
    return idx
