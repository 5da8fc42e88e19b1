"""What a figure shows, as a fingerprint that travels inside its PNG.

:func:`figure_content` reads a matplotlib figure object (never its pixels) into plain JSON: the
suptitle, legends and, per visible axes, the title, axis labels and scales, explicitly set ticks
and tick labels, every line's label, style and data, the polygons and points of collections
(``fill_between`` bands, scatter points, error bars), images, patches and texts. Numbers are
rounded (1e-6 for lines, collections and patches; 1e-4 for images and colour bars), so the fingerprint
depends on what is drawn, not on the renderer, fonts, dpi, layout or the names of the input files.

:func:`content_fingerprint` is the SHA-256 of that JSON in canonical form;
``doabench.reporting.plots.save_figure`` writes it into every PNG's metadata under
:data:`CONTENT_KEY` (a PNG text chunk) and :func:`png_fingerprint` reads it back, so a check can
tell whether a committed figure is what its command draws now (``tests/test_docs_figures.py``).
"""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

#: the PNG text chunk that holds a figure's content fingerprint
CONTENT_KEY = "doabench:content"
#: decimals kept of line, collection, patch and text coordinates
DATA_DECIMALS = 6
#: decimals kept of image values (maps computed in float32 differ in their last bits between machines)
IMAGE_DECIMALS = 4


def _numbers(values: Any, decimals: int = DATA_DECIMALS) -> Any:
    """Nested lists of rounded floats (None for NaN and infinities); text where the values are not numbers."""
    try:
        array: np.ndarray = np.ma.filled(np.ma.asarray(values, dtype=float), np.nan)
    except (TypeError, ValueError):
        return [str(v) for v in np.ravel(np.asarray(values, dtype=object))]

    def one(x: float) -> float | None:
        if not math.isfinite(x):
            return None
        return round(float(x), decimals) + 0.0  # + 0.0: -0.0 and 0.0 read alike

    if array.ndim == 0:
        return one(float(array))
    return np.vectorize(one, otypes=[object])(array).tolist() if array.size else []


def _label(artist: Any) -> str:
    """An artist's legend label; matplotlib's automatic ``_child3``-style names read as no label."""
    label = str(artist.get_label() or "")
    return "" if label.startswith("_") else label


def _colour(colour: Any) -> str:
    from matplotlib.colors import to_hex

    try:
        return to_hex(colour, keep_alpha=True)
    except (TypeError, ValueError):
        return str(colour)


def _line(line: Any) -> dict[str, Any]:
    return {"label": _label(line), "x": _numbers(line.get_xdata(orig=True)), "y": _numbers(line.get_ydata(orig=True)),
            "colour": _colour(line.get_color()), "marker": str(line.get_marker()),
            "linestyle": str(line.get_linestyle()), "visible": bool(line.get_visible())}


def _collection(collection: Any) -> dict[str, Any]:
    # The paths' vertices in data coordinates (a fill_between band's polygon, an error bar's
    # segments) and the offsets (scatter points).
    mapped = collection.get_array()
    # A colour-mapped collection (a colour bar's mesh) spans the values of an image: kept to an
    # image's decimals.
    decimals = DATA_DECIMALS if mapped is None else IMAGE_DECIMALS
    out = {"label": _label(collection),
           "paths": [_numbers(path.vertices, decimals) for path in collection.get_paths()],
           "offsets": _numbers(collection.get_offsets(), decimals)}
    if mapped is not None:
        # Its colours are set when it is drawn: its values and colour map say what it shows
        # whether or not it has been drawn yet.
        out["values"] = _numbers(np.ma.filled(np.ma.asarray(mapped, dtype=float), np.nan), decimals)
        out["cmap"] = str(collection.get_cmap().name)
    else:
        out["facecolours"] = [_colour(c) for c in np.atleast_2d(collection.get_facecolor())]
        out["edgecolours"] = [_colour(c) for c in np.atleast_2d(collection.get_edgecolor())]
    return out


def _image(image: Any) -> dict[str, Any]:
    array: np.ndarray = np.ma.filled(np.ma.asarray(image.get_array(), dtype=float), np.nan)
    return {"shape": list(array.shape), "values": _numbers(array, IMAGE_DECIMALS),
            "extent": _numbers(image.get_extent()), "cmap": str(image.get_cmap().name)}


def _patch(patch: Any) -> dict[str, Any]:
    # The outline in the patch's own coordinates (data coordinates for axvspan, Rectangle, Polygon).
    vertices = patch.get_patch_transform().transform(patch.get_path().vertices)
    return {"label": _label(patch), "vertices": _numbers(vertices), "facecolour": _colour(patch.get_facecolor())}


def _text(text: Any) -> dict[str, Any]:
    return {"text": text.get_text(), "position": _numbers(text.get_position())}


def _fixed_ticks(axis: Any) -> dict[str, Any]:
    """Ticks a plot set itself (positions of a FixedLocator, labels of a FixedFormatter); ticks
    that matplotlib chooses depend on the layout and are left out."""
    from matplotlib.ticker import FixedFormatter, FixedLocator

    out: dict[str, Any] = {}
    locator, formatter = axis.get_major_locator(), axis.get_major_formatter()
    if isinstance(locator, FixedLocator):
        out["positions"] = _numbers(locator.locs)  # type: ignore[attr-defined]  # not in matplotlib's stubs
    if isinstance(formatter, FixedFormatter):
        out["labels"] = [str(s) for s in formatter.seq]
    return out


def _legend(legend: Any) -> list[str] | None:
    if legend is None:
        return None
    return [t.get_text() for t in legend.get_texts()]


def _axes(ax: Any) -> dict[str, Any]:
    return {
        "titles": [ax.get_title(loc=loc) for loc in ("left", "center", "right")],
        "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(),
        "xscale": ax.get_xscale(), "yscale": ax.get_yscale(),
        "xticks": _fixed_ticks(ax.xaxis), "yticks": _fixed_ticks(ax.yaxis),
        "lines": [_line(line) for line in ax.get_lines()],
        "collections": [_collection(c) for c in ax.collections],
        "images": [_image(image) for image in ax.get_images()],
        "patches": [_patch(p) for p in ax.patches],
        "texts": [_text(t) for t in ax.texts],
        "legend": _legend(ax.get_legend()),
    }


def figure_content(fig: Any) -> dict[str, Any]:
    """What ``fig`` shows, as JSON-ready data (see the module docstring); hidden axes are left out."""
    suptitle = getattr(fig, "_suptitle", None)
    return {
        "suptitle": suptitle.get_text() if suptitle is not None else "",
        "legends": [_legend(legend) for legend in fig.legends],
        "texts": [_text(t) for t in fig.texts if t is not suptitle],
        "axes": [_axes(ax) for ax in fig.axes if ax.get_visible()],
    }


def canonical_json(content: Any) -> str:
    """``content`` as one canonical JSON text: sorted keys, no spaces, ASCII."""
    return json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def content_fingerprint(fig: Any) -> str:
    """SHA-256 (hex) of :func:`figure_content` in canonical JSON."""
    return hashlib.sha256(canonical_json(figure_content(fig)).encode("ascii")).hexdigest()


def png_fingerprint(path: str | Path) -> str | None:
    """The content fingerprint stored in a PNG written by doabench; None when it holds none."""
    from PIL import Image

    with Image.open(path) as image:
        text = getattr(image, "text", None) or {}
        value = text.get(CONTENT_KEY)
    return str(value) if value is not None else None
