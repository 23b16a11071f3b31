"""The one settings schema: every parameter defined once, generated files current, one bool and one list parser,
the same validation in the node's path and in replay's. No DDS."""

from __future__ import annotations

import array
import math
import re
from pathlib import Path

import pytest

from ccf_ros import settings
from ccf_ros.core.fields import parse_bool, parse_numbers
from ccf_ros.core.registry import make_filter
from ccf_ros.errors import ParameterError
from ccf_ros.node.compat import PROFILES, bias_estimation_off
from ccf_ros.settings import build, coerce, schema

ROOT = Path(__file__).resolve().parents[1]
#: The node's descriptor ranges before the schema (node_support.PARAMETER_RANGES, others (0, 1e9)), kept here to
#: show the schema declares the same ranges; the ones it changed are where the core refused more than the descriptor
#: said (the descriptor now shows the range that is enforced).
OLD_RANGES = {
    'alpha': (0.0, 1.0), 'lcf_alpha': (0.0, 1.0), 'kp': (0.0, 1e6), 'ki': (0.0, 1e6), 'mag_norm_tol': (0.0, 10.0),
    'mag_dip_tol_rad': (0.0, math.pi), 'mag_consistency_rad': (0.0, math.pi), 'gyro_range_rad_s': (0.0, 1000.0),
    'constant_dt': (0.0, 10.0), 'orientation_stddev': (0.0, math.pi), 'gyro_bias_rate_hz': (0.0, 100000.0),
    'yaw_offset': (-2.0 * math.pi, 2.0 * math.pi), 'declination': (-2.0 * math.pi, 2.0 * math.pi),
    'mag_bias_x': (-10.0, 10.0), 'mag_bias_y': (-10.0, 10.0), 'mag_bias_z': (-10.0, 10.0), 'gain': (0.0, 1.0),
    'zeta': (-1.0, 1.0), 'gain_acc': (-1e9, 1e9), 'gain_mag': (-1e9, 1e9), 'bias_alpha': (-1e9, 1e9),
}
TIGHTENED = {'mag_ref_learn_s': (0.0, 3600.0), 'ckf_bias0_rad_s': (0.0, 1.0), 'madgwick_beta': (0.0, 100.0),
             'mahony_kp': (0.0, 1e4), 'mahony_ki': (0.0, 1e4), 'mag_online_memory_rad': (1.0, 1e6)}


def test_config_yaml_and_doc_parameters_are_generated_from_the_schema():
    assert (ROOT / 'config' / 'ccf.yaml').read_text() == settings.config_yaml()
    doc = (ROOT / 'doc' / 'parameters.md').read_text()
    assert settings.readme_table_is_current(doc, full=True) is True, 'regenerate: python -m ccf_ros.settings --markdown-all'
    # Every parameter is there, the baselines' gains and imu_tools' names included.
    assert all(f'| `{name}` |' in doc for name in schema())


def test_readme_parameter_table_is_current():
    readme = (ROOT / 'README.md').read_text()
    assert settings.readme_table_is_current(readme) is True, 'README table is stale: python -m ccf_ros.settings --markdown'
    # The default filter's, the engine's and the node's; not the baselines' gains nor imu_tools' names.
    assert all(f'| `{n}` |' in readme for n in ('tau_acc_s', 'max_dt_s', 'mount_rotation', 'qos_depth'))
    assert not any(f'| `{n}` |' in readme for n in ('kp', 'madgwick_beta', 'ckf_q', 'gain', 'zeta'))


def test_a_stale_table_is_told_from_a_current_one():
    table = settings.markdown_table()
    assert settings.readme_table_is_current(f'# x\n\n{table}\nmore\n') is True
    assert settings.readme_table_is_current('# x\n' + table.replace('`0.5`', '`0.6`', 1)) is False
    assert settings.readme_table_is_current('# x\n') is None


def test_every_parameter_is_defined_completely_once():
    entries = schema()
    assert list(entries) == list(settings.all_defaults()) and len(entries) > 70
    for name, p in entries.items():
        assert p.unit and p.description and p.applies_to, name
        if isinstance(p.default, (int, float)) and not isinstance(p.default, bool):
            assert p.range is not None and p.range[0] <= p.default <= p.range[1], name
        # The default passes its own definition, unchanged.
        assert coerce(name, p.default) == p.default, name
    assert entries['tau_acc_s'].group == 'filter' and entries['mount_rotation'].group == 'engine'
    assert entries['qos_depth'].group == 'node' and entries['gain'].group == 'imu_tools'
    assert entries['qos_depth'].read_only == frozenset(PROFILES)
    assert entries['yaw_offset'].read_only == {'imu_filter_madgwick_node'}


def test_the_descriptor_ranges_are_the_ones_before_except_where_they_now_say_what_was_enforced():
    entries = schema()
    for name, want in {**OLD_RANGES, **TIGHTENED}.items():
        assert entries[name].range == pytest.approx(want), name
    for name in ('max_dt_s', 'tau_acc_s', 'rest_min_s', 'mag_timeout_s', 'bias_save_interval_s', 'motion_hint_timeout_s',
                 'motion_hint_linear_m_s', 'bias_walk_rad_s_sqrt_s'):
        assert entries[name].range == (0.0, 1e9), name  # the positive reals, as before


@pytest.mark.parametrize(('text', 'value'), [('true', True), (' False', False), ('YES', True), ('off', False),
                                             ('1', True), ('0', False), (True, True), (False, False)])
def test_one_bool_parser_means_the_same_everywhere(text, value):
    assert parse_bool('x', text) is value
    assert coerce('stateless', text) is value  # engine setting (node on-set callback, replay)
    assert make_filter({'rest_bias': text}).params.rest_bias is value  # filter parameter through the core
    assert bias_estimation_off({'do_bias_estimation': text}) is (not value)  # the drop-ins' switch


@pytest.mark.parametrize('bad', ['maybe', '', 1, 0, None, 2.0])
def test_anything_else_is_no_flag(bad):
    with pytest.raises(ValueError, match='must be true or false'):
        parse_bool('x', bad)
    with pytest.raises(ParameterError, match='publish_tf'):
        coerce('publish_tf', bad)
    with pytest.raises(ParameterError, match='do_bias_estimation'):
        build({'do_bias_estimation': bad})  # was accepted silently by replay


@pytest.mark.parametrize('value', ['[1, 0, 0]', '1,0,0', ' (1, 0, 0) ', [1, 0, 0], (1.0, 0.0, 0.0),
                                   array.array('d', [1.0, 0.0, 0.0])])
def test_one_list_parser_for_text_lists_and_rclpy_arrays(value):
    assert parse_numbers('x', value) == (1.0, 0.0, 0.0)
    assert coerce('gyro_offset_rad_s', value) == (1.0, 0.0, 0.0)
    assert make_filter({'filter': 'ekf', 'ekf_q': value}).params.ekf_q == (1.0, 0.0, 0.0)


def test_the_list_parser_names_the_parameter_and_what_it_expects():
    with pytest.raises(ValueError, match="ekf_q must be a number, got 'x'"):
        parse_numbers('ekf_q', [1.0, 'x', 2.0])
    with pytest.raises(ValueError, match='mag_soft_iron must be 9 numbers'):
        parse_numbers('mag_soft_iron', 3.0, '9 numbers')
    with pytest.raises(ValueError, match='must be a number'):
        parse_numbers('kp', [True, 1, 2])


def _outside(p: settings.Parameter) -> float:
    assert p.range is not None
    return p.range[1] * 1.5 + 1.0 if p.range[1] < 1e300 else math.nan


def test_a_value_out_of_range_is_refused_by_the_node_path_and_by_replay_alike():
    """coerce (the node's on-set callback) and build (replay, fleet) refuse the same values, naming them."""
    n = 0
    for name, p in schema().items():
        if p.range is None or isinstance(p.default, (bool, tuple)) or p.per_axis:
            continue
        bad = _outside(p)
        with pytest.raises(ParameterError, match=name):
            coerce(name, bad)
        with pytest.raises(ParameterError, match=name):
            build({'filter': 'ekf', name: bad} if name.startswith('ekf') else {name: bad}, strict=False)
        n += 1
    assert n > 45


def test_a_list_of_the_wrong_length_is_refused_whichever_filter_is_selected():
    """coerce (the node's on-set callback) and build (replay's and fleet's parameters files) check a list's length
    themselves: a list for a filter not selected is never built, and a wrong one was taken."""
    n = 0
    for name, p in schema().items():
        if isinstance(p.default, tuple):
            bad = [1.0] * (max(p.lengths) + 1)
            with pytest.raises(ParameterError, match=f'{name} must be {re.escape(p.what)}, got'):
                coerce(name, bad)
            with pytest.raises(ParameterError, match=name):
                build({name: bad}, strict=False)  # (filter=ccf)
            n += 1
    assert n == 8


def test_above_means_the_lower_bound_itself_is_refused():
    assert schema()['tau_acc_s'].above and not schema()['constant_dt'].above
    with pytest.raises(ParameterError, match=r'tau_acc_s must be within \(0, 1e9\] s, got 0'):
        coerce('tau_acc_s', 0)
    assert coerce('constant_dt', 0) == 0.0
    assert coerce('qos_depth', '7') == 7 and isinstance(coerce('qos_depth', 7.0), int)
    for bad in (7.5, 'inf', float('inf'), float('nan')):  # inf once escaped as OverflowError (int(inf))
        with pytest.raises(ParameterError, match='qos_depth must be an integer'):
            coerce('qos_depth', bad)


def test_old_names_stay_importable():
    from ccf_ros.node import HOLD_S, MAG_TOLERANCE_S, TF_QOS  # names of the former single module ccf_ros.node
    from ccf_ros.node_support import PER_AXIS, coerce_parameter, parameter_range

    assert HOLD_S == 0.02 and MAG_TOLERANCE_S > 0 and TF_QOS.depth == 100

    assert settings.AdapterSettings is settings.EngineSettings
    assert settings.adapter_settings({'mag_bias_y': '2e-5'}).mag_bias == (0.0, 2e-5, 0.0)
    assert set(settings.ADAPTER_DEFAULTS) == set(settings.ENGINE_DEFAULTS) | set(settings.NODE_DEFAULTS) | set(
        settings.IMU_TOOLS_GAINS)
    assert settings.DESCRIPTIONS['tau_acc_s'].startswith('quaternion: ')
    assert {'kp', 'ki', 'alpha', 'lcf_alpha'} == PER_AXIS and parameter_range('gain') == (0.0, 1.0)
    assert coerce_parameter('kp', [1, 2, 3], 25.0) == (1.0, 2.0, 3.0)
