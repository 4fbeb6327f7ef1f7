"""Parameter values are read as rcl reads them: in the generator, a params file, a campaign.

The oracle is rcl itself: a node of ours with ``automatically_declare_parameters_from_overrides``
gets each notation through ``--ros-args -p`` and through ``--params-file``, and reports the
type and value rcl gave it; the generator (``-p``, ``--params-file``) and a campaign spec
(``base.overrides``) must read the same.
"""

import math

import pytest
import yaml

from ros_helpers import next_domain_id

#: Notations rcl accepts, each read by its own rules (YAML 1.1 reads many differently).
NOTATIONS = [
    '2e-4', '1E5', '.5', '+1', '1.', '-0', '.inf', '-.inf', '+.inf', 'nan', '.NaN', '+.NaN',
    'Infinity', '0x1p3', '1e400', '1e-310', '9223372036854775808', 'true', 'True', 'TRUE',
    'tRue', 'yes', 'on', 'y', 'N', 'Off', '1', '010', '08', '0x10', '1_000', '0b1', '~',
    'null', '1:20', '2024-01-01', 'abc', "'2e-4'", '"yes"', '!!str 5', '!!float 1',
    '[1, 2]', '[.5, 1e3]', '[2e-4, -1E5, nan]', '[true, yes, off]', '[a, b]', '[[1, 2]]',
]
#: Notations rcl refuses (at start-up): lists of mixed types.
REFUSED = ['[0.1, 0, 0]', '[1, "2"]', '[true, 1]']
#: Real parameters in the notations users write; each is accepted by the node.
REAL = [
    ('imu.gyro_noise_density', '2e-4'), ('imu.gyro_random_walk', '2E-5'), ('tol', '1e-10'),
    ('time_scale', '1'), ('publish_rate', '+50'), ('star_tracker.rate', '5.'),
    ('imu.enable', 'yes'), ('star_tracker.enable', 'True'), ('mag.enable', 'off'),
    ('imu.seed', '0x10'), ('inertia', '[2, 2, 1]'), ('omega0', '[.3, -.2, .5]'),
    ('torque', '[0.0, 0.0, 5e-2]'), ('frame_id', 'world'), ('accel.noise_density', '.5e-2'),
]


def _rcl_read(tmp_path, pairs):
    """Return ``{name: value}`` as rcl reads ``pairs`` from ``-p`` and from a params file.

    ``-p`` names get the prefix ``p.``, params-file names ``f.``; values are Python values
    of rcl's types (an array a list).
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    path = tmp_path / 'rcl.yaml'
    path.write_text('/**:\n  ros__parameters:\n    f:\n' +
                    ''.join(f'      {n}: {v}\n' for n, v in pairs))
    args = ['probe', '--ros-args', '--params-file', str(path)]
    for n, v in pairs:
        args += ['-p', f'p.{n}:={v}']
    ctx = Context()
    rclpy.init(context=ctx, args=args, domain_id=next_domain_id())
    try:
        node = Node('probe', context=ctx, allow_undeclared_parameters=True,
                    automatically_declare_parameters_from_overrides=True)
        try:
            return {n: _plain(node.get_parameter(n).value)
                    for p in ('p', 'f') for n in (f'{p}.{m}' for m, _ in pairs)}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def _plain(v):
    return list(v) if not isinstance(v, (bool, int, float, str)) else v


def _same(a, b):
    """Equal values of the same Python type (NaN equals NaN), lists element by element."""
    if isinstance(a, list) or isinstance(b, list):
        return isinstance(a, list) and isinstance(b, list) and len(a) == len(b) and \
            all(_same(x, y) for x, y in zip(a, b))
    if type(a) is not type(b):
        return False
    return a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))


def _generator_read(tmp_path, pairs):
    """The generator's reading: ``-p`` (parse_override) and ``--params-file`` (load_values)."""
    from rigidrot_ros.run.generate import load_values, parse_override
    path = tmp_path / 'gen.yaml'
    path.write_text('attitude_node:\n  ros__parameters:\n' +
                    ''.join(f'    {n}: {v}\n' for n, v in pairs))
    from_file = load_values(str(path))
    out = {}
    for n, v in pairs:
        name, value = parse_override(f'{n}:={v}')
        out['p.' + name] = value
        out['f.' + n] = from_file[n]
    return out


def test_the_generator_reads_every_notation_as_rcl_does(tmp_path):
    pairs = [(f'v{i}', v) for i, v in enumerate(NOTATIONS)]
    rcl = _rcl_read(tmp_path, pairs)
    ours = _generator_read(tmp_path, pairs)
    wrong = {k: (NOTATIONS[int(k.split('.v')[1])], rcl[k], ours[k]) for k in rcl
             if not _same(rcl[k], ours[k])}
    assert not wrong, wrong
    assert _same(rcl['p.v0'], 2e-4) and _same(rcl['f.v9'], math.nan)     # the table's sense


@pytest.mark.parametrize('value', REFUSED)
def test_a_list_of_mixed_types_is_refused_by_rcl_and_the_generator(tmp_path, value):
    import rclpy
    from rclpy.context import Context
    from rigidrot_ros.run.generate import GenerationError, load_values, parse_override
    ctx = Context()
    with pytest.raises(Exception, match='Sequence should be of same type'):
        rclpy.init(context=ctx, args=['probe', '--ros-args', '-p', f'x:={value}'])
    with pytest.raises(GenerationError, match='ROS reads a list as one type'):
        parse_override(f'torque:={value}')
    path = tmp_path / 'mixed.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    torque: {value}\n')
    with pytest.raises(GenerationError, match='line 3.*ROS reads a list as one type'):
        load_values(str(path))


def _spec(tmp_path, overrides):
    path = tmp_path / 'spec.yaml'
    path.write_text('seed: 1\nruns: 2\nduration: 1e0\nbase:\n  overrides:\n' +
                    ''.join(f'    {n}: {v}\n' for n, v in overrides) +
                    'estimator:\n  factory: rigidrot_ros.estimators.mekf:make\n'
                    '  params: {sigma_v: 1.7e-4, sigma_u: 2.0e-5, bias_sigma: 2.0e-3}\n')
    return path


def test_node_generator_and_campaign_read_real_parameters_alike(tmp_path):
    """The notations users write, on real parameters: one value in all three, accepted."""
    from rigidrot_ros.campaign.spec import load_spec
    from rigidrot_ros.run import params
    from rigidrot_ros.run.generate import prepare_run
    rcl = _rcl_read(tmp_path, REAL)
    ours = _generator_read(tmp_path, REAL)
    spec = load_spec(str(_spec(tmp_path, REAL)))
    assert spec['duration'] == 1.0
    campaign = spec['base']['values']
    for name, text in REAL:
        for where in ('p.', 'f.'):
            assert _same(rcl[where + name], ours[where + name]), (name, text, where)
        assert _same(rcl['p.' + name], campaign[name]), (name, text, campaign[name])
        # the node's validator gives the same checked value from rcl's and from ours
        assert params.check(name, rcl['p.' + name]) == params.check(name, campaign[name])
    prepare_run({n: campaign[n] for n, _ in REAL})          # accepted, as by the node


@pytest.mark.parametrize('name, text', [('imu.gyro_noise_density', 'nan'),
                                        ('publish_rate', '.inf'),
                                        ('imu.seed', '1e3')])
def test_a_value_the_node_refuses_is_refused_with_the_node_s_reason(tmp_path, name, text):
    from rigidrot_ros.campaign.spec import load_spec, SpecError
    from rigidrot_ros.run import params
    from rigidrot_ros.run.generate import GenerationError, parse_override, prepare_run
    rcl = _rcl_read(tmp_path, [(name, text)])['p.' + name]
    with pytest.raises(ValueError) as node:
        params.check(name, rcl)
    with pytest.raises(GenerationError) as gen:
        prepare_run(dict([parse_override(f'{name}:={text}')]))
    with pytest.raises(SpecError) as camp:
        load_spec(str(_spec(tmp_path, [(name, text)])))
    assert str(node.value) == str(gen.value) and str(node.value) in str(camp.value)


def test_the_generated_defaults_file_reads_the_same_both_ways():
    """config/default.yaml as PyYAML and as rcl read it (the table writes 1.0e-12)."""
    from rigidrot_ros.run import rclyaml
    from rigidrot_ros.run.settings import find_config
    text = open(find_config(), encoding='utf-8').read()
    assert rclyaml.load(text) == yaml.safe_load(text)
