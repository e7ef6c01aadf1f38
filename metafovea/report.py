"""Self-contained HTML reports: headings, tables and PNG figures embedded as base64.

The one home of figure output: :func:`fig_to_png` (the only ``savefig``), :func:`array_png` (an array as an
image, one pixel per element) and :class:`HtmlReport` (every HTML page: one style for every report).

Reports read well in a browser at any width: tables scroll inside their own box instead of widening the page,
text wraps, figures scale down, numbers are formatted (3-4 significant digits, ``n/a`` for NaN, ``-`` for
missing) and never shown as Python reprs; a verdict table (:meth:`HtmlReport.verdict`) goes to the top of the page.
"""

from __future__ import annotations

import base64
import html
import io as _io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from metafovea.io import atomic_write_text

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from numpy.typing import ArrayLike

#: the resolution of every figure a report or a command writes (one for all: figures of two stages side by side
#: in a page then share one scale)
FIGURE_DPI = 100
#: the thumbnails of a result's notebook display (a glance, not a figure)
THUMBNAIL_DPI = 60


def fig_to_png(fig: Figure, dpi: int = FIGURE_DPI, *, trim: bool | None = None) -> bytes:
    """A matplotlib figure as PNG bytes at ``dpi`` (default :data:`FIGURE_DPI`).

    ``trim``: cut the figure to its content (``bbox_inches='tight'``, which draws it twice); default: unless the
    figure has the constrained layout (already fitted to its size); a figure laid out to fit passes False."""
    if trim is None:
        from matplotlib.layout_engine import ConstrainedLayoutEngine

        trim = not isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine)
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight" if trim else None)
    return buf.getvalue()


def array_png(img: ArrayLike, cmap: Any = "inferno") -> bytes:
    """One image as a PNG, one pixel per array element (NaN shown as 0), in the colour map ``cmap`` (a name or a
    matplotlib colormap: thermal images pass :func:`metafovea.plotting.iron_colormap`)."""
    import numpy as np
    from matplotlib.image import imsave

    buf = _io.BytesIO()
    imsave(buf, np.nan_to_num(np.asarray(img, dtype=np.float64)), cmap=cmap, format="png")
    return buf.getvalue()


def fmt(v: Any, unit: str = "") -> str:
    """A value as a person reads it: floats to 3-4 significant digits (``n/a`` for NaN), ``-`` for None, yes/no
    for booleans, lists and dicts item by item (never a Python repr); ``unit`` appended."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        s = "yes" if v else "no"
    elif isinstance(v, float):
        if not math.isfinite(v):
            return "n/a"
        a = abs(v)
        s = f"{v:.3g}" if (a >= 1e4 or (0 < a < 1e-2)) else f"{v:.4g}"
    elif isinstance(v, dict):
        return "; ".join(f"{str(k).replace('_', ' ')} {fmt(x)}" for k, x in v.items())
    elif isinstance(v, (list, tuple)):
        return ", ".join(fmt(x) for x in v)
    else:
        s = str(v)
    return f"{s} {unit}" if unit else s


CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:1.5em auto;
padding:0 1em;color:#222;line-height:1.4;overflow-wrap:break-word}
h1{font-size:1.6em}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
.scroll{max-width:100%;overflow-x:auto;margin:.8em 0}
table{border-collapse:collapse;font-size:92%}
td,th{border:1px solid #ccc;padding:3px 8px;text-align:right;white-space:nowrap}
td.text,th.text{text-align:left;white-space:normal;min-width:8em}
th{background:#eef1f4}
tr.baseline td{font-style:italic;color:#666}
td.best{font-weight:bold;background:#e7f6e7}
td.pass{color:#0a6b0a;font-weight:bold}td.fail{color:#b00;font-weight:bold}
img{max-width:100%;height:auto}
figure{margin:1em 0}figcaption{font-size:90%;color:#555}
pre{background:#f6f6f6;padding:8px;white-space:pre-wrap;overflow-x:auto}
p.note{font-size:92%;color:#444}
"""


class HtmlReport:
    """Accumulates sections; :meth:`write` produces one self-contained HTML file."""

    def __init__(self, title: str):
        self.title = title
        self.parts: list[str] = []
        self._verdict: str | None = None

    def heading(self, text: str, level: int = 2) -> None:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def paragraph(self, text: str, note: bool = False) -> None:
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")

    def pre(self, text: str) -> None:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]], *, text_columns: Sequence[int] = (0,),
              best: Sequence[tuple[int, int]] = (), baseline_rows: Sequence[int] = ()) -> None:
        """A table in its own scrolling box. ``text_columns``: left-aligned, wrapping columns; ``best``: the
        ``(row, column)`` cells marked best; ``baseline_rows``: rows shown as baselines (not methods)."""
        tc, bc, br = set(text_columns), set(best), set(baseline_rows)

        def cell(tag: str, i: int, j: int, v: Any) -> str:
            cls = ["text"] if j in tc else []
            if (i, j) in bc:
                cls.append("best")
            c = f' class="{" ".join(cls)}"' if cls else ""
            return f"<{tag}{c}>{html.escape(v if isinstance(v, str) else fmt(v))}</{tag}>"

        h = "".join(cell("th", -1, j, str(c)) for j, c in enumerate(header))
        body = "".join(('<tr class="baseline">' if i in br else "<tr>")
                       + "".join(cell("td", i, j, c) for j, c in enumerate(r)) + "</tr>" for i, r in enumerate(rows))
        self.parts.append(f'<div class="scroll"><table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table></div>')

    def key_values(self, rows: Sequence[tuple[str, Any]]) -> None:
        """A two-column table of quantities and their values (with units)."""
        self.table(["quantity", "value"], [[k, v] for k, v in rows], text_columns=(0, 1))

    def verdict(self, items: Sequence[dict[str, Any]]) -> None:
        """The verdict at the top of the page: each check (``stage``, ``check``, ``value``, ``reference``,
        ``passed``) with pass/fail."""
        rows = "".join(
            "<tr>" + "".join(f'<td class="text">{html.escape(fmt(it.get(k)))}</td>'
                             for k in ("stage", "check", "value", "reference"))
            + (f'<td class="{"pass" if it["passed"] else "fail"}">{"pass" if it["passed"] else "FAIL"}</td></tr>')
            for it in items)
        n_fail = sum(1 for it in items if not it["passed"])
        verdict = f"all {len(items)} checks pass" if not n_fail else f"{n_fail} of {len(items)} checks fail"
        head = f"<h2>Verdict: {verdict}</h2>"
        self._verdict = (head + '<div class="scroll"><table><thead><tr><th class="text">stage</th>'
                         '<th class="text">check</th><th class="text">value</th><th class="text">reference</th>'
                         f"<th>result</th></tr></thead><tbody>{rows}</tbody></table></div>")

    def image(self, png: bytes, caption: str = "") -> None:
        b64 = base64.b64encode(png).decode()
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self.parts.append(f'<figure><img src="data:image/png;base64,{b64}" alt="{html.escape(caption)}"/>'
                          f'{cap}</figure>')

    def render(self) -> str:
        return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
                f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
                f"<title>{html.escape(self.title)}</title><style>{CSS}</style></head><body>"
                f"<h1>{html.escape(self.title)}</h1>" + (self._verdict or "")
                + "\n".join(self.parts) + "</body></html>\n")

    def write(self, path: str | Path) -> Path:
        return atomic_write_text(path, self.render())
