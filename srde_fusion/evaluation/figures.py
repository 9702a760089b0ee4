"""Pictures of disparity maps: colour-mapped maps, source maps and comparison figures.

Figures are built on :class:`matplotlib.figure.Figure` directly and rendered with the
Agg backend, so nothing here touches pyplot's global state or needs a display.
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from .._atomic import write_atomic
from ..errors import DisparityError

__all__ = [
    "colorize_disparity",
    "colorize_source",
    "comparison_figure",
    "save_figure",
    "DISPARITY_CMAP",
    "ERROR_CMAP",
]

#: Colour map of disparity (near = bright).
DISPARITY_CMAP = "turbo"
#: Colour map of absolute errors.
ERROR_CMAP = "magma"
#: Colour of invalid pixels (RGB in [0, 1]).
INVALID_RGB = (0.5, 0.5, 0.5)
#: Colour of backbone pixels in a source map.
BACKBONE_RGB = (0.15, 0.15, 0.15)
# The error colour scale ends at this percentile of the errors shown, so a few gross
# outliers do not wash out the rest.
_ERROR_PERCENTILE = 98.0
# Width of the colour-bar column relative to a panel.
_COLORBAR_WIDTH = 0.05
# Lowest upper end of the error scale, px (a perfect map would otherwise get a 0-wide scale).
_MIN_ERROR_SCALE_PX = 0.05
# The error colour bar starts here (log scale), pixels: errors below look alike.
_LOG_ERROR_FLOOR_PX = 1e-3


def _finite_range(arrays, lo_pct: float = 1.0, hi_pct: float = 99.0) -> tuple[float, float]:
    values = np.concatenate([a[np.isfinite(a)].ravel() for a in arrays] or [np.zeros(0)])
    if values.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(values, [lo_pct, hi_pct])
    if hi <= lo:
        hi = lo + 1.0
    return float(lo), float(hi)


def colorize_disparity(disparity_px: np.ndarray, *, vmin: float | None = None,
                       vmax: float | None = None, cmap: str = DISPARITY_CMAP) -> np.ndarray:
    """Colour-map a disparity map; invalid pixels are grey.

    Parameters
    ----------
    disparity_px : numpy.ndarray, (H, W), float, pixels
    vmin, vmax : float, optional
        Ends of the colour scale; the 1st and 99th percentiles of the finite values by
        default.
    cmap : str
        A matplotlib colour map name.

    Returns
    -------
    numpy.ndarray, (H, W, 3), uint8
        RGB image.

    Examples
    --------
    >>> import numpy as np
    >>> rgb = colorize_disparity(np.array([[1.0, np.nan]]), vmin=0.0, vmax=2.0)
    >>> rgb.shape, rgb[0, 1].tolist()
    ((1, 2, 3), [128, 128, 128])
    """
    disparity_px = np.asarray(disparity_px, dtype=np.float64)
    if disparity_px.ndim != 2:
        raise DisparityError(f"disparity_px: expected shape (H, W), got {disparity_px.shape}")
    lo, hi = _finite_range([disparity_px])
    lo = lo if vmin is None else vmin
    hi = hi if vmax is None else vmax
    valid = np.isfinite(disparity_px)
    scaled = Normalize(lo, hi, clip=True)(np.where(valid, disparity_px, lo))
    rgb = colormaps[cmap](np.asarray(scaled))[..., :3]
    rgb[~valid] = INVALID_RGB
    return np.round(rgb * 255.0).astype(np.uint8)


def colorize_source(source: np.ndarray) -> np.ndarray:
    """Colour a source map: backbone pixels dark, object ``k`` in the k-th ``tab10`` colour.

    Parameters
    ----------
    source : numpy.ndarray, (H, W), int
        0 = backbone, k = object k (see :class:`~srde_fusion.fusion.fuse.FusionResult`).

    Returns
    -------
    numpy.ndarray, (H, W, 3), uint8
    """
    source = np.asarray(source)
    if source.ndim != 2 or not np.issubdtype(source.dtype, np.integer):
        raise DisparityError(f"source: expected an (H, W) integer map, got shape "
                             f"{source.shape} and dtype {source.dtype}")
    palette = np.array([BACKBONE_RGB, *colormaps["tab10"].colors])
    index = np.where(source > 0, (source - 1) % 10 + 1, 0)
    return np.round(palette[index] * 255.0).astype(np.uint8)


def comparison_figure(image: np.ndarray, disparities: Mapping[str, np.ndarray], *,
                      gt_disparity: np.ndarray | None = None, source: np.ndarray | None = None,
                      region: np.ndarray | None = None, title: str | None = None,
                      panel_width_in: float = 3.2) -> Figure:
    """Draw a figure like the paper's: input, ground truth, each method's map, errors.

    Row 1: the input image, the ground truth (if given) and each disparity map on one
    shared colour scale, with a colour bar. Row 2 (with ground truth): the source map
    (if given) and each map's absolute error on one shared scale, with a colour bar.

    Parameters
    ----------
    image : numpy.ndarray, (H, W, 3) or (H, W), uint8
        The reference view.
    disparities : dict of str -> numpy.ndarray, (H, W), float, pixels
        Panel title -> disparity map, in display order (e.g. backbone, SRDE, fused).
    gt_disparity : numpy.ndarray, (H, W), float, optional
        Ground truth, pixels.
    source : numpy.ndarray, (H, W), int, optional
        Where the fused map's pixels came from.
    region : numpy.ndarray, (H, W), bool, optional
        Outlined on the input image (e.g. the object masks).
    title : str, optional
    panel_width_in : float
        Width of one panel, inches.

    Returns
    -------
    matplotlib.figure.Figure
    """
    maps = dict(disparities)
    h, w = image.shape[:2]
    for name, d in maps.items():
        if np.shape(d) != (h, w):
            raise DisparityError(f"disparities[{name!r}]: expected shape {(h, w)} like the "
                                 f"image, got {np.shape(d)}")
    top = [("input", image)]
    if gt_disparity is not None:
        top.append(("ground truth", gt_disparity))
    top += list(maps.items())
    n_cols = len(top)
    n_rows = 2 if (gt_disparity is not None or source is not None) else 1
    panel_h = panel_width_in * h / w
    # One extra narrow column holds each row's colour bar, so every panel is the same size.
    fig = Figure(figsize=(panel_width_in * n_cols + 1.2, (panel_h + 0.5) * n_rows + 0.4))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(n_rows, n_cols + 1, width_ratios=[1.0] * n_cols + [_COLORBAR_WIDTH],
                            left=0.01, right=0.94, bottom=0.03,
                            top=0.90 if title else 0.95, wspace=0.04, hspace=0.15)
    axes = np.array([[fig.add_subplot(grid[r, c]) for c in range(n_cols)]
                     for r in range(n_rows)])
    for ax in axes.ravel():
        ax.set_axis_off()

    # Invalid pixels (NaN) are drawn grey, not left blank.
    disparity_cmap = colormaps[DISPARITY_CMAP].with_extremes(bad=INVALID_RGB)
    error_cmap = colormaps[ERROR_CMAP].with_extremes(bad=INVALID_RGB)
    disp_maps = [d for _, d in top[1:]]
    vmin, vmax = _finite_range(
        [np.asarray(gt_disparity, dtype=np.float64)] if gt_disparity is not None
        else [np.asarray(d, dtype=np.float64) for d in disp_maps])
    ax = axes[0, 0]
    ax.imshow(image, cmap="gray" if image.ndim == 2 else None)
    if region is not None and np.any(region):
        ax.contour(np.asarray(region, dtype=float), levels=[0.5], colors="w", linewidths=0.8)
    ax.set_title("input")
    disp_im = None
    for col, (name, d) in enumerate(top[1:], start=1):
        d = np.asarray(d, dtype=np.float64)
        disp_im = axes[0, col].imshow(np.ma.masked_invalid(d), cmap=disparity_cmap,
                                      vmin=vmin, vmax=vmax)
        axes[0, col].set_title(name)
    if disp_im is not None:
        fig.colorbar(disp_im, cax=fig.add_subplot(grid[0, n_cols]), label="disparity [px]")

    if n_rows == 2:
        if source is not None:
            ax = axes[1, 0]
            ax.imshow(colorize_source(source), interpolation="nearest")
            ax.set_title("source (colour = object k)")
            # Number each object where its SRDE pixels are, so "object 2: fallback" on the
            # console can be found on the picture (a fallback object has no pixels here).
            for k in np.unique(source[source > 0]):
                vv, uu = np.nonzero(source == k)
                ax.text(float(uu.mean()), float(vv.mean()), str(int(k)), color="white",
                        ha="center", va="center", fontsize=9, fontweight="bold")
            ax.legend(handles=[Patch(color=BACKBONE_RGB, label="backbone kept"),
                               Patch(color=INVALID_RGB, label="no value (maps)")],
                      loc="lower left", fontsize=6, framealpha=0.7)
        if gt_disparity is not None:
            gt = np.asarray(gt_disparity, dtype=np.float64)
            errors = {name: np.abs(np.asarray(d, dtype=np.float64) - gt)
                      for name, d in maps.items()}
            finite = [e[np.isfinite(e)] for e in errors.values()]
            finite = np.concatenate(finite) if finite else np.zeros(0)
            err_max = (max(float(np.percentile(finite, _ERROR_PERCENTILE)), _MIN_ERROR_SCALE_PX)
                       if finite.size else 1.0)
            # A logarithmic scale: SRDE's errors (thousandths to tenths of a pixel) and a
            # network's (pixels to tens) both stay visible on one colour bar.
            norm = LogNorm(vmin=min(_LOG_ERROR_FLOOR_PX, err_max / 10.0), vmax=err_max)
            err_im = None
            first = n_cols - len(errors)
            for col, (name, e) in enumerate(errors.items(), start=first):
                shown = np.ma.masked_invalid(np.maximum(e, norm.vmin))
                err_im = axes[1, col].imshow(shown, cmap=error_cmap, norm=norm)
                axes[1, col].set_title(f"|{name} - gt|")
            if err_im is not None:
                fig.colorbar(err_im, cax=fig.add_subplot(grid[1, n_cols]), extend="max",
                             label="abs. error [px]")
    if title:
        fig.suptitle(title)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Write a figure to an image file (format from the extension) and return its path."""
    out = Path(path)
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format=out.suffix.lstrip(".").lower() or "png")
    return write_atomic(out, buffer.getvalue())
