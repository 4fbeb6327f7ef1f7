"""The shipped parameter files: every one loads and selects the model its comment names."""

import pytest

from rigidrot_ros.core import solve
from rigidrot_ros.run.settings import find_config, load_defaults, scene_from_params

PRESETS = {
    'default.yaml': 'axial-torque',
    'torque_free.yaml': 'torque-free-axisymmetric',
    'sphere_oblique.yaml': 'sphere',
    'axial_torque.yaml': 'axial-torque',
    'transverse_virtual.yaml': 'transverse-virtual',
    'transverse_body.yaml': 'transverse-body',
    'torque_free_triaxial.yaml': 'torque-free-triaxial',
    'air_bearing.yaml': 'torque-free-axisymmetric',
}


@pytest.mark.parametrize('name, model', sorted(PRESETS.items()))
def test_preset_selects_its_model(name, model):
    params = load_defaults(find_config(name))
    assert solve(scene_from_params(params)).model == model


def test_default_file_declares_every_node_parameter():
    from rigidrot_ros.run.params import BY_NAME
    assert set(load_defaults()) == set(BY_NAME)


def test_bad_params_files_are_named(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('just text\n')
    with pytest.raises(ValueError, match='not a ROS 2 params file'):
        load_defaults(str(bad))
    bad.write_text('node:\n  other: 1\n')
    with pytest.raises(ValueError, match='no ros__parameters'):
        load_defaults(str(bad))
    with pytest.raises(FileNotFoundError, match='nothing.yaml'):
        find_config('nothing.yaml')


def test_package_xml_declares_every_ros_package_the_code_imports():
    """Each ROS package imported (ast, not grep) is an exec_depend of package.xml."""
    import ast
    from pathlib import Path
    import xml.etree.ElementTree as ET
    root = Path(__file__).resolve().parents[2]
    deps = {e.text for e in ET.parse(root / 'package.xml').getroot().iter('exec_depend')}
    ros = ('rclpy', 'builtin_interfaces', 'rcl_interfaces', 'rosgraph_msgs')
    imported = set()
    for path in (root / 'rigidrot_ros').rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ''] if isinstance(node, ast.ImportFrom) and not node.level
                     else [])
            for name in names:
                top = name.split('.')[0]
                if top.endswith(('_msgs', '_srvs')) or top in ros:
                    imported.add(top)
    assert {'nav_msgs', 'sensor_msgs', 'std_msgs', 'visualization_msgs'} <= imported
    assert imported - deps == set()


def test_default_yaml_and_parameters_page_are_generated_from_the_table():
    """config/default.yaml and doc/parameters.md are exactly what the table generates."""
    from pathlib import Path
    from rigidrot_ros.run import params
    root = Path(__file__).resolve().parents[2]
    fix = 'regenerate: python -m rigidrot_ros.run.params --yaml > config/default.yaml'
    assert (root / 'config' / 'default.yaml').read_text(encoding='utf-8') == \
        params.yaml_text(), fix
    page = (root / 'doc' / 'parameters.md').read_text(encoding='utf-8')
    assert page == params.markdown_text(), 'regenerate with --markdown > doc/parameters.md'
    assert [line for line in page.splitlines() if line.startswith('# ')] == \
        ['# Parameters of attitude_node']                          # one MyST title


def test_table_yaml_help_and_page_agree_on_every_parameter():
    """Each name, default, range and 'applies' appears where it should, read back."""
    import yaml
    from rigidrot_ros.run import params
    from rigidrot_ros.ros.cli import usage
    assert load_defaults() == params.defaults()                # the YAML as ROS reads it
    raw = yaml.safe_load(params.yaml_text())['/**']['ros__parameters']
    assert raw['imu']['rate'] == 0.0 and raw['tol'] == 1e-12   # nested, typed as floats
    text, page = usage(), params.markdown_text()
    for p in params.PARAMS:
        assert f'  {p.name} [{p.default!r}' in text, p.name
        assert p.full_description().split()[0] in text
        row = next(line for line in page.splitlines() if line.startswith(f'| `{p.name}` |'))
        assert f'| {p.applies} |' in row and (p.allowed() or '') in row, row
        assert p.check(p.default) == p.default or p.type == 'double[]'
    assert text.count('range [0.001, 10000]') == 1             # publish_rate (the sensors: 0 or)
    assert params.BY_NAME['imu.rate'].allowed() == '0 or [0.001, 10000]'


def test_each_validator_names_its_parameter_and_its_rule():
    import math
    from rigidrot_ros.run import params
    cases = [('publish_rate', 2e4, '[0.001, 10000] Hz'), ('publish_rate', True, 'number'),
             ('tol', 0, '[2e-14, 1] rad'), ('time_scale', math.nan, 'time_scale'),
             ('imu.rate', 5e-4, '0 (= publish_rate)'), ('qos_depth', 0, '[1, 10000]'),
             ('imu.seed', -1, '[0, 2^63 - 1]'), ('record', 1, 'true or false'),
             ('frame_id', '', 'non-empty'), ('backend', 'gpu', "one of ('auto'"),
             ('inertia', [1.0, 2.0], 'must have 3 components, got 2'),
             ('record_topics', 'a', 'list'),
             ('inertia', [1, 'a', 1], "inertia[1] must be a real number, got 'a'"),
             ('inertia', 'abc', 'inertia must be a list of 3 numbers'),
             ('omega0', [0, 10 ** 400, 0], 'omega0[1] = 1000'),
             ('omega0', [0, 10 ** 400, 0], 'beyond the float64 range')]
    for name, value, words in cases:
        with pytest.raises(ValueError, match=None) as exc:
            params.check(name, value)
        assert str(exc.value).startswith(f'parameter {name}') and words in str(exc.value), \
            (name, value, str(exc.value))
    assert params.check('imu.rate', 0) == 0.0 and params.check('qos_depth', 10) == 10
    with pytest.raises(ValueError, match='unknown parameter'):
        params.check('publish-rate', 5.0)


def test_the_generator_entry_point_prints_each_text(capsys):
    from rigidrot_ros.run import params
    assert params.main(['--yaml']) == 0
    assert capsys.readouterr().out == params.yaml_text()
    assert params.main(['--markdown']) == 0
    assert capsys.readouterr().out == params.markdown_text()
    assert params.main(['--bogus']) == 2
