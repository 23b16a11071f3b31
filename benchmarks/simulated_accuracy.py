"""Issue 23's name for the simulated accuracy tables: runs ``experiments/simulated_accuracy.py`` with the same
arguments (accuracy scripts live in experiments/, this folder times things; the script and its options are
documented there).

Usage: python benchmarks/simulated_accuracy.py [--seeds 0,1,2] [--vqf] [--mag | --no-mag-envs] [NAME=VALUE ...]
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / 'experiments' / 'simulated_accuracy.py'

if __name__ == '__main__':
    # The script's own process (not runpy): its worker pool pickles its functions by module name.
    os.execv(sys.executable, [sys.executable, str(SCRIPT), *sys.argv[1:]])
