"""The entry's summary: ``DIR/summary.csv`` (one row a datapoint) and ``DIR/index.html``
(a static page, no server: the same rows with each camera's Figure-20 overlay, the dCp
RMS on the model and a Kulite PSD as thumbnails, each linked to its file)."""

from __future__ import annotations

import csv
import html
import io
import math
from pathlib import Path

__all__ = ["write_summary", "COLUMNS"]

#: the CSV's columns, in order.
COLUMNS = ("datapoint", "status", "mach", "alpha", "beta", "phi", "q", "cameras", "seen",
           "si_change_median", "kulites", "kulite_rms_ratio", "kulite_band_hz", "seconds")


def _fmt(v) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def _cell(folder: str, files: list, label: str) -> str:
    out = []
    for f in files:
        href = html.escape(f"{folder}/{f}", quote=True)
        if f.endswith(".png"):
            out.append(f'<a href="{href}"><img src="{href}" alt="{html.escape(label)} '
                       f'{html.escape(f)}" width="180"></a>')
        else:
            out.append(f'<a href="{href}">{html.escape(Path(f).name)}</a>')
    return "<br>".join(out)


def write_summary(out: Path, rows: list, index, seconds: float) -> tuple[Path, Path]:
    """Write ``summary.csv`` and ``index.html`` in ``out``; returns their paths."""
    from resection.io._write import atomic_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_fmt(r.get(c, "")) for c in COLUMNS])
    csv_path = out / "summary.csv"
    atomic_text(csv_path, buf.getvalue())
    head = "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS) + \
        "<th>camera overlays</th><th>dCp RMS</th><th>Kulites</th><th>files</th>"
    body = []
    for r in rows:
        dp = r["datapoint"]
        files = r.get("files", {})
        cls = "failed" if r["status"].startswith("failed") else r["status"]
        cells = "".join(f"<td>{html.escape(_fmt(r.get(c, '')))}</td>" for c in COLUMNS)
        rms = [f for f in files.get("unsteady", []) if f.endswith("_rms.png")]
        other = files.get("calibration", []) + [f for f in files.get("unsteady", [])
                                                if f.endswith(".h5")]
        if files.get("kulite_table"):
            other.append(files["kulite_table"])
        body.append(f'<tr class="{html.escape(cls)}" id="dp-{html.escape(dp)}">{cells}'
                    f"<td>{_cell(dp, files.get('pose', []), 'camera overlay')}</td>"
                    f"<td>{_cell(dp, rms, 'dCp RMS')}</td>"
                    f"<td>{_cell(dp, files.get('kulite_psd', [])[:1], 'Kulite PSD')}</td>"
                    f"<td>{_cell(dp, other, 'file')}</td></tr>")
    n_ok = sum(r["status"] == "ok" for r in rows)
    n_off = sum(r["status"] == "wind-off" for r in rows)
    n_bad = len(rows) - n_ok - n_off
    title = html.escape(f"entry {index.name or Path(index.source).stem}")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 1em; }}
table {{ border-collapse: collapse; font-size: 12px; }}
td, th {{ border: 1px solid #bbb; padding: 3px; vertical-align: top; }}
tr.failed {{ background: #fdd; }} tr.wind-off {{ background: #eef; }}
</style></head>
<body><h1>{title}</h1>
<p>{len(rows)} datapoints: {n_ok} ok, {n_off} wind-off, {n_bad} failed; {seconds:.1f} s.
Index: {html.escape(str(index.source))}. Table: <a href="summary.csv">summary.csv</a>.</p>
<table><thead><tr>{head}</tr></thead><tbody>
{chr(10).join(body)}
</tbody></table></body></html>
"""
    html_path = out / "index.html"
    atomic_text(html_path, page)
    return csv_path, html_path
