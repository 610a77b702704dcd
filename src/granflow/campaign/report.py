"""Execute the campaign report notebook and render it as a self-contained HTML page.

The notebook source is a jupytext "percent" script (``notebooks/campaign_report.py``).  It is
read with jupytext, a parameters cell (``RESULTS = ...``, papermill's "injected-parameters"
convention) is inserted after the cell tagged ``parameters``, the notebook is executed with
nbclient in the results folder, saved as ``.ipynb`` and rendered to a single HTML file with
inline PNG figures.  The HTML renderer is built in (markdown via markdown-it-py, which jupytext
already needs), so no nbconvert/pandoc installation is required.  A failing cell fails the
report (nbclient raises), it never yields a half-empty page silently.
"""

from __future__ import annotations

import html
import json
import os
import re
from pathlib import Path

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; max-width: 1100px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
pre { background: #f6f8fa; padding: 0.6em; overflow-x: auto; font-size: 85%; }
pre.err { background: #fdecea; }
details.code summary { color: #666; font-size: 85%; cursor: pointer; }
table { border-collapse: collapse; font-size: 90%; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: right; }
th { background: #f0f0f0; }
img { max-width: 100%; }
.output { margin: 0.4em 0 1.2em 0; }
"""


def _markdown(text: str) -> str:
    try:
        from markdown_it import MarkdownIt

        return MarkdownIt("commonmark", {"html": True}).enable("table").render(text)
    except ImportError:  # pragma: no cover - jupytext depends on markdown-it-py
        return f"<pre>{html.escape(text)}</pre>"


def _join(x) -> str:
    return "".join(x) if isinstance(x, list) else str(x)


def _output_html(out) -> str:
    kind = out.get("output_type")
    if kind == "stream":
        return f"<pre>{html.escape(_ANSI.sub('', _join(out.get('text', ''))))}</pre>"
    if kind == "error":
        tb = _ANSI.sub("", "\n".join(out.get("traceback", [])))
        return f"<pre class='err'>{html.escape(tb)}</pre>"
    data = out.get("data", {})
    if "image/png" in data:
        png = _join(data["image/png"]).replace("\n", "")
        return f"<img src='data:image/png;base64,{png}'/>"
    if "image/svg+xml" in data:
        return _join(data["image/svg+xml"])
    if "text/html" in data:
        return _join(data["text/html"])
    if "text/markdown" in data:
        return _markdown(_join(data["text/markdown"]))
    if "text/plain" in data:
        return f"<pre>{html.escape(_join(data['text/plain']))}</pre>"
    return ""


def notebook_html(nb, title: str = "granflow campaign report", show_code: bool = True) -> str:
    """Self-contained HTML of an executed notebook (markdown, folded code, outputs)."""
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             f"</title><style>{_CSS}</style></head><body>"]
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            parts.append(_markdown(cell.source))
        elif cell.cell_type == "code":
            if "remove-cell" in cell.metadata.get("tags", []):
                continue
            if show_code and cell.source.strip():
                parts.append("<details class='code'><summary>code</summary><pre><code>"
                             f"{html.escape(cell.source)}</code></pre></details>")
            outs = "".join(_output_html(o) for o in cell.get("outputs", []))
            if outs:
                parts.append(f"<div class='output'>{outs}</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def build_notebook(source, parameters: dict):
    """Read a jupytext script and insert the parameters cell (after the 'parameters' cell)."""
    import jupytext
    import nbformat

    nb = jupytext.read(source)
    lines = [f"{k} = {json.dumps(v)}" for k, v in parameters.items()]
    cell = nbformat.v4.new_code_cell("# injected parameters\n" + "\n".join(lines))
    cell.metadata["tags"] = ["injected-parameters"]
    where = next((i + 1 for i, c in enumerate(nb.cells)
                  if "parameters" in c.metadata.get("tags", [])), 0)
    nb.cells.insert(where, cell)
    for c in nb.cells:  # nbformat wants ids on every cell for v4.5
        c.setdefault("id", f"cell-{nb.cells.index(c)}")
    return nb


def render_report(source, out_html, parameters: dict, out_ipynb=None, cwd=None,
                  timeout: int = 600, kernel_name: str = "python3") -> Path:
    """Execute the notebook ``source`` with ``parameters`` and write HTML (and .ipynb)."""
    import nbformat
    from nbclient import NotebookClient

    from ..provenance import atomic_write_bytes

    nb = build_notebook(source, parameters)
    client = NotebookClient(nb, timeout=timeout, kernel_name=kernel_name,
                            resources={"metadata": {"path": os.fspath(cwd or Path.cwd())}})
    client.execute()
    if out_ipynb is not None:
        atomic_write_bytes(out_ipynb, nbformat.writes(nb).encode())
    title = f"granflow campaign report: {parameters.get('CAMPAIGN', '')}".strip()
    atomic_write_bytes(out_html, notebook_html(nb, title=title).encode())
    return Path(out_html)
