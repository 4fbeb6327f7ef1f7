"""A run's temporary directory, removed even when the process that made it is killed.

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
"""

import fcntl
import os
import shutil
import tempfile
import time

__all__ = ['WorkDir', 'claim_work_dir', 'sweep_work_dirs', 'PREFIX', 'LOCK_NAME']

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
