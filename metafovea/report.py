"""Self-contained HTML reports: headings, tables and PNG figures embedded as base64.

The one home of figure output: :func:`fig_to_png` (the only ``savefig``), :func:`array_png` (an array as an
image, one pixel per element) and :class:`HtmlReport` (every HTML page).
"""

from __future__ import annotations

import base64
import html
import io as _io
from pathlib import Path
from typing import Any, Sequence

from metafovea.io import atomic_write_text


def fig_to_png(fig: Any, dpi: int = 100) -> bytes:
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def array_png(img: Any, cmap: str = "inferno") -> bytes:
    """One image as a PNG, one pixel per array element, in the colour map ``cmap`` (NaN shown as 0)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    buf = _io.BytesIO()
    plt.imsave(buf, np.nan_to_num(np.asarray(img, dtype=np.float64)), cmap=cmap, format="png")
    return buf.getvalue()


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if v != v:
            return "n/a"
        a = abs(v)
        return f"{v:.3g}" if (a >= 1e4 or (0 < a < 1e-2)) else f"{v:.4g}"
    return str(v)


class HtmlReport:
    """Accumulates sections; :meth:`write` produces one self-contained HTML file."""

    def __init__(self, title: str):
        self.title = title
        self.parts: list[str] = []

    def heading(self, text: str, level: int = 2) -> None:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def paragraph(self, text: str) -> None:
        self.parts.append(f"<p>{html.escape(text)}</p>")

    def pre(self, text: str) -> None:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in r) + "</tr>" for r in rows)
        self.parts.append(f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>")

    def image(self, png: bytes, caption: str = "") -> None:
        b64 = base64.b64encode(png).decode()
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self.parts.append(f'<figure><img src="data:image/png;base64,{b64}" alt="{html.escape(caption)}"/>{cap}</figure>')

    def render(self) -> str:
        css = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
               "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;"
               "text-align:right}th{background:#eee}img{max-width:100%}pre{background:#f6f6f6;padding:8px}"
               "figcaption{font-size:90%;color:#555}")
        return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{css}</style></head><body><h1>{html.escape(self.title)}</h1>"
                + "\n".join(self.parts) + "</body></html>\n")

    def write(self, path: str | Path) -> Path:
        return atomic_write_text(path, self.render())
