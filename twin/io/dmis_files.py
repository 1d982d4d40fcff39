"""What ``twin cmm check`` writes: the program's summary and results (JSON-ready dicts), the
tolerance results as CSV (``results.csv``) and as a page a quality engineer reads
(``report.html``). Metres in the JSON and CSV field names that say so; millimetres on the page."""

from __future__ import annotations

import csv
import html
from pathlib import Path

import numpy as np

from algorithms.probing.dmis.evaluation import Evaluation, ToleranceResult
from algorithms.probing.dmis.model import DmisModel, Feature, StylusChange

#: Columns of results.csv (one row per tolerance result; metres).
RESULT_COLUMNS = ("tolerance", "kind", "features", "nominal_m", "actual_m", "lower_m", "upper_m", "deviation_m",
                  "result", "note", "line")


def _r(v, digits: int = 9):
    if v is None:
        return None
    return [round(float(x), digits) for x in np.asarray(v).reshape(-1)]


def _m(x: float | None) -> float | None:
    return None if x is None else round(float(x), 9)


def feature_dict(f: Feature | None) -> dict | None:
    if f is None:
        return None
    return {"kind": f.kind, "inner": f.inner, "point_m": _r(f.point_m), "direction": _r(f.direction),
            "size_m": _m(f.size_m), "angle_rad": _m(f.angle_rad)}


def summary(model: DmisModel) -> dict:
    """What the program does, read without a machine: features, measurements, moves, stylus
    changes, constructions, alignments, tolerances, outputs, and every statement skipped."""
    return {
        "program": model.name,
        "version": model.version,
        "encoding": model.encoding,
        "files": model.sources,
        "statements_executed": model.statements_executed,
        "features": {f.label: {**(feature_dict(f) or {}), "line": f.where.line} for f in model.features.values()},
        "measurements": [{"feature": m.feature, "requested": m.requested, "touches": len(m.touches),
                          "line": m.where.line} for m in model.measurements],
        "touches": len(model.touches),
        "moves": len(model.moves),
        "stylus_changes": [{"stylus": e.name, "line": e.where.line} for e in model.events
                           if isinstance(e, StylusChange)],
        "constructions": [{"feature": c.label, "kind": c.kind, "method": c.method, "from": list(c.inputs),
                           "line": c.where.line} for c in model.constructions],
        "datums": dict(model.datums),
        "alignments": [{"op": a.op, "line": a.where.line} for a in model.alignments],
        "tolerances": [{"label": t.label, "kind": t.kind, "line": t.where.line} for t in model.tolerances.values()],
        "outputs": [{"features": list(o.features), "tolerances": list(o.tolerances), "line": o.where.line}
                    for o in model.outputs],
        "notices": [{"file": n.where.source, "line": n.where.line, "word": n.word, "kind": n.kind,
                     "message": n.message} for n in model.notices],
    }


def tolerance_dict(t: ToleranceResult) -> dict:
    return {"tolerance": t.label, "kind": t.kind, "features": list(t.features), "nominal_m": _m(t.nominal_m),
            "actual_m": _m(t.actual_m), "lower_m": _m(t.lower_m), "upper_m": _m(t.upper_m),
            "deviation_m": _m(t.deviation_m), "in_tolerance": t.in_tolerance, "note": t.note, "line": t.where.line}


def results(ev: Evaluation) -> dict:
    """The evaluation: the verdict, each tolerance, each feature (base frame) with its form."""
    return {
        "verdict": ev.verdict,
        "tolerances": [tolerance_dict(t) for t in ev.tolerances],
        "features": {r.label: {"nominal": feature_dict(r.nominal), "actual": feature_dict(r.actual),
                               "points": len(r.points_m), "form_m": _m(r.form_m),
                               "rms_residual_m": _m(float(np.sqrt(np.mean(r.residuals_m**2))) if len(r.residuals_m)
                                                    else None), "note": r.note}
                     for r in ev.features.values()},
    }


def _result_word(t: ToleranceResult) -> str:
    return "not evaluated" if t.in_tolerance is None else ("in" if t.in_tolerance else "OUT")


def write_results_csv(path: Path, ev: Evaluation) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(RESULT_COLUMNS)
        for t in ev.tolerances:
            w.writerow([t.label, t.kind, " ".join(t.features), _m(t.nominal_m), _m(t.actual_m), _m(t.lower_m),
                        _m(t.upper_m), _m(t.deviation_m), _result_word(t), t.note, t.where.line])


def _mm(x: float | None) -> str:
    return "" if x is None else f"{1e3 * x:.4f}"


_STYLE = """body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse;margin:1em 0}
td,th{border:1px solid #bbb;padding:4px 8px;text-align:right}td.l,th.l{text-align:left}
.PASS{background:#2e7d32;color:#fff}.FAIL{background:#c62828;color:#fff}.INCOMPLETE{background:#ef6c00;color:#fff}
.verdict{display:inline-block;padding:6px 16px;font-size:1.4em;font-weight:bold;border-radius:4px}
tr.out td{background:#ffebee}tr.none td{background:#fff3e0}"""


def write_results_html(path: Path, model: DmisModel, ev: Evaluation, run: dict, checks: list[tuple[str, bool, str]],
                       verdict: str) -> None:
    """``report.html``: the verdict, the checks that decide it, the tolerance table (mm), the
    features, and the statements skipped."""
    e = html.escape
    rows = []
    for t in ev.tolerances:
        cls = "none" if t.in_tolerance is None else ("" if t.in_tolerance else "out")
        rows.append(f"<tr class='{cls}'><td class='l'>{e(t.label)}</td><td class='l'>{e(t.kind)}</td>"
                    f"<td class='l'>{e(', '.join(t.features))}</td>"
                    f"<td>{_mm(t.nominal_m)}</td><td>{_mm(t.actual_m)}</td>"
                    f"<td>{_mm(t.lower_m)}</td><td>{_mm(t.upper_m)}</td><td>{_mm(t.deviation_m)}</td>"
                    f"<td class='l'>{_result_word(t)}</td><td class='l'>{e(t.note)}</td></tr>")
    feats = []
    for r in ev.features.values():
        a = r.actual
        feats.append(f"<tr><td class='l'>{e(r.label)}</td><td class='l'>{r.nominal.kind}</td><td>{len(r.points_m)}</td>"
                     f"<td>{'' if a is None else ', '.join(f'{1e3 * x:.4f}' for x in a.point_m)}</td>"
                     f"<td>{'' if a is None else _mm(a.size_m)}</td><td>{_mm(r.form_m)}</td>"
                     f"<td class='l'>{e(r.note)}</td></tr>")
    check_rows = "".join(f"<tr><td class='l'>{e(name)}</td><td class='l'>{'pass' if ok else 'FAIL'}</td>"
                         f"<td class='l'>{e(detail)}</td></tr>" for name, ok, detail in checks)
    notices = "".join(f"<tr><td>{n.where.line}</td><td class='l'>{e(n.word)}</td><td class='l'>{n.kind}</td>"
                      f"<td class='l'>{e(n.message)}</td></tr>" for n in model.notices)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{e(model.name)}</title>
<style>{_STYLE}</style></head><body>
<h1>{e(model.name)}</h1>
<p><span class="verdict {verdict}">{verdict}</span> &nbsp; {len(ev.tolerances)} tolerance results,
{sum(t.in_tolerance is True for t in ev.tolerances)} in, {sum(t.in_tolerance is False for t in ev.tolerances)} out,
{sum(t.in_tolerance is None for t in ev.tolerances)} not evaluated; {run['measured_points']} touches,
{run['misses']} missed, {run['contacts']} unintended contacts, cycle {run['cycle_time_s']:.1f} s.</p>
<h2>Checks</h2><table><tr><th class='l'>check</th><th class='l'>result</th><th class='l'>detail</th></tr>
{check_rows}</table>
<h2>Tolerances (mm)</h2>
<table><tr><th class='l'>tolerance</th><th class='l'>type</th><th class='l'>feature</th><th>nominal</th><th>actual</th>
<th>lower limit</th><th>upper limit</th><th>deviation</th><th class='l'>result</th><th class='l'>note</th></tr>
{''.join(rows)}</table>
<h2>Features (part frame, mm)</h2>
<table><tr><th class='l'>feature</th><th class='l'>type</th><th>points</th><th>actual position</th><th>size</th>
<th>form</th><th class='l'>note</th></tr>{''.join(feats)}</table>
<h2>Statements not run ({len(model.notices)})</h2>
<table><tr><th>line</th><th class='l'>word</th><th class='l'>kind</th><th class='l'>why</th></tr>{notices}</table>
</body></html>
"""
    path.write_text(page, encoding="utf-8")
