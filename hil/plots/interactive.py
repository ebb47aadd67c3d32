"""The interactive figure of model against measurement: one self-contained HTML page (Bokeh) beside
the report, to zoom into a reversal or a settling that the PNG shows at full scale.

Per channel, measured and simulated (the fit % of each model in the legend, a click hides a line)
and the residual beneath; every panel on one shared time axis, so that a zoom or a pan in one moves
all. BokehJS is written into the page (``bokeh.resources.INLINE``): it opens offline, mailed or years
later, and fetches nothing. Values are drawn in the unit an engineer reads (hil.plots.engineering),
as float32 (half the size; 7 significant digits are more than any record holds).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.io.safe_write import write_atomic
from hil.plots.residual_figures import _channel_units, fit_label

__all__ = ["write_interactive"]

_TOOLS = "xpan,xwheel_zoom,box_zoom,reset,save"


def interactive_layout(analysis: dict, after: dict | None = None, names=("model", "fitted model")):
    """The Bokeh layout (a column of panels) of :func:`write_interactive`."""
    from bokeh.layouts import column
    from bokeh.models import ColumnDataSource, Range1d
    from bokeh.plotting import figure

    A = analysis["_arrays"]
    B = after["_arrays"] if after else None
    t = np.asarray(A["t"], float)
    chans = list(A["measured"])
    sig_u = _channel_units(analysis, "measured", chans)
    res_u = _channel_units(analysis, "residual", chans, B)
    x_range = Range1d(float(t[0]), float(t[-1]), bounds=(float(t[0]), float(t[-1])))
    panels = []
    for c in chans:
        (name, k), (rname, rk) = sig_u[c], res_u[c]
        data = {"t": t.astype(np.float32), "measured": (A["measured"][c] / k).astype(np.float32),
                "model": (A["simulated"][c] / k).astype(np.float32),
                "residual": (A["residual"][c] / rk).astype(np.float32)}
        if B:
            data["fitted"] = (B["simulated"][c] / k).astype(np.float32)
            data["residual_fitted"] = (B["residual"][c] / rk).astype(np.float32)
        src = ColumnDataSource(data)
        p = figure(height=280, sizing_mode="stretch_width", x_range=x_range, tools=_TOOLS,
                   active_scroll="xwheel_zoom", title=c, y_axis_label=f"{c} [{name}]")
        p.line("t", "measured", source=src, color="black", line_width=1.2, legend_label="measured")
        p.line("t", "model", source=src, color="#1f77b4", line_width=1,
               legend_label=fit_label(names[0], analysis["channels"][c]["fit"]))
        r = figure(height=150, sizing_mode="stretch_width", x_range=x_range, tools=_TOOLS,
                   active_scroll="xwheel_zoom", y_axis_label=f"residual [{rname}]", x_axis_label="time [s]")
        r.line("t", "residual", source=src, color="#1f77b4", line_width=1, legend_label=names[0])
        if B:
            p.line("t", "fitted", source=src, color="#d62728", line_width=1, line_dash="dashed",
                   legend_label=fit_label(names[1], after["channels"][c]["fit"]))
            r.line("t", "residual_fitted", source=src, color="#d62728", line_width=1, legend_label=names[1])
        for fig in (p, r):
            fig.legend.click_policy = "hide"
            fig.legend.location = "top_right"
            fig.legend.label_text_font_size = "8pt"
        p.xaxis.major_label_text_font_size = "0pt"          # the time axis is read under the residual
        panels += [p, r]
    return column(*panels, sizing_mode="stretch_width")


def write_interactive(analysis: dict, path: Path, title: str, after: dict | None = None,
                      names=("model", "fitted model")) -> Path:
    """Write the interactive overlay of ``analysis`` (hil.ident.residual_analysis.analyse; ``after``: the
    fitted model's) to ``path``: one HTML file with BokehJS inline. Returns the path."""
    from bokeh.embed import file_html
    from bokeh.resources import INLINE
    html = file_html(interactive_layout(analysis, after, names), INLINE, title)
    return write_atomic(Path(path), html)
