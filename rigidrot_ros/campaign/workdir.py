"""Machine-local claims of a run: its temporary directory, and its ROS domain.

A run's temporary directory is removed even when the process that made it is killed.

A campaign run works in ``$TMPDIR/rigidrot_campaign_run<index>_<random>`` (the bags it
generates and records). The process that owns it holds an exclusive ``flock`` on the
``.owner.lock`` file inside for as long as it lives; the kernel drops that lock when the
process ends, however it ends (SIGKILL of a Dask worker, a machine's OOM killer), and
only then. :func:`sweep_work_dirs` removes every such directory whose lock it can take:
each run calls it before making its own, and the client after the campaign, so a worker
killed on a machine leaves nothing behind once a run or a campaign comes next there.

The directory is made under a hidden name, locked, then renamed into place (rename is
atomic), so a sweep never sees a directory whose owner has not locked it yet. Directories
of other names, and those of other users (they cannot be opened), are left alone.

A ROS run claims a ``ROS_DOMAIN_ID`` no other run on the machine holds
(:func:`claim_domain`, one lock file per id): the paced path's session and the replay path
of :mod:`rigidrot_ros.campaign.run` both claim theirs here.
"""

import fcntl
import os
import shutil
import tempfile
import time

from rigidrot_ros.campaign.failure import RunFailed

__all__ = ['WorkDir', 'claim_work_dir', 'sweep_work_dirs', 'PREFIX', 'LOCK_NAME', 'claim_domain',
           'DOMAIN_WAIT_S']

#: Name prefix of a run's directory in the temporary directory.
PREFIX = 'rigidrot_campaign_run'
#: The lock file inside it.
LOCK_NAME = '.owner.lock'
_NEW = '.rigidrot_campaign_new_'
#: A hidden directory this old was left by a process killed between mkdtemp and rename.
_STALE_NEW_S = 3600.0


class WorkDir:
    """A claimed run directory: ``path``; :meth:`release` removes it."""

    def __init__(self, path, lock):
        self.path = path
        self._lock = lock

    def release(self):
        """Remove the directory and drop its lock."""
        shutil.rmtree(self.path, ignore_errors=True)
        if self._lock is not None:
            self._lock.close()
            self._lock = None


def claim_work_dir(index, root=None):
    """Make and lock a new directory for run ``index`` under ``root`` (the temp dir)."""
    root = root or tempfile.gettempdir()
    sweep_work_dirs(root)
    tmp = tempfile.mkdtemp(prefix=_NEW, dir=root)
    lock = open(os.path.join(tmp, LOCK_NAME), 'w')
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = os.path.join(root, f'{PREFIX}{int(index)}_{os.path.basename(tmp)[len(_NEW):]}')
        os.rename(tmp, path)
    except BaseException:
        lock.close()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return WorkDir(path, lock)


def sweep_work_dirs(root=None):
    """Remove the run directories under ``root`` whose owner has died; how many."""
    root = root or tempfile.gettempdir()
    try:
        names = os.listdir(root)
    except OSError:
        return 0
    removed = 0
    for name in names:
        path = os.path.join(root, name)
        if name.startswith(PREFIX):
            try:
                lock = open(os.path.join(path, LOCK_NAME))
            except OSError:                     # not ours, or not a run directory
                continue
            with lock:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:                 # its owner lives
                    continue
                shutil.rmtree(path, ignore_errors=True)
                removed += 1
        elif name.startswith(_NEW):
            try:
                old = time.time() - os.stat(path).st_mtime > _STALE_NEW_S
            except OSError:
                continue
            if old:
                shutil.rmtree(path, ignore_errors=True)
                removed += 1
    return removed


#: Seconds a run waits for a free ROS domain.
DOMAIN_WAIT_S = 600.0


def claim_domain(base, span):
    """Claim a ROS_DOMAIN_ID in ``[base, base + span)``: ``(domain, locked file)``.

    One lock file per id (``flock``), so no other run on this machine holds it while the
    file is open; waits :data:`DOMAIN_WAIT_S` at most for one to be free (RunFailed).
    """
    root = os.path.join(tempfile.gettempdir(), f'rigidrot_campaign_domains_{os.getuid()}')
    os.makedirs(root, exist_ok=True)
    end = time.monotonic() + DOMAIN_WAIT_S
    while True:
        for d in range(base, base + span):
            fh = open(os.path.join(root, f'{d}.lock'), 'w')
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                fh.close()
                continue
            return d, fh
        if time.monotonic() > end:
            raise RunFailed(f'no free ROS domain in [{base}, {base + span}) for '
                            f'{DOMAIN_WAIT_S:g} s')
        time.sleep(0.2)
