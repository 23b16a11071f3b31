"""``replay()`` and the fleet's health-only task of this tree vs another checkout (``--before SRC``, e.g. main's), in
samples per CPU second: alternating child processes (one per run, the code imported from each tree), so both see
the same load; the bare rosbags read of the same records beside them.

    .venv/bin/python benchmarks/replay_ab.py --before /work/main [BAG] [--rounds 4]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BROAD = Path('/work/shared/data/broad')

CHILD = """
import sys, time
src, what, bag, out = sys.argv[1:5]
import ccf_ros
assert ccf_ros.__file__.startswith(src), (ccf_ros.__file__, src)
try:  # the version process_bag checks: code_version where the tree has it
    from ccf_ros.fleet.keys import code_version
    __version__ = code_version()
except ImportError:
    from ccf_ros import __version__
from ccf_ros.cli import build_parser, engine_settings, make_engine
from ccf_ros.fleet.task import FleetOptions, process_bag
from ccf_ros.offline.bagio import open_bag
from ccf_ros.offline.replay import replay
merged, strict = engine_settings(build_parser().parse_args(['fleet', 'run', 'x', '-o', 'y']))
def bare():
    n = 0
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic in ('/imu/data_raw', '/imu/mag')]
        for _ in reader.messages(connections=conns):
            n += 1
    return n // 2
def run():
    if what == 'bare':
        return bare()
    if what == 'replay':
        return replay(bag, out + '/r', make_engine(merged, strict), overwrite=True, progress=False).n_in
    opts = FleetOptions(out=out + '/t', settings=merged, strict=strict, version=__version__, reference='')
    return process_bag(bag, 'h', opts)['samples']
run()  # (warm: imports, caches)
c0 = time.process_time()
n = run()
print(n / (time.process_time() - c0))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('bag', nargs='?', type=Path)
    ap.add_argument('--before', type=Path, required=True, help='the other checkout (its ccf_ros is imported)')
    ap.add_argument('--rounds', type=int, default=4)
    args = ap.parse_args()
    bag = args.bag or sorted(p for p in BROAD.iterdir() if (p / 'metadata.yaml').exists())[0]
    trees = {'before': args.before.resolve(), 'now': ROOT}
    runs = [('bare', 'now'), ('replay', 'before'), ('replay', 'now'), ('health', 'before'), ('health', 'now')]
    rates: dict[tuple[str, str], list[float]] = {r: [] for r in runs}
    with tempfile.TemporaryDirectory(prefix='ccf_ab_') as tmp:
        for _ in range(args.rounds):
            for what, tree in runs:  # interleaved
                env = {**os.environ, 'PYTHONPATH': str(trees[tree])}
                out = subprocess.run([sys.executable, '-c', CHILD, str(trees[tree]), what, str(bag), tmp], env=env,
                                     check=True, capture_output=True, text=True, cwd=tmp).stdout
                rates[(what, tree)].append(float(out.split()[-1]))
    med = {k: statistics.median(v) for k, v in rates.items()}
    bare = med[('bare', 'now')]
    print(f'{bag.name}, median of {args.rounds} interleaved rounds, samples per CPU second; load at the end '
          f'{os.getloadavg()[0]:.1f}')
    for (what, tree), v in med.items():
        print(f'  {what:7s} {tree:7s} {v:10,.0f} /CPU s   CPU vs the bare read {bare / v:.2f}x')
    for what in ('replay', 'health'):
        print(f'  {what}: now / before {med[(what, "now")] / med[(what, "before")]:.2f}x')


if __name__ == '__main__':
    main()
