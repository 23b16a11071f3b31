"""``ccf fleet report OUT``: a Markdown report with PNG plots from ``OUT/results.jsonl``, for people: per device the
health table and trends over the bags' start times, and first the bags and devices that need attention."""

from __future__ import annotations

import json
import math
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

from ..errors import CcfError, ParameterError

__all__ = ['check_device_regex', 'device_of', 'write_report']

#: Metrics plotted over the bags' start times (name, label).
TRENDS = (
    (('gyro_bias_x_rad_s', 'gyro_bias_y_rad_s', 'gyro_bias_z_rad_s'), 'gyro bias at rest, °/s', 180 / math.pi),
    (('hard_iron_x', 'hard_iron_y', 'hard_iron_z'), 'hard-iron estimate (sensor unit)', 1.0),
    (('vibration_m_s2',), 'vibration (RMS above 5 Hz), m/s²', 1.0),
    (('dropped_samples',), 'dropped samples', 1.0),
)
_RANK = {'failed': 0, 'fail': 1, 'warn': 2, 'ok': 3}


def check_device_regex(regex: str | None) -> None:
    """:class:`ParameterError` naming ``--device`` when ``regex`` is not a regular expression."""
    if regex:
        try:
            re.compile(regex)
        except re.error as err:
            raise ParameterError(f'--device is not a regular expression ({err}): {regex!r}') from err


def device_of(bag: str, regex: str | None) -> str:
    """The device a bag belongs to: ``regex``'s first group (or whole match) on the path, else its parent folder
    (for a rosbag2 folder: the folder holding it)."""
    if regex:
        m = re.search(regex, bag)
        if m:
            return m.group(1) if m.groups() else m.group(0)
        return '(no match)'
    return Path(bag).parent.name or '/'


def _fmt(v: Any, scale: float = 1.0) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '–'
    return f'{v * scale:.3g}'


def _read(out: Path) -> list[dict[str, Any]]:
    path = out / 'results.jsonl'
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except OSError as err:
        raise CcfError(f'cannot read {path}: {err.strerror} (run ccf fleet run first)') from err


def _plot(out: Path, device: str, recs: list[dict[str, Any]], index: int) -> str | None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    for r in recs:  # results.jsonl writes NaN as null
        if r.get('metrics'):
            r['metrics'] = {k: (math.nan if v is None else v) for k, v in r['metrics'].items()}
    pts = [r for r in recs if r['status'] == 'ok' and math.isfinite(r['metrics'].get('start_time_s', math.nan))]
    if not pts:
        return None
    pts.sort(key=lambda r: r['metrics']['start_time_s'])
    t0 = pts[0]['metrics']['start_time_s']
    x = [(r['metrics']['start_time_s'] - t0) / 86400.0 for r in pts]
    fig, axes = plt.subplots(len(TRENDS), 1, figsize=(7, 2.0 * len(TRENDS)), sharex=True)
    for ax, (names, label, scale) in zip(axes, TRENDS, strict=True):
        for name in names:
            y = [r['metrics'].get(name, math.nan) * scale for r in pts]
            ax.plot(x, y, 'o-', ms=3, label=name.removesuffix('_rad_s').split('_')[-1] if len(names) > 1 else None)
        ax.set_ylabel(label, fontsize=7)
        if len(names) > 1:
            ax.legend(fontsize=6, loc='best')
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel('bag start, days after the first bag')
    fig.suptitle(f'device {device}: {len(pts)} bags', fontsize=9)
    fig.tight_layout()
    name = f'report_device{index}.png'
    fig.savefig(out / name, dpi=90)
    plt.close(fig)
    return name


def write_report(out: str | Path, device_regex: str | None = None) -> Path:
    """Write ``OUT/report.md`` (+ one PNG per device) from ``OUT/results.jsonl``; returns the report's path."""
    check_device_regex(device_regex)
    out = Path(out)
    recs = _read(out)
    by_device: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in recs:
        by_device[device_of(r['bag'], device_regex)].append(r)

    def rank(r: dict[str, Any]) -> int:
        return _RANK['failed'] if r['status'] != 'ok' else _RANK[r['health']]

    n_failed = sum(r['status'] != 'ok' for r in recs)
    lines = ['# Fleet IMU health report', '',
             f'{len(recs)} bags, {len(by_device)} devices: {sum(r.get("health") == "ok" for r in recs)} ok, '
             f'{sum(r.get("health") == "warn" for r in recs)} warn, {sum(r.get("health") == "fail" for r in recs)} '
             f'fail, {n_failed} failed to process.', '', '## Needs attention first', '']
    attention = sorted((r for r in recs if rank(r) < _RANK['ok']), key=lambda r: (rank(r), r['bag']))
    if not attention:
        lines.append('Nothing: every bag processed and healthy.')
    for r in attention:
        why = r.get('error') if r['status'] != 'ok' else ', '.join(r['flags'])
        what = 'failed' if r['status'] != 'ok' else r['health']
        lines.append(f'- **{what}** `{r["bag"]}` ({device_of(r["bag"], device_regex)}): {why}')
    dev_rank = sorted(by_device, key=lambda d: (min(rank(r) for r in by_device[d]),
                                                -sum(rank(r) < 3 for r in by_device[d]), d))
    lines += ['', '## Devices', '', '| device | bags | ok | warn | fail | failed | flags seen |', '|---|---|---|---|---|---|---|']
    for d in dev_rank:
        rs = by_device[d]
        seen = sorted({f for r in rs for f in r.get('flags', [])})
        lines.append(f'| {d} | {len(rs)} | {sum(r.get("health") == "ok" for r in rs)} | '
                     f'{sum(r.get("health") == "warn" for r in rs)} | {sum(r.get("health") == "fail" for r in rs)} | '
                     f'{sum(r["status"] != "ok" for r in rs)} | {", ".join(seen) or "–"} |')
    for i, d in enumerate(dev_rank):
        rs = sorted(by_device[d], key=lambda r: (r.get('metrics') or {}).get('start_time_s') or math.inf)
        lines += ['', f'## Device {d}', '',
                  '| bag | health | flags | samples | rate Hz | dropped | gyro bias °/s | acc norm err % | vibration m/s² '
                  '| mag rejected % |', '|---|---|---|---|---|---|---|---|---|---|']
        for r in rs:
            m = r.get('metrics') or {}
            if r['status'] != 'ok':
                lines.append(f'| `{Path(r["bag"]).name}` | failed | {r.get("error", "")} | | | | | | | |')
                continue
            lines.append(
                f'| `{Path(r["bag"]).name}` | {r["health"]} | {", ".join(r["flags"]) or "–"} | {r["samples"]} | '
                f'{_fmt(m.get("rate_hz"))} | {_fmt(m.get("dropped_samples"))} | '
                f'{_fmt(m.get("gyro_bias_rad_s"), 180 / math.pi)} | {_fmt(m.get("acc_norm_error_share"), 100)} | '
                f'{_fmt(m.get("vibration_m_s2"))} | {_fmt(m.get("mag_rejected_share"), 100)} |')
        png = _plot(out, d, rs, i)
        if png:
            lines += ['', f'![trends of {d}]({png})']
    path = out / 'report.md'
    tmp = out / '.report.md.tmp'
    tmp.write_text('\n'.join(lines) + '\n')
    tmp.replace(path)
    return path
