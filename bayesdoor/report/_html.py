"""Self-contained HTML pages: figures embedded as base64 PNG, plain tables, one stylesheet."""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Iterable, Sequence
from typing import Any

_CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 0;
       color: #1d232a; background: #f5f6f8; }
main { max-width: 1180px; margin: 0 auto; padding: 24px 28px 60px; }
h1 { font-size: 26px; margin: 0 0 4px; }
h2 { font-size: 19px; margin: 34px 0 10px; padding-bottom: 4px; border-bottom: 1px solid #d4d8de; }
p.sub { color: #5b6470; margin: 0 0 18px; }
p.note { color: #5b6470; font-size: 13.5px; max-width: 920px; }
p.warn { background: #fff4e0; border-left: 4px solid #e67e22; padding: 8px 12px;
         max-width: 920px; font-size: 14px; }
.cards { display: flex; flex-wrap: wrap; gap: 12px; margin: 16px 0; }
.card { background: white; border: 1px solid #dde1e6; border-radius: 8px; padding: 10px 16px;
        min-width: 120px; }
.card .v { font-size: 24px; font-weight: 600; }
.card .k { font-size: 12.5px; color: #5b6470; text-transform: uppercase; letter-spacing: .04em; }
.card.bad { border-color: #d9534f; } .card.bad .v { color: #c0392b; }
.card.good .v { color: #1e8449; }
figure { background: white; border: 1px solid #dde1e6; border-radius: 8px; margin: 12px 0;
         padding: 10px; }
figure img { max-width: 100%; display: block; margin: 0 auto; }
figcaption { font-size: 13px; color: #5b6470; margin-top: 6px; }
table { border-collapse: collapse; background: white; font-size: 13.5px; margin: 8px 0; }
th, td { border: 1px solid #dde1e6; padding: 4px 9px; text-align: right; }
th { background: #eef0f3; font-weight: 600; }
td.l, th.l { text-align: left; }
tr.wrong td { background: #fdecea; }
tr.ood td { background: #fff6dc; }
tr.failed td { background: #eceff1; color: #6b7680; }
.tag { display: inline-block; padding: 0 7px; border-radius: 9px; color: white; font-size: 12.5px; }
a { color: #1f5fa8; }
"""


def png(fig: Any, *, dpi: int = 100) -> bytes:
    """The PNG bytes of a matplotlib figure (zlib's fastest level: embedded in a report that
    is written once and read in a browser, time counts more than some 10 % of bytes)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, pil_kwargs={"compress_level": 1})
    return buffer.getvalue()


def img(data: bytes, alt: str, caption: str | None = None) -> str:
    """A ``<figure>`` with the PNG ``data`` embedded as a base64 data URI."""
    uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{uri}" alt="{html.escape(alt)}">{cap}</figure>'


def cards(items: Iterable[tuple[str, str, str]]) -> str:
    """A row of headline numbers: ``(label, value, kind)`` with kind ``""``, ``good``, ``bad``."""
    body = "".join(
        f'<div class="card {kind}"><div class="v">{html.escape(value)}</div>'
        f'<div class="k">{html.escape(label)}</div></div>'
        for label, value, kind in items
    )
    return f'<div class="cards">{body}</div>'


def table(
    header: Sequence[str],
    rows: Iterable[Sequence[str]],
    *,
    row_classes: Sequence[str] | None = None,
    left: int = 1,
    raw: bool = False,
) -> str:
    """An HTML table; the first ``left`` columns are left-aligned.

    Cells are escaped unless ``raw`` (for cells that hold links or tags made here).
    """

    def cell(tag: str, i: int, text: str) -> str:
        cls = ' class="l"' if i < left else ""
        return f"<{tag}{cls}>{text if raw else html.escape(text)}</{tag}>"

    head = "".join(cell("th", i, h) for i, h in enumerate(header))
    lines = []
    for r, row in enumerate(rows):
        cls = f' class="{row_classes[r]}"' if row_classes and row_classes[r] else ""
        lines.append(f"<tr{cls}>" + "".join(cell("td", i, c) for i, c in enumerate(row)) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(lines)}</tbody></table>"


def page(title: str, subtitle: str, body: str) -> str:
    """A complete HTML document with the report stylesheet."""
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body><main>"
        f'<h1>{html.escape(title)}</h1><p class="sub">{html.escape(subtitle)}</p>'
        f"{body}</main></body></html>\n"
    )


def section(title: str, *parts: str) -> str:
    """A titled section."""
    return f"<h2>{html.escape(title)}</h2>" + "".join(parts)


def warning(text: str) -> str:
    """A highlighted paragraph for what the reader must not miss."""
    return f'<p class="warn">{html.escape(text)}</p>'


def note(text: str) -> str:
    """An explanatory paragraph."""
    return f'<p class="note">{html.escape(text)}</p>'
