"""Make the documentation's pictures of the view, through the tested headless path.

``python -m rigidrot_ros.view.docshot -o doc`` runs a small Monte Carlo campaign of the
reference MEKF (``doc/campaigns/mekf_tuned.yaml``'s scene and tuning, fewer and shorter
runs), opens one run in ``rigidrot_view`` and screenshots it in headless Chromium
(:func:`rigidrot_ros.view.browser.screenshot`): ``view.png``; then the campaign alone:
``view_campaign.png``. Nothing is drawn by hand; the same command gives the same data
(seeded), the pixels may differ by the renderer's version.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time

import yaml

from rigidrot_ros.runtime.processes import script

__all__ = ['main']

SPEC = {
    'name': 'MEKF tuned (docs)', 'seed': 2024, 'runs': 12, 'duration': 20.0,
    'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True,
                           'imu.gyro_noise_density': 1.7e-4, 'imu.gyro_random_walk': 2.0e-5}},
    'dispersions': {'attitude0': 'uniform',
                    'omega0': {'mean': [0.3, -0.2, 0.5], 'sigma': 0.05},
                    'imu.gyro_bias': {'mean': [0.0, 0.0, 0.0], 'sigma': 2.0e-3}},
    'estimator': {'factory': 'rigidrot_ros.estimators.mekf:make',
                  'params': {'sigma_v': 1.7e-4, 'sigma_u': 2.0e-5, 'bias_sigma': 2.0e-3}},
}


def _free_port():
    import socket
    with socket.socket() as s:
        s.bind(('', 0))
        return s.getsockname()[1]


def _campaign_drawn(img):
    """Whether the Monte Carlo NEES line (its colour) and the ANEES bars are drawn."""
    import numpy as np

    from rigidrot_ros.view.rr_log import ESTIMATE_COLORS
    d = np.abs(img[..., :3].astype(int) - np.asarray(ESTIMATE_COLORS[1])).max(axis=2)
    return int((d <= 60).sum()) >= 2000


def _shot(args, out, size):
    from rigidrot_ros.view.browser import screenshot
    web, grpc = _free_port(), _free_port()
    proc = subprocess.Popen([script('rigidrot_view')] + args + ['--port', str(web),
                                                                '--grpc-port', str(grpc)],
                            stderr=subprocess.PIPE, text=True)
    try:
        url = None
        end = time.monotonic() + 300
        while url is None and time.monotonic() < end:
            line = proc.stderr.readline()
            if not line and proc.poll() is not None:
                raise RuntimeError(f'rigidrot_view exited with status {proc.returncode}')
            if 'serving the view at ' in line:
                url = line.split('serving the view at ')[1].split(' (')[0]
        if url is None:
            raise RuntimeError('rigidrot_view did not serve in 300 s')
        kw = {} if '--run' in args else {'ready': _campaign_drawn}
        _, secs, refused = screenshot(url, out, size=size, **kw)
        print(f'{out}: drawn in {secs:.1f} s ({len(refused)} requests to other hosts '
              f'refused)', file=sys.stderr)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)


def main(argv=None):
    """Write ``view.png`` and ``view_campaign.png`` into ``-o``."""
    ap = argparse.ArgumentParser(prog='python -m rigidrot_ros.view.docshot',
                                 description=__doc__.splitlines()[0])
    ap.add_argument('-o', '--out', default='doc', help='directory for the pictures')
    ap.add_argument('--run', type=int, default=3, help='the run to open (default 3)')
    opts = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='rigidrot_docshot_') as tmp:
        spec = os.path.join(tmp, 'spec.yaml')
        with open(spec, 'w', encoding='utf-8') as fh:
            yaml.safe_dump(SPEC, fh)
        camp = os.path.join(tmp, 'camp')
        subprocess.run([script('rigidrot_campaign'), spec, '-o', camp, '--quiet'],
                       check=True)
        _shot([camp, '--run', str(opts.run)], os.path.join(opts.out, 'view.png'),
              (1400, 820))
        _shot([camp], os.path.join(opts.out, 'view_campaign.png'), (1100, 620))
    return 0


if __name__ == '__main__':
    sys.exit(main())
