"""Draw doc/frames.png: the output frame (base_link), the IMU's frame on a bracket (mount_rotation) and the
magnetometer chip's frame (mag_rotation), as ccf_ros composes them.

Usage: python experiments/frames_figure.py [-o doc/frames.png]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import numpy as np

from ccf_ros.frames import rotation_matrix

MOUNT = [math.pi, 0.0, math.pi / 2]  # upside down on a 90 deg bracket
MAG = [0.0, 0.0, -math.pi / 2]  # magnetometer chip turned -90 deg about z on the IMU board


def triad(ax, R, title, style='-'):
    """One frame's axes (columns of R, in base_link coordinates) in its own 3-D panel, base_link's faint behind."""
    for k, (c, name) in enumerate(zip('rgb', 'xyz', strict=True)):
        e = np.eye(3)[:, k]
        ax.plot(*zip((0, 0, 0), e, strict=True), color=c, alpha=0.15, linewidth=1)
        v = R[:, k]
        ax.quiver(0, 0, 0, *v, color=c, linestyle=style, arrow_length_ratio=0.12, linewidth=2.5)
        ax.text(*(1.18 * v), name, color=c, fontsize=12, weight='bold')
    ax.set_xlim(-1, 1)
    ax.set_ylim(-1, 1)
    ax.set_zlim(-1, 1)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=20, azim=-60)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])
    ax.set_title(title, fontsize=9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('-o', '--output', type=Path, default=Path(__file__).resolve().parents[1] / 'doc' / 'frames.png')
    a = ap.parse_args()
    R_mount = np.array(rotation_matrix('mount_rotation', MOUNT)).reshape(3, 3)
    R_mag = np.array(rotation_matrix('mag_rotation', MAG)).reshape(3, 3)
    fig = plt.figure(figsize=(12, 4.6))
    triad(fig.add_subplot(1, 3, 1, projection='3d'), np.eye(3),
          'base_link = output_frame_id\n(imu/data, imu/gyro_bias, TF child;\nwhat robot_localization sees)')
    triad(fig.add_subplot(1, 3, 2, projection='3d'), R_mount,
          'imu_link (the input frame_id)\nmount_rotation = [pi, 0, pi/2]: upside down on a 90° bracket\n'
          'gyro, acc: v_out = R_mount (v - gyro_offset)')
    triad(fig.add_subplot(1, 3, 3, projection='3d'), R_mount @ R_mag,
          'magnetometer chip\nmag_rotation = [0, 0, -pi/2] in imu_link\n'
          'm_out = R_mount R_mag S (m - mag_bias)', '--')
    fig.subplots_adjust(left=0.0, right=1.0, top=0.80, bottom=0.08, wspace=0.05)
    fig.text(0.5, 0.02, 'ccf_ros frames, drawn in base_link (faint: base_link axes). Every vector is turned into '
             'base_link before the filter.', ha='center', fontsize=10)
    fig.savefig(a.output, dpi=100)
    print(f'wrote {a.output}')


if __name__ == '__main__':
    main()
