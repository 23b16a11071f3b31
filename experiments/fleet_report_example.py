"""Make doc/fleet_report_example.png: two simulated robots recorded on five days, robot_b's gyro offset growing
and its vibration rising from day to day, one day of robot_a losing samples; ``ccf fleet run`` over them and the
report's trend plot of robot_b copied to the doc folder.

    .venv/bin/python experiments/fleet_report_example.py [--output doc/fleet_report_example.png]
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ccf_ros.offline.simulate import SimData, generate, write_bag

ROOT = Path(__file__).resolve().parents[1]
DAY_S = 86400.0


def _day(seed: int, day: int, bias_deg_s: float, shake_m_s2: float, drop: bool) -> SimData:
    d = generate(30.0, 100.0, seed, rest_s=8.0)
    d.t_s = d.t_s + day * DAY_S
    d.gyr[:, 0] += math.radians(bias_deg_s)
    moving = d.t_s - d.t_s[0] > 9.0  # the motors shake the robot once it drives
    d.acc[:, 0] += moving * shake_m_s2 * np.sin(2 * np.pi * 31.0 * d.t_s)
    if drop:
        keep = np.ones(len(d.t_s), bool)
        keep[1500:1560] = False
        d = SimData(*(getattr(d, f)[keep] for f in ('t_s', 'q_true', 'gyr', 'acc', 'mag', 'bias', 'moving')))
    return d


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--output', default=str(ROOT / 'doc' / 'fleet_report_example.png'))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix='ccf_fleet_example_') as tmp:
        root = Path(tmp) / 'fleet'
        for day in range(5):
            write_bag(_day(10 + day, day, 0.3, 0.5, drop=day == 2), root / 'robot_a' / f'day{day}')
            write_bag(_day(20 + day, day, 0.5 + 0.6 * day, 3.0 + 5.0 * day, drop=False), root / 'robot_b' / f'day{day}')
        out = Path(tmp) / 'out'
        r = subprocess.run([str(Path(sys.executable).parent / 'ccf'), 'fleet', 'run', str(root), '-o', str(out), '-j',
                            '2', '--reference', '', '--quiet'], capture_output=True, text=True)
        print(r.stdout, r.stderr, end='')
        report = (out / 'report.md').read_text()
        print(report)
        devices = [line.split()[2] for line in report.splitlines() if line.startswith('## Device ')]
        png = out / f'report_device{devices.index("robot_b")}.png'
        shutil.copy(png, args.output)
        print(f'wrote {args.output}')


if __name__ == '__main__':
    main()
