"""The core is pure math: it imports and solves with rclpy absent."""

import subprocess
import sys
import textwrap


def test_core_imports_without_rclpy():
    code = textwrap.dedent('''
        import sys

        class Block:
            def find_spec(self, name, path=None, target=None):
                if name == 'rclpy' or name.startswith('rclpy.'):
                    raise ImportError('rclpy is blocked in this test')

        sys.meta_path.insert(0, Block())
        from rigidrot_ros.core import Scene, solve
        sol = solve(Scene(inertia=(2, 2, 1), torque=(0, 0, 0.1), omega0=(0.3, -0.2, 0.5)))
        sol.at([0.0, 1.0])
        from rigidrot_ros.runtime.ahead import Lookahead     # the node's pure part too
        la = Lookahead(sol, lambda k: 0.01 * k, 0.01)
        la.get(0)
        la.refill(0)
        assert not any(m == 'rclpy' or m.startswith('rclpy.') for m in sys.modules)
        print('ok')
    ''')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith('ok')
