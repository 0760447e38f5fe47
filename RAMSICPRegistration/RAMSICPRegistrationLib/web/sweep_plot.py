"""The RAMSICP scale sweep (RMS and TRE against L) as a small SVG, drawn on the server: the page gets a string and
needs no plotting library (nothing is fetched from outside)."""

from html import escape

import numpy as np

WIDTH, HEIGHT = 300, 150
MARGIN = {"left": 38, "right": 10, "top": 12, "bottom": 30}
SERIES_COLOURS = {"RMS": "#1e88e5", "TRE": "#e53935"}


def sweep_svg(scales, series, chosen_scale=None):
    """SVG text of the sweep.

    Args:
        scales: (K,) the scale factors L.
        series: {"RMS": (K,) mm, "TRE": (K,) mm or None}; a None series is left out.
        chosen_scale: the L the policy chose, marked with a dashed line.
    """
    scales = np.asarray(scales, dtype=np.float64)
    drawn = {name: np.asarray(values, dtype=np.float64) for name, values in series.items() if values is not None}
    if len(scales) == 0 or not drawn:
        return ""
    values = np.concatenate(list(drawn.values()))
    low, high = 0.0, float(np.nanmax(values)) * 1.1 or 1.0
    left, right = MARGIN["left"], WIDTH - MARGIN["right"]
    top, bottom = MARGIN["top"], HEIGHT - MARGIN["bottom"]
    span = float(scales.max() - scales.min()) or 1.0

    def x_of(scale):
        return left + (scale - scales.min()) / span * (right - left)

    def y_of(value):
        return bottom - (value - low) / (high - low) * (bottom - top)

    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" font-size="10" '
        'font-family="sans-serif" role="img" aria-label="RAMSICP sweep: error against the scale factor L">',
        f'<line x1="{left}" y1="{bottom}" x2="{right}" y2="{bottom}" stroke="#888"/>',
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{bottom}" stroke="#888"/>',
        f'<text x="{(left + right) / 2:.1f}" y="{HEIGHT - 4}" text-anchor="middle">scale factor L</text>',
        f'<text x="4" y="{top + 4}" >mm</text>',
    ]
    for tick in (scales.min(), scales.max()):
        parts.append(f'<text x="{x_of(tick):.1f}" y="{bottom + 12}" text-anchor="middle">{tick:g}</text>')
    for tick in (low, high / 1.1):
        parts.append(f'<text x="{left - 3}" y="{y_of(tick) + 3:.1f}" text-anchor="end">{tick:.2f}</text>')
    if chosen_scale is not None:
        x = x_of(chosen_scale)
        parts.append(f'<line x1="{x:.1f}" y1="{top}" x2="{x:.1f}" y2="{bottom}" stroke="#555" stroke-dasharray="3,3"/>')
        parts.append(f'<text x="{x + 3:.1f}" y="{top + 8}">L = {chosen_scale:g}</text>')
    for row, (name, ys) in enumerate(drawn.items()):
        colour = SERIES_COLOURS.get(name, "#333")
        points = " ".join(f"{x_of(s):.1f},{y_of(v):.1f}" for s, v in zip(scales, ys) if np.isfinite(v))
        parts.append(f'<polyline points="{points}" fill="none" stroke="{colour}" stroke-width="1.5"/>')
        parts.append(f'<text x="{right - 40}" y="{top + 10 + 12 * row}" fill="{colour}">{escape(name)}</text>')
    parts.append("</svg>")
    return "".join(parts)


def result_sweep_svg(result):
    """The sweep of a RegistrationResult (empty text when it ran no sweep)."""
    if not result.sweep:
        return ""
    scales = [entry.scale for entry in result.sweep]
    rms = [entry.result.rms_mm for entry in result.sweep]
    tre = None if result.sweep[0].tre_mm is None else [entry.tre_mm for entry in result.sweep]
    return sweep_svg(scales, {"RMS": rms, "TRE": tre}, result.scale)
