"""rigidrot_generate loads what generation needs: no ROS message classes, no scipy.linalg.

A generation writes CDR (never a ROS message object; the markers' CDR template alone is
made from one, so they are off here) and numba's compiled code loads without its BLAS
probe (``runtime.jit.cached_load``), so neither is in the process after a run;
scipy.linalg still imports afterwards.
"""

import json
import subprocess
import sys

PROBE = r'''
import json, sys
from rigidrot_ros.tools.generate import main
code = main(['-o', sys.argv[1], '--duration', '1', '--quiet', '-p', 'imu.enable:=true',
             '-p', 'star_tracker.enable:=true', '-p', 'odom.enable:=true',
             '-p', 'transform.enable:=true'])
loaded = sorted(m for m in sys.modules if m.split('.')[0] in (
    'rclpy', 'std_msgs', 'geometry_msgs', 'sensor_msgs', 'nav_msgs', 'visualization_msgs',
    'builtin_interfaces') or m == 'scipy.linalg')
import scipy.linalg.cython_blas
print(json.dumps({'code': code, 'loaded': loaded}))
'''


def test_generation_loads_no_ros_messages_nor_scipy_linalg(tmp_path):
    proc = subprocess.run([sys.executable, '-c', PROBE, str(tmp_path / 'bag')],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got == {'code': 0, 'loaded': []}
    assert any(p.suffix == '.mcap' for p in (tmp_path / 'bag').iterdir())
