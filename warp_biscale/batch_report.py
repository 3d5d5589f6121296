"""What a batch run shows a person: its progress line in the terminal, and the results table (CSV, one row
per task) and contact sheet (HTML: every render's thumbnail beside its parameters, sortable by error or
time with plain inline JavaScript, nothing fetched from elsewhere) in the results folder."""

from __future__ import annotations

import csv
import html
import math
import os
import sys
import time

from .io import atomic_path

__all__ = ["ProgressLine", "rows", "write_report", "COLUMNS"]

# Fixed columns of results.csv, in order; tile.<param>, material.<param> and image:<scene> columns are added.
COLUMNS = ("task", "status", "label", "tile", "material", "method", "lobes", "facets", "directions", "normal_res",
           "route", "seed", "backend", "lobes_live", "method_used", "bake_s", "truth_s", "render_s", "total_s", "psnr",
           "rmse", "max_rel_error", "rss_mb", "peak_rss_mb", "wbm_bytes", "wbm", "truth", "worker", "attempts", "error")


def _eta(seconds) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds // 60 % 60:02d}m" if seconds >= 3600 else (
        f"{seconds // 60}m{seconds % 60:02d}s" if seconds >= 60 else f"{seconds}s")


class ProgressLine:
    """`done/total, failed, rate, ETA` on stderr: one line rewritten on a terminal, a line per task otherwise.
    `enabled=None`: only on a terminal."""

    def __init__(self, total: int, skipped: int = 0, enabled=None, stream=None):
        self.stream = stream or sys.stderr
        tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.enabled = tty if enabled is None else bool(enabled)
        self.tty = self.enabled and tty
        self.total, self.skipped = total, skipped
        self.t0 = time.perf_counter()
        self._open = False
        if self.enabled:
            self.say(f"batch: {total} task(s) to run" + (f", {skipped} done before (skipped)" if skipped else ""))

    def _write(self, text, newline=True):
        if self._open and self.tty:
            self.stream.write("\r\033[K")
        self.stream.write(text + ("\n" if newline else ""))
        self.stream.flush()
        self._open = not newline

    def say(self, text):
        if self.enabled:
            self._write(text)

    def status(self, done, failed) -> str:
        finished = done + failed
        dt = time.perf_counter() - self.t0
        rate = finished / dt if dt > 0 else 0.0
        eta = (self.total - finished) / rate if rate > 0 else None
        return (f"[{finished}/{self.total}] {done} done, {failed} failed, {rate:.2f} tasks/s, "
                f"ETA {_eta(eta) if finished < self.total else '0s'}")

    def update(self, done, failed, label, seconds=None, error=None):
        if not self.enabled:
            return
        head = self.status(done, failed)
        if error is not None:  # a failure keeps its own line, on a terminal too
            self._write(f"{head}  FAILED {label}: {error}")
        elif self.tty:
            self._write(f"{head}  {label}", newline=False)
        else:
            self._write(f"{head}  {label} ({seconds:.2f} s)")

    def finish(self, res):
        if not self.enabled:
            return
        word = "interrupted" if res.interrupted else "finished"
        self._write(f"batch {word}: {res.done} done, {res.failed} failed, {res.skipped} skipped (done before), "
                    f"{len(res.tasks) - res.done - res.failed - res.skipped} not run, in {res.elapsed:.1f} s "
                    f"({res.rate:.2f} tasks/s)")


# ------------------------------------------------------------------------------------------------
# table


def _num(v, digits=4):
    if v is None:
        return ""
    if isinstance(v, float):
        if not math.isfinite(v):
            return "inf" if v > 0 else "-inf" if v < 0 else "nan"
        return f"{v:.{digits}g}"
    return v


def _param(v) -> str:
    if isinstance(v, (list, tuple)):
        return "/".join(str(_num(x)) for x in v)
    return str(_num(v))


def rows(jobs, records: dict, tasks_dir: str = "tasks") -> list:
    """One dict per task of the job (in its order): its parameters and, where it ran, its results; paths
    are relative to the results folder."""
    out = []
    for t in jobs.tasks:
        rec = records.get(t.hash, {})
        status = rec.get("status", "pending")
        folder = f"{tasks_dir}/{t.hash}"
        tim, met, mem, outs = (rec.get(k, {}) or {} for k in ("timings", "metrics", "memory", "outputs"))
        row = {"task": t.hash, "status": status, "label": t.label, "tile": t.tile["label"],
               "material": t.material["label"], **{k: t.bake[k] for k in ("method", "lobes", "facets", "directions",
                                                                          "normal_res", "route", "seed", "backend")}}
        if status == "done":
            row.update({
                "lobes_live": rec.get("bake_info", {}).get("lobes_live"),
                "method_used": rec.get("bake_info", {}).get("method") or "", "bake_s": _num(tim.get("bake")),
                "truth_s": _num(tim.get("truth")), "render_s": _num(sum(tim.get("render", {}).values()))
                if tim.get("render") else "", "total_s": _num(tim.get("total")), "psnr": _num(met.get("psnr")),
                "rmse": _num(met.get("rmse")), "max_rel_error": _num(met.get("max_rel_error")),
                "rss_mb": _num(mem.get("rss_mb")), "peak_rss_mb": _num(mem.get("peak_rss_mb")),
                "wbm_bytes": mem.get("wbm_bytes"), "wbm": f"{folder}/{outs['material']}",
                "truth": f"{folder}/{outs['truth']}" if outs.get("truth") else "",
                "worker": (rec.get("worker") or {}).get("address") or f"pid {(rec.get('worker') or {}).get('pid')}",
                "attempts": rec.get("attempts") or "",
            })
            for scene, name in outs.get("renders", {}).items():
                row[f"image:{scene}"] = f"{folder}/{name}"
                row[f"_thumb:{scene}"] = f"{folder}/{outs['thumbnails'][scene]}"
        elif status == "failed":
            row.update({"error": rec.get("error", ""), "attempts": rec.get("attempts", "")})
        tile_params = dict(t.tile.get("params", {}))
        if t.tile["kind"] != "family":
            tile_params = {"file": os.path.basename(t.tile["path"]), **tile_params}
        row.update({f"tile.{k}": _param(v) for k, v in tile_params.items()})
        row.update({f"material.{k}": _param(v) for k, v in t.material.get("params", {}).items()})
        out.append(row)
    return out


def _columns(table, scenes) -> list:
    extra = []
    for prefix in ("tile.", "material."):
        for r in table:
            extra += [k for k in r if k.startswith(prefix) and k not in extra]
    fixed = list(COLUMNS)
    at = fixed.index("method")
    return fixed[:at] + extra + fixed[at:] + [f"image:{s['name']}" for s in scenes]


def write_report(output, jobs, records: dict, tasks_dir: str = "tasks") -> tuple[str, str]:
    """Write results.csv and index.html into `output` (atomically) → their paths."""
    table = rows(jobs, records, tasks_dir)
    cols = _columns(table, jobs.scenes)
    csv_path = os.path.join(output, "results.csv")
    with atomic_path(csv_path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, cols, extrasaction="ignore")
            w.writeheader()
            for r in table:
                w.writerow({c: "" if r.get(c) is None else r.get(c, "") for c in cols})
    html_path = os.path.join(output, "index.html")
    with atomic_path(html_path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(_html(jobs, table, cols))
    return csv_path, html_path


# ------------------------------------------------------------------------------------------------
# contact sheet

_CSS = """body{font:13px system-ui,sans-serif;margin:1em;color:#222}
table{border-collapse:collapse}th,td{border:1px solid #ccc;padding:3px 6px;vertical-align:middle}
th{background:#eee;cursor:pointer;position:sticky;top:0;white-space:nowrap}th:hover{background:#ddd}
td.n{text-align:right;font-variant-numeric:tabular-nums}tr.failed{background:#fdd}tr.pending{color:#999}
td.img{padding:1px}img{display:block;image-rendering:auto}.err{color:#a00;max-width:40em}
button{margin-right:.5em}"""

_JS = """function sortBy(col, dir){
  var tb=document.getElementById('t').tBodies[0], rs=Array.prototype.slice.call(tb.rows);
  var th=document.getElementById('t').tHead.rows[0].cells[col];
  if(dir===undefined){dir=th.getAttribute('data-dir')==='asc'?'desc':'asc';}
  var heads=document.getElementById('t').tHead.rows[0].cells;
  for(var i=0;i<heads.length;i++){heads[i].removeAttribute('data-dir');
    heads[i].textContent=heads[i].textContent.replace(/ [\\u25b2\\u25bc]$/,'');}
  th.setAttribute('data-dir',dir);th.textContent+=dir==='asc'?' \\u25b2':' \\u25bc';
  function key(r){var c=r.cells[col],v=c.getAttribute('data-v');if(v===null)v=c.textContent;
    var x=parseFloat(v);return (v!==''&&!isNaN(x))?[0,x]:(v===''?[2,0]:[1,v.toLowerCase()]);}
  rs.sort(function(a,b){var p=key(a),q=key(b);if(p[0]!==q[0])return p[0]-q[0];
    var s=p[1]<q[1]?-1:p[1]>q[1]?1:0;return dir==='asc'?s:-s;});
  for(var i=0;i<rs.length;i++)tb.appendChild(rs[i]);
}
function sortNamed(name,dir){var h=document.getElementById('t').tHead.rows[0].cells;
  for(var i=0;i<h.length;i++){if(h[i].getAttribute('data-c')===name){sortBy(i,dir);return;}}}"""

_SHOWN = ("status", "tile", "material", "method", "method_used", "lobes", "facets", "directions", "lobes_live",
          "bake_s", "truth_s", "render_s", "total_s", "psnr", "max_rel_error", "peak_rss_mb", "wbm_bytes", "worker",
          "error")
_NUMERIC = {"lobes", "facets", "directions", "lobes_live", "bake_s", "truth_s", "render_s", "total_s", "psnr",
            "max_rel_error", "peak_rss_mb", "wbm_bytes"}


def _html(jobs, table, cols) -> str:
    esc = html.escape
    scenes = [s["name"] for s in jobs.scenes]
    params = [c for c in cols if c.startswith("tile.") or c.startswith("material.")]
    shown = [c for c in _SHOWN if c in ("status", "tile", "material")] + params + [
        c for c in _SHOWN if c not in ("status", "tile", "material")]
    counts = {s: sum(r["status"] == s for r in table) for s in ("done", "failed", "pending")}
    title = f"warp_biscale batch: {os.path.basename(jobs.path) if jobs.path else 'jobs'}"
    out = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>", f"<title>{esc(title)}</title>",
           f"<style>{_CSS}</style>", f"<script>{_JS}</script></head><body>", f"<h1>{esc(title)}</h1>",
           f"<p>{len(table)} task(s): {counts['done']} done, {counts['failed']} failed, {counts['pending']} not run. "
           "Click a column's head to sort by it; a thumbnail opens its full image. Table: "
           "<a href='results.csv'>results.csv</a>.</p>",
           "<p><button onclick=\"sortNamed('psnr','asc')\">worst PSNR first</button>"
           "<button onclick=\"sortNamed('total_s','desc')\">slowest first</button>"
           "<button onclick=\"sortNamed('bake_s','desc')\">slowest bake first</button>"
           "<button onclick=\"sortNamed('status','asc')\">failed first</button></p>",
           "<table id='t'><thead><tr>"]
    heads = [f"render: {s}" for s in scenes] + ["task"] + shown
    keys = [f"image:{s}" for s in scenes] + ["task"] + shown
    for i, (h, k) in enumerate(zip(heads, keys)):
        out.append(f"<th data-c='{esc(k)}' onclick='sortBy({i})'>{esc(h)}</th>")
    out.append("</tr></thead><tbody>")
    for r in table:
        cells = []
        for s in scenes:
            thumb, full = r.get(f"_thumb:{s}"), r.get(f"image:{s}")
            cells.append(f"<td class='img'><a href='{esc(full)}'><img src='{esc(thumb)}' alt='{esc(s)}' "
                         f"loading='lazy'></a></td>" if thumb else "<td class='img'></td>")
        folder = f"tasks/{r['task']}"
        cells.append(f"<td title='{esc(r['label'])}'><a href='{esc(folder)}/'>{esc(r['task'][:8])}</a></td>")
        for c in shown:
            v = r.get(c, "")
            v = "" if v is None else str(v)
            if c in _NUMERIC:
                sort = v if v not in ("inf", "-inf", "nan") else {"inf": "1e308", "-inf": "-1e308", "nan": ""}[v]
                cells.append(f"<td class='n' data-v='{esc(sort)}'>{esc(v)}</td>")
            elif c == "status":
                order = {"failed": 0, "pending": 1, "done": 2}.get(v, 3)
                cells.append(f"<td data-v='{order}'>{esc(v)}</td>")
            elif c == "error":
                cells.append(f"<td class='err'>{esc(v)}</td>")
            else:
                cells.append(f"<td>{esc(v)}</td>")
        out.append(f"<tr class='{esc(r['status'])}'>{''.join(cells)}</tr>")
    out.append("</tbody></table></body></html>")
    return "\n".join(out) + "\n"
