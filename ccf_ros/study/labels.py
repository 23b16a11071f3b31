"""Names shared by the study's modules: formulations and method labels.

The labels are keys of ``results.json`` and appear as such in the report, its tables and figures: change one here
and every experiment, table and figure follows.
"""

from __future__ import annotations

#: The two formulations studied with the same gains (see :mod:`ccf_ros.study.experiments`).
EULER = 'euler'
QUATERNION = 'quaternion'
FORMULATIONS = (EULER, QUATERNION)

#: Method labels (Figs 10-16, Tables 1-4).
LCF = 'LCF'
NCF = 'NCF'
CCF_EULER = 'CCF paper (euler)'
CCF_QUATERNION = 'CCF ccf_ros (quaternion)'
MAHONY = 'Mahony'
MADGWICK = 'Madgwick'
EKF = 'EKF'
CKF = 'CKF'
LSCF_EULER = 'LSCF (euler)'  # only where the LSCF was fitted (not with --no-lscf)

#: The CCF and the NCF of each formulation (the quaternion NCF is Mahony's filter).
CCF_LABEL = {EULER: CCF_EULER, QUATERNION: CCF_QUATERNION}
NCF_LABEL = {EULER: NCF, QUATERNION: MAHONY}

#: Filter kinds of the gain grid (Tables 1-2): the NCF and the CCF of a formulation.
GRID_NCF = 'NCF'
GRID_CCF = 'CCF'

#: Curves of the time series (Figs 13-14) besides the two CCFs.
REFERENCE = 'reference'
GYRO_ONLY = 'gyro only'
ACC_MAG_ONLY = 'accelerometer/magnetometer only'
