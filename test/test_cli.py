"""The ``ccf`` command: the error rule (input errors one line and exit 2, bugs a traceback, --debug, Ctrl-C 130),
``ccf params``, defaults in every --help, calibrate-mag wired in. Simulated data only: runs without ../shared."""

from __future__ import annotations

import argparse
import io
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from ccf_ros import settings
from ccf_ros.cli import build_parser, format_value, main, unit_of
from ccf_ros.core.registry import FILTERS, all_param_names, param_fields
from ccf_ros.engine import ImuEngine
from ccf_ros.errors import BagError, CcfError, ParameterError

#: Raises an exception of the type named by CCF_BUG in the quaternion CCF's step after 3000 samples (a filter bug
#: mid-bag); the rest of the command runs unchanged.
FILTER_BUG = '''
    import os
    from ccf_ros.core.ccf import QuaternionCcf

    _step, _n = QuaternionCcf._step, [0]

    def step(self, *args, **kwargs):
        _n[0] += 1
        if _n[0] > 3000:
            raise {exc}('injected filter bug')
        return _step(self, *args, **kwargs)

    QuaternionCcf._step = step
'''

#: Makes every IMU sample take 1 ms more (a 60 s bag replays in ~20 s): time to press Ctrl-C.
SLOW_ENGINE = '''
    import os
    import signal
    import time
    from pathlib import Path
    from ccf_ros.core.base import OrientationFilter

    # Ctrl-C as in a terminal, even when the suite runs with SIGINT ignored (started in the background by a
    # non-interactive shell: children inherit the ignore, and Python then installs no handler).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    # The filter's update on the floats: every path (message by message, and the bulk path's one engine call per
    # chunk) calls it (update() itself only unpacks into it).
    _update = OrientationFilter._update_floats
    _mark = os.environ.get('CCF_TEST_MARK')
    _n = [0]

    def _slow(self, *args):
        time.sleep(0.001)
        _n[0] += 1
        if _mark and _n[0] == 500:  # well into the replay: tell the test
            Path(_mark).touch()
        return _update(self, *args)

    OrientationFilter._update_floats = _slow
'''


def _command(args: tuple[object, ...], patch: str) -> list[str]:
    script = textwrap.dedent(patch) + '\nimport sys\nfrom ccf_ros.cli import main\nsys.exit(main(sys.argv[1:]))\n'
    return [sys.executable, '-c', script, *map(str, args)]


def ccf_process(*args: object, patch: str = '') -> subprocess.CompletedProcess:
    """``ccf ARGS`` in a new Python process, after running ``patch``."""
    return subprocess.run(_command(args, patch), capture_output=True, text=True, timeout=300)


def ccf_started(*args: object, patch: str = '', env: dict[str, str] | None = None) -> subprocess.Popen:
    """``ccf ARGS`` started in a new Python process (stderr piped), after running ``patch``."""
    return subprocess.Popen(_command(args, patch), stderr=subprocess.PIPE, text=True, env=env)


def one_line(stderr: str) -> str:
    """The single line of an input error; fails on a traceback or several lines."""
    assert 'Traceback' not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


def nothing_left(directory: Path, *names: str) -> None:
    """Neither the outputs nor their hidden staging directories exist."""
    for name in names:
        assert not (directory / name).exists()
        assert not (directory / f'.{name}.partial').exists()


# --- the error rule ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize('exc', ['RuntimeError', 'ValueError'])
def test_a_filter_bug_during_replay_shows_its_traceback_not_a_bag_error(sim_bag, tmp_path, exc):
    """A ValueError too: the core raises ValueError for bad parameters, but one from inside the filter is a bug."""
    r = ccf_process('replay', sim_bag, '-o', tmp_path / 'out', patch=FILTER_BUG.format(exc=exc))
    assert r.returncode == 1, r.stderr
    assert 'Traceback' in r.stderr and f'{exc}: injected filter bug' in r.stderr
    assert 'in step' in r.stderr  # the frame that raised is shown
    assert 'unreadable' not in r.stderr and 'error:' not in r.stderr
    nothing_left(tmp_path, 'out')


def test_an_engine_bug_propagates_from_main_unchanged(sim_bag, tmp_path, monkeypatch, capsys):
    def broken(self, t_s, gyr, acc):
        raise RuntimeError('engine bug')

    monkeypatch.setattr(ImuEngine, 'on_imu', broken)
    with pytest.raises(RuntimeError, match='engine bug') as info:
        main(['replay', str(sim_bag), '-o', str(tmp_path / 'out')])
    assert not isinstance(info.value, CcfError) and info.value.__cause__ is None
    assert 'unreadable' not in capsys.readouterr().err
    nothing_left(tmp_path, 'out')


def test_truncated_bag_is_one_line_and_exit_2(sim_bag, tmp_path):
    import shutil

    bad = shutil.copytree(sim_bag, tmp_path / 'truncated')
    mcap = next(bad.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    r = ccf_process('replay', bad, '-o', tmp_path / 'o')
    assert r.returncode == 2
    assert one_line(r.stderr).startswith('ccf replay: error: ') and 'truncated' in r.stderr
    nothing_left(tmp_path, 'o')


def test_bag_corrupt_in_the_middle_is_one_line_and_no_half_bag(sim_bag, tmp_path):
    """Opens fine, fails while reading (after part of the output is written): still one line, nothing left."""
    import shutil

    bad = shutil.copytree(sim_bag, tmp_path / 'corrupt')
    mcap = next(bad.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 2000] = b'\xab' * 2000
    mcap.write_bytes(bytes(data))
    r = ccf_process('replay', bad, '-o', tmp_path / 'o')
    assert r.returncode == 2
    assert 'bag is unreadable or truncated' in one_line(r.stderr)
    nothing_left(tmp_path, 'o')


@pytest.mark.parametrize(
    ('param', 'expected'),
    [
        ('tau_acc_s=-3', ('tau_acc_s', '-3')),
        ('tau_acc_s=fast', ('tau_acc_s', 'fast')),
        ('use_mag=maybe', ('use_mag', 'maybe')),
        ('no_such_parameter=1', ('no_such_parameter',)),
        ('kp=3', ('kp', 'does not apply')),  # an euler gain, and the default filter is the quaternion CCF
        ('tau_acc_s', ('--param expects NAME=VALUE',)),
        # A singular soft-iron matrix (a row repeated) would flatten the field: heading lost for good.
        ('mag_soft_iron=[1,0,0,0,1,0,1,0,0]', ('mag_soft_iron', 'invertible')),
    ],
)
def test_a_bad_param_is_one_line_naming_it(sim_bag, tmp_path, capsys, param, expected):
    assert main(['replay', str(sim_bag), '-o', str(tmp_path / 'o'), '--param', param]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith('ccf replay: error: ')
    for text in expected:
        assert text in line
    nothing_left(tmp_path, 'o')


def test_a_param_that_does_not_apply_is_refused_even_with_a_params_file(sim_bag, tmp_path, capsys):
    """A parameters file holds every filter's parameters (those that do not apply are ignored), but a name given
    on the command line must apply to the selected filter."""
    cfg = Path(__file__).resolve().parents[1] / 'config' / 'ccf.yaml'
    assert main(['replay', str(sim_bag), '-o', str(tmp_path / 'o'), '--params-file', str(cfg), '--param', 'kp=3']) == 2
    assert "'kp' does not apply" in one_line(capsys.readouterr().err)


def test_bad_params_files_are_one_line(sim_bag, tmp_path, capsys):
    bad_yaml = tmp_path / 'bad.yaml'
    bad_yaml.write_text('ccf_node:\n  ros__parameters:\n    tau_acc_s: [1,\n')
    no_params = tmp_path / 'no_params.yaml'
    no_params.write_text('ccf_node:\n  tau_acc_s: 1.0\n')
    bad_value = tmp_path / 'bad_value.yaml'
    bad_value.write_text('/**:\n  ros__parameters:\n    tau_mag_s: -1.0\n')
    cases = [
        (tmp_path / 'missing.yaml', ('cannot read', 'missing.yaml')),
        (bad_yaml, ('not valid YAML', 'bad.yaml')),
        (no_params, ('no ros__parameters', 'no_params.yaml')),
        (bad_value, ('tau_mag_s', '-1')),
    ]
    for path, texts in cases:
        assert main(['replay', str(sim_bag), '-o', str(tmp_path / 'o'), '--params-file', str(path)]) == 2
        line = one_line(capsys.readouterr().err)
        assert all(text in line for text in texts), line


def test_other_input_errors_are_one_line(sim_bag, tmp_path, capsys):
    out = tmp_path / 'exists'
    out.mkdir()
    (tmp_path / 'afile').write_text('')
    robot = tmp_path / 'robot.yaml'
    robot.write_text('imu_filter: {ros__parameters: {use_mag: false}}\nekf_filter_node: {ros__parameters: {}}\n')
    cases = [
        (['replay', str(sim_bag), '-o', str(out)], 'exists; pass --overwrite'),
        (['replay', str(sim_bag), '-o', str(tmp_path / 'x'), '--imu-topic', '/nope'], '/nope'),
        (['replay', str(sim_bag), '-o', str(tmp_path / 'x'), '--imu-topic', '/imu/mag'],
         'topic /imu/mag is sensor_msgs/msg/MagneticField, expected sensor_msgs/msg/Imu'),
        (['replay', str(sim_bag), '-o', str(tmp_path / 'x'), '--mag-topic', '/imu/data_raw'],
         'expected sensor_msgs/msg/MagneticField'),
        (['replay', str(tmp_path / 'nothing'), '-o', str(tmp_path / 'x')], 'no such bag'),
        (['replay', str(sim_bag), '-o', str(tmp_path / 'afile' / 'dir')], 'cannot create'),  # a file as folder
        (['replay', str(sim_bag), '-o', str(tmp_path / 'x'), '--mag-topic', '/nope'], 'topic /nope not in bag'),
        (['replay', str(sim_bag), '-o', str(tmp_path / 'afile'), '--overwrite'], 'is a file, not a bag'),
        (['simulate', '-o', str(tmp_path / 's'), '--duration', '0'], 'finite and > 0'),
        (['simulate', '-o', str(tmp_path / 's'), '--duration', 'inf'], 'finite and > 0'),
        (['simulate', '-o', str(tmp_path / 's'), '--seed', '-1'], 'seed must be an integer >= 0'),
        (['simulate', '-o', str(tmp_path / 's'), '--duration', '0.001'], 'ask for at least 2'),
        (['simulate', '-o', str(tmp_path / 'afile'), '--overwrite'], 'is a file, not a bag'),
        (['play', str(sim_bag), '--rate', '0'], '--rate must be > 0'),
        (['play', str(sim_bag), '--qos-depth', '0'], '--qos-depth must be >= 1'),
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--json', str(tmp_path / 'no' / 'x.json')],
         'no such directory'),
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose'], '/imu/data'),  # no estimate in a raw bag
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/imu/data_raw'],
         'marks its orientation unknown'),  # a driver's raw Imu: orientation_covariance[0] = -1
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/imu/mag'],
         '/imu/mag: sensor_msgs/msg/MagneticField holds no orientation'),  # the estimate, not the reference
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/ground_truth/pose',
          '--mask-topic', '/imu/mag'], 'expected std_msgs/msg/Bool'),
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/ground_truth/pose',
          '--json', str(tmp_path / 'afile')], 'exists; pass --overwrite'),
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/ground_truth/pose',
          '--plot', str(tmp_path / 'afile')], 'exists; pass --overwrite'),
        (['demo', '--offline-only', '--live-rate', '-1'], '--live-rate'),
        # A plot type matplotlib does not write, found before any work (eval had written its JSON; a traceback).
        (['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/ground_truth/pose',
          '--json', str(tmp_path / 'x.json'), '--plot', str(tmp_path / 'e.txt')], '.txt is not an image type'),
        (['calibrate-mag', str(sim_bag), '-o', str(tmp_path / 'x.yaml'), '--plot', str(tmp_path / 'e.txt')],
         '.txt is not an image type'),
        # A file as the study's folder, refused before the study runs (raised FileExistsError at the end).
        (['study', str(sim_bag), '-o', str(tmp_path / 'afile'), '--overwrite'], 'is a file, not a folder'),
        # A mask topic named is checked as eval checks it (a typo was ignored: every sample scored).
        (['study', str(sim_bag), '-o', str(tmp_path / 's'), '--mask-topic', '/nope'], 'topic /nope not in bag'),
        (['study', str(sim_bag), '-o', str(tmp_path / 's'), '--mask-topic', '/imu/mag'], 'expected std_msgs/msg/Bool'),
        # fleet reads a parameters file as replay does: no section for the node named, before any bag.
        (['fleet', 'run', str(sim_bag), '-o', str(tmp_path / 's'), '--params-file', str(robot), '--node-name', 'imu'],
         'no section for node /imu (sections: /imu_filter, /ekf_filter_node'),
    ]
    for argv, text in cases:
        assert main(argv) == 2, argv
        line = one_line(capsys.readouterr().err)
        assert line.startswith(f'ccf {argv[0]}: error: ') and text in line, (argv, line)
    nothing_left(tmp_path, 'x', 's', 'x.json', 'x.yaml', 'e.txt')
    assert (tmp_path / 'afile').read_text() == '' and not (tmp_path / '.afile.partial').exists()


def test_debug_reraises_input_errors_with_their_traceback(sim_bag, tmp_path):
    missing = tmp_path / 'nothing'
    for argv in (['--debug', 'replay', str(missing), '-o', str(tmp_path / 'o')],
                 ['replay', str(missing), '-o', str(tmp_path / 'o'), '--debug']):
        with pytest.raises(BagError, match='no such bag'):
            main(argv)
    with pytest.raises(ParameterError, match='tau_acc_s'):
        main(['--debug', 'replay', str(sim_bag), '-o', str(tmp_path / 'o'), '--param', 'tau_acc_s=-1'])
    r = ccf_process('--debug', 'replay', missing, '-o', tmp_path / 'o')
    assert r.returncode == 1 and 'Traceback' in r.stderr and 'BagError: ' in r.stderr
    # Without --debug the same is one line.
    r = ccf_process('replay', missing, '-o', tmp_path / 'o')
    assert r.returncode == 2 and 'no such bag' in one_line(r.stderr)


def test_ctrl_c_exits_130_and_leaves_no_half_bag(sim_bag, tmp_path):
    out = tmp_path / 'out'
    mark = tmp_path.parent / f'{tmp_path.name}.mark'
    p = ccf_started('replay', sim_bag, '-o', out, patch=SLOW_ENGINE, env={**os.environ, 'CCF_TEST_MARK': str(mark)})
    staging = tmp_path / '.out.partial'
    deadline = time.time() + 120
    while not mark.exists() and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)  # polling a file the replay writes at its 500th sample (of 17160, 1 ms each at least)
    assert mark.exists() and staging.exists(), 'replay did not get going'
    assert p.poll() is None, 'replay ended before Ctrl-C'
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert one_line(err) == 'ccf replay: interrupted'
    nothing_left(tmp_path, 'out')


# --- calibrate-mag through ccf -------------------------------------------------------------------------------
def test_calibrate_mag_is_a_ccf_subcommand_and_its_errors_are_one_line(sim_bag, tmp_path, monkeypatch, capsys):
    from ccf_ros.offline import calibrate_mag

    assert main(['calibrate-mag', str(sim_bag), '--mag-topic', '/imu/data_raw', '-o', str(tmp_path / 'a.yaml')]) == 2
    assert 'expected sensor_msgs/msg/MagneticField' in one_line(capsys.readouterr().err)
    assert main(['calibrate-mag', str(sim_bag), '--field-norm-ut', '-5', '-o', str(tmp_path / 'a.yaml')]) == 2
    assert '--field-norm-ut' in one_line(capsys.readouterr().err)
    # Data that cannot give a calibration (a sensor at rest): CalibrationError, one line.
    monkeypatch.setattr(calibrate_mag, 'read_mag', lambda bag, topic, progress=None: np.tile([20e-6, 0.0, -40e-6], (500, 1))
                        + 1e-7 * np.random.default_rng(0).standard_normal((500, 3)))
    assert main(['calibrate-mag', str(sim_bag), '-o', str(tmp_path / 'b.yaml')]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith('ccf calibrate-mag: error: ') and 'rotate the sensor' in line
    assert not any(tmp_path.iterdir())


# --- ccf params ----------------------------------------------------------------------------------------------
def table(text: str) -> tuple[str, dict[str, dict[str, str]]]:
    """Title and rows of ``ccf params`` by name, cut at the header's column starts (so alignment is checked)."""
    lines = text.splitlines()
    header = lines[1]
    cols = ('NAME', 'DEFAULT', 'UNIT', 'DESCRIPTION')
    starts = [header.index(c) for c in cols]
    assert starts[0] == 0 and starts == sorted(starts)
    rows = {}
    for line in lines[2:]:
        cells = [line[a:b].strip() for a, b in zip(starts, [*starts[1:], len(line)], strict=True)]
        assert line[starts[1] - 2:starts[1]] == '  ' and line[starts[3] - 2:starts[3]] == '  ', line
        rows[cells[0]] = dict(zip(cols[1:], cells[1:], strict=True))
    return lines[0], rows


def test_params_lists_every_parameter_with_default_unit_and_description(capsys):
    assert main(['params']) == 0
    _, rows = table(capsys.readouterr().out)
    defaults = settings.all_defaults()
    assert list(rows) == list(defaults)
    for name, value in defaults.items():
        assert rows[name] == {'DEFAULT': format_value(value), 'UNIT': unit_of(name),
                              'DESCRIPTION': settings.DESCRIPTIONS[name]}, name
    assert rows['tau_acc_s']['UNIT'] == 's' and rows['use_mag']['DEFAULT'] == 'true'
    assert rows['ekf_q']['DEFAULT'] == '[5, 0.05, 10]'


def test_params_reads_the_settings_when_it_runs(monkeypatch, capsys):
    """Parameters added later (by anyone) appear without touching the command."""
    new = {'new_rate_hz': settings.Parameter('new_rate_hz', 12.5, 'Hz', 'a new rate', 'node', (0.0, 1e3)),
           'new_flag': settings.Parameter('new_flag', False, '-', '', 'engine')}
    monkeypatch.setattr(settings, 'schema', lambda: new)
    assert main(['params']) == 0
    _, rows = table(capsys.readouterr().out)
    assert rows == {'new_rate_hz': {'DEFAULT': '12.5', 'UNIT': 'Hz', 'DESCRIPTION': 'a new rate'},
                    'new_flag': {'DEFAULT': 'false', 'UNIT': '-', 'DESCRIPTION': ''}}


@pytest.mark.parametrize(
    ('name', 'unit'),
    [('tau_acc_s', 's'), ('rest_gyro_rad_s', 'rad/s'), ('rest_acc_m_s2', 'm/s²'), ('gyro_bias_rate_hz', 'Hz'),
     ('mag_dip_tol_rad', 'rad'), ('gyro_arw_rad_sqrt_s', 'rad/√s'), ('bias_walk_rad_s_sqrt_s', '(rad/s)/√s'),
     ('alpha', '-'), ('use_mag', '-'), ('constant_dt', 's'), ('mag_bias_x', 'T'), ('declination', 'rad'),
     ('ki', '1/s²'), ('madgwick_beta', 'rad/s')],
)
def test_unit_from_the_name_or_its_suffix(name, unit):
    assert unit_of(name) == unit


#: A unit suffix of a name and the unit it says, longest first (``_rad_s_sqrt_s`` before ``_rad_s`` before ``_s``).
NAME_SUFFIX_UNITS = (('_rad_s_sqrt_s', '(rad/s)/√s'), ('_rad_sqrt_s', 'rad/√s'), ('_rad_s', 'rad/s'), ('_m_s2', 'm/s²'),
                     ('_m_s', 'm/s'), ('_rad', 'rad'), ('_hz', 'Hz'), ('_s', 's'))


def test_a_unit_in_the_name_is_the_unit_of_the_definition():
    """The definitions' units cannot contradict the names users read (a slip like motion_hint_linear_m_s in s)."""
    checked = 0
    for name, p in settings.schema().items():
        suffix_unit = next((u for suffix, u in NAME_SUFFIX_UNITS if name.endswith(suffix)), None)
        if suffix_unit is not None:
            assert p.unit == suffix_unit, name
            checked += 1
    assert checked > 30


def test_params_yaml_prints_config_yaml(capsys):
    assert main(['params', '--yaml']) == 0
    assert capsys.readouterr().out == settings.config_yaml()


@pytest.mark.parametrize(('argv', 'key'), [(['--filter', 'ekf'], ('ekf', 'euler')),
                                           (['--filter', 'ccf'], ('ccf', 'quaternion')),
                                           (['--filter', 'ccf', '--formulation', 'euler'], ('ccf', 'euler')),
                                           (['--filter', 'madgwick'], ('madgwick', 'quaternion'))])
def test_params_of_one_filter(capsys, argv, key):
    assert main(['params', *argv]) == 0
    title, rows = table(capsys.readouterr().out)
    assert f'filter={key[0]} formulation={key[1]}' in title
    fields = param_fields(FILTERS[key][0])
    adapter = [n for n in settings.all_defaults() if n not in all_param_names()]
    assert set(rows) == set(fields) | set(adapter)
    for name, f in fields.items():
        assert rows[name]['DEFAULT'] == format_value(f.default), name  # the filter's own default
    assert 'filter' not in rows and 'formulation' not in rows


def test_params_of_a_filter_in_a_formulation_it_lacks_is_one_line(capsys):
    assert main(['params', '--filter', 'ekf', '--formulation', 'quaternion']) == 2
    assert 'no formulation' in one_line(capsys.readouterr().err)
    assert main(['params', '--formulation', 'euler']) == 2
    assert '--formulation needs --filter' in one_line(capsys.readouterr().err)


# --- help ----------------------------------------------------------------------------------------------------
def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_subcommand_help_shows_every_default():
    subs = subcommands(build_parser())
    assert set(subs) == {'replay', 'eval', 'simulate', 'play', 'demo', 'study', 'calibrate-mag', 'params', 'fleet'}
    subs |= {f'fleet {k}': v for k, v in subcommands(subs['fleet']).items()}  # fleet run, fleet report
    assert {'fleet run', 'fleet report'} <= set(subs)
    n_checked = 0
    for name, sub in subs.items():
        text = ' '.join(sub.format_help().split())
        for action in sub._actions:
            if action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS):
                assert f'(default: {action.default})' in text, (name, action.option_strings)
                n_checked += 1
        assert '--debug' in text
    assert n_checked >= 20  # 24 when written
    assert 'calibrate-mag' in build_parser().format_help() and 'params' in build_parser().format_help()


def test_help_exits_0(capsys):
    for argv in (['--help'], ['replay', '--help'], ['params', '--help'], ['calibrate-mag', '--help']):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 0
    assert '(default: mag_calibration.yaml)' in ' '.join(capsys.readouterr().out.split())


def test_an_output_folder_that_does_not_exist_yet_is_created(sim_bag, tmp_path, capsys):
    out = tmp_path / 'new' / 'folder' / 'out'
    assert main(['replay', str(sim_bag), '-o', str(out)]) == 0
    assert out.is_dir() and 'flags at the end: initialized' in capsys.readouterr().out


def test_replay_reads_imu_tools_parameter_files_unchanged(sim_bag, tmp_path):
    """imu_tools' own YAMLs (QoS overrides, gains, do_bias_estimation) apply to replay as to the node: each gives
    the output of the same settings on the command line (filter_config.yaml sets use_mag: false), and not the
    defaults'."""
    from ccf_ros.offline.bagio import read_orientations

    data = Path(__file__).resolve().parent / 'data'

    def replayed(name: str, *options: str) -> np.ndarray:
        assert main(['replay', str(sim_bag), '-o', str(tmp_path / name), *options]) == 0
        return read_orientations(tmp_path / name, '/imu/data')[1]

    default = replayed('default')
    assert np.array_equal(replayed('imu_filter', '--params-file', str(data / 'imu_filter.yaml')), default)
    from_file = replayed('filter_config', '--params-file', str(data / 'filter_config.yaml'))
    assert np.array_equal(from_file, replayed('no_mag', '--param', 'use_mag=false'))
    assert not np.array_equal(from_file, default)


def test_a_bag_without_the_magnetometer_topic_replays_6d_with_a_warning(sim_bag, tmp_path, capsys):
    from conftest import copy_bag

    bag = copy_bag(sim_bag, tmp_path / 'nomag', edit=lambda topic, msg, t: [] if topic == '/imu/mag' else [(msg, t)])
    assert main(['replay', str(bag), '-o', str(tmp_path / 'out')]) == 0
    err = capsys.readouterr().err
    assert 'warning: no /imu/mag in the bag: 6-D' in err
    assert main(['replay', str(bag), '-o', str(tmp_path / 'out2'), '--no-mag']) == 0
    assert 'warning' not in capsys.readouterr().err
    assert main(['replay', str(bag), '-o', str(tmp_path / 'out5'), '--param', 'use_mag=false']) == 0
    assert 'warning' not in capsys.readouterr().err  # switched off in the settings: nothing to warn about
    # Named by the user: a typo must not pass as a 6-D run.
    assert main(['replay', str(bag), '-o', str(tmp_path / 'out3'), '--mag-topic', '/imu/mag']) == 2
    assert 'no messages on /imu/mag' in one_line(capsys.readouterr().err)  # the topic is there, but empty
    assert main(['study', str(bag), '-o', str(tmp_path / 'st'), '--mag-topic', '/imu/magnetic_field']) == 2
    assert 'topic /imu/magnetic_field not in bag' in one_line(capsys.readouterr().err)
    # Node-only settings have no effect offline: said once, not silently dropped.
    assert main(['replay', str(sim_bag), '-o', str(tmp_path / 'out4'), '--param', 'gyro_bias_rate_hz=1']) == 0
    assert 'warning: gyro_bias_rate_hz: node settings, without effect on replay' in capsys.readouterr().err


def test_replay_of_an_imu_topic_without_messages_is_an_error(sim_bag, tmp_path, capsys):
    from conftest import copy_bag

    bag = copy_bag(sim_bag, tmp_path / 'empty', edit=lambda topic, msg, t: [] if topic == '/imu/data_raw' else [(msg, t)])
    assert main(['replay', str(bag), '-o', str(tmp_path / 'out')]) == 2
    assert 'no messages on /imu/data_raw' in one_line(capsys.readouterr().err)
    nothing_left(tmp_path, 'out')


def test_eval_replaces_its_json_and_plot_only_with_overwrite(sim_bag, tmp_path, capsys):
    out, js = tmp_path / 'out', tmp_path / 'score.json'
    assert main(['replay', str(sim_bag), '-o', str(out)]) == 0
    js.write_text('precious')
    argv = ['eval', str(out), '--reference', '/ground_truth/pose', '--reference-bag', str(sim_bag), '--json', str(js)]
    assert main(argv) == 2 and js.read_text() == 'precious'
    capsys.readouterr()
    assert main([*argv, '--overwrite']) == 0
    assert '"total_rmse_deg"' in js.read_text()


def test_overwrite_never_deletes_a_folder_that_is_not_a_bag_nor_the_input(sim_bag, tmp_path, capsys):
    data = tmp_path / 'data'
    data.mkdir()
    (data / 'notes.txt').write_text('precious')
    assert main(['replay', str(sim_bag), '-o', str(data), '--overwrite']) == 2
    assert 'not a bag' in capsys.readouterr().err and (data / 'notes.txt').exists()
    assert main(['replay', str(sim_bag), '-o', str(sim_bag.parent), '--overwrite']) == 2
    assert 'holds it' in capsys.readouterr().err and sim_bag.exists()
    out = tmp_path / 'out'
    assert main(['replay', str(sim_bag), '-o', str(out)]) == 0
    assert main(['replay', str(sim_bag), '-o', str(out), '--overwrite']) == 0  # a bag: replaced


class _Terminal(io.StringIO):
    """stderr as a terminal: progress bars are drawn on one."""

    def isatty(self) -> bool:
        return True


def test_eval_and_calibrate_mag_show_progress_on_a_terminal_only(sim_bag, monkeypatch, capsys):
    """Reading an hour of messages takes a while: eval draws a bar per topic it reads, calibrate-mag one for the
    magnetometer (and the gyro), on a terminal; off one (a pipe, CI), stderr stays clean."""
    from ccf_ros.offline.calibrate_mag import read_mag

    args = ['eval', str(sim_bag), '--reference', '/ground_truth/pose', '--estimate-topic', '/ground_truth/pose']
    assert main(args) == 0
    assert capsys.readouterr().err == ''
    n = 60 * 286
    term = _Terminal()
    monkeypatch.setattr(sys, 'stderr', term)
    assert main(args) == 0
    assert term.getvalue().count(f'/ground_truth/pose: 100%|##########| {n}/{n}') == 2, term.getvalue()[-400:]
    term.truncate(0)
    assert len(read_mag(sim_bag, progress='/imu/mag')) == n
    assert f'/imu/mag: 100%|##########| {n}/{n}' in term.getvalue()
