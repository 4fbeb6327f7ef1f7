"""The shipped parameter files: every one loads and selects the model its comment names."""

import pytest

from rigidrot_ros.core import solve
from rigidrot_ros.settings import find_config, load_defaults, scene_from_params

PRESETS = {
    'default.yaml': 'axial-torque',
    'torque_free.yaml': 'torque-free-axisymmetric',
    'sphere_oblique.yaml': 'sphere',
    'axial_torque.yaml': 'axial-torque',
    'transverse_virtual.yaml': 'transverse-virtual',
    'transverse_body.yaml': 'transverse-body',
    'torque_free_triaxial.yaml': 'torque-free-triaxial',
}


@pytest.mark.parametrize('name, model', sorted(PRESETS.items()))
def test_preset_selects_its_model(name, model):
    params = load_defaults(find_config(name))
    assert solve(scene_from_params(params)).model == model


def test_default_file_declares_every_node_parameter():
    from rigidrot_ros.params import BY_NAME
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
    root = Path(__file__).resolve().parents[1]
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
