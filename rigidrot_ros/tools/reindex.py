"""rigidrot_reindex: finish a torn bag (a killed recorder), like ``ros2 bag reindex``.

Every complete record of each .mcap file is kept (schemas, channels with their QoS
metadata, run descriptions, messages); an unfinished file is rewritten with its summary,
index and end magic (the original is kept as ``<file>.orig`` unless --no-backup), and
``metadata.yaml`` is rebuilt with the true message counts and times, so rosbags and the
rosbag2 tools read the bag. A finished file is left as it is.
"""

import sys

from rigidrot_ros.bag import BagError, reindex
from rigidrot_ros.tools.cli import OneLineParser

__all__ = ['main']


def main(argv=None):
    """Entry point of ``rigidrot_reindex``; returns the exit status."""
    ap = OneLineParser(prog='rigidrot_reindex', description=__doc__.splitlines()[0])
    ap.add_argument('bag', help='bag directory (or a single .mcap file)')
    ap.add_argument('--no-backup', action='store_true',
                    help='do not keep the torn originals as <file>.orig')
    opts = ap.parse_args(argv)
    try:
        out = reindex(opts.bag, backup=not opts.no_backup)
    except (BagError, OSError) as exc:
        print(f'rigidrot_reindex: {exc}', file=sys.stderr)
        return 2
    for note in out['notes']:
        print(f'rigidrot_reindex: {note}', file=sys.stderr)
    done = ', '.join(out['rewritten']) or 'nothing (every file was finished)'
    print(f'rewritten: {done}')
    print(f'messages: {sum(out["counts"].values())} {out["counts"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
