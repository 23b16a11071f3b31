"""The state file (``bias_file``): what the engine learnt, kept across restarts. JSON, no ROS import.

Format (version 1)::

    {"version": 1, "frame_id": "imu_link", "stamp": 1764748800.0,
     "sections": {"gyro_bias": {"bias_rad_s": [bx, by, bz], "sigma_rad_s": 0.0003}}}

``frame_id`` is the IMU messages' frame (the sensor's, not ``output_frame_id``), ``stamp`` the wall time of the
write (s since the epoch). Each section is optional and owned by one part of the engine (``gyro_bias``: the gyro
bias in the IMU's frame, rad/s, ``gyro_offset_rad_s`` included, and its 1-σ, rad/s); a reader ignores sections it
does not know, and a writer keeps them (other parts add e.g. ``heading`` or ``hard_iron``).

The file is written atomically (a temporary sibling, flushed, then renamed over it, :func:`os.replace`): a crash or power loss
mid-write leaves the previous file or the new one, never part of one.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

VERSION = 1
GYRO_BIAS = 'gyro_bias'


class StateFileError(ValueError):
    """The state file cannot be used: unreadable, not JSON, another version, malformed fields."""


@dataclass
class State:
    """The content of a state file."""

    frame_id: str = ''
    #: wall time of the write, s since the epoch
    stamp: float = 0.0
    #: section name -> its fields (JSON values)
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)

    def gyro_bias(self) -> tuple[tuple[float, float, float], float | None] | None:
        """``(bias rad/s [x, y, z], sigma rad/s or None)`` of the ``gyro_bias`` section, None if absent.

        Raises:
            StateFileError: the section is malformed.
        """
        sec = self.sections.get(GYRO_BIAS)
        if sec is None:
            return None
        b = sec.get('bias_rad_s')
        s = sec.get('sigma_rad_s')
        if not (isinstance(b, list) and len(b) == 3 and all(_finite(v) for v in b)):
            raise StateFileError(f'gyro_bias.bias_rad_s must be 3 finite numbers, got {b!r}')
        if s is not None and not (_finite(s) and s >= 0):
            raise StateFileError(f'gyro_bias.sigma_rad_s must be a number >= 0 or null, got {s!r}')
        return (float(b[0]), float(b[1]), float(b[2])), None if s is None else float(s)

    def set_gyro_bias(self, bias_rad_s: tuple[float, float, float], sigma_rad_s: float | None) -> None:
        """Set the ``gyro_bias`` section."""
        self.sections[GYRO_BIAS] = {'bias_rad_s': [float(v) for v in bias_rad_s],
                                    'sigma_rad_s': None if sigma_rad_s is None else float(sigma_rad_s)}


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def read_state(path: str | Path) -> State:
    """The state in ``path``.

    Raises:
        FileNotFoundError: no such file (not an error at a first start).
        StateFileError: anything else that makes it unusable, with the reason.
    """
    try:
        text = Path(path).read_text(encoding='utf-8')
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError) as err:
        raise StateFileError(f'cannot read {path}: {err}') from err
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise StateFileError(f'{path} is not JSON ({err})') from err
    if not isinstance(data, dict):
        raise StateFileError(f'{path}: expected a JSON object')
    if data.get('version') != VERSION:
        raise StateFileError(f'{path}: version {data.get("version")!r}, this ccf_ros reads {VERSION}')
    frame_id, stamp, sections = data.get('frame_id', ''), data.get('stamp', 0.0), data.get('sections', {})
    if not isinstance(frame_id, str) or not _finite(stamp) or not isinstance(sections, dict) or not all(
        isinstance(v, dict) for v in sections.values()
    ):
        raise StateFileError(f'{path}: malformed frame_id, stamp or sections')
    return State(frame_id, float(stamp), sections)


def write_state(path: str | Path, state: State) -> None:
    """Write ``state`` to ``path`` atomically (see the module docstring).

    Raises:
        OSError: the folder is not writable (nothing is left behind).
    """
    path = Path(path)
    data = {'version': VERSION, 'frame_id': state.frame_id, 'stamp': state.stamp, 'sections': state.sections}
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as f:
            json.dump(data, f, indent=1)
            f.write('\n')
            f.flush()
            os.fsync(f.fileno())
        Path(tmp).replace(path)  # os.replace: atomic on POSIX
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
