"""ROS 2 message definitions as MCAP ``ros2msg`` schema text, from the installed .msg files.

The text is the type's own .msg followed by each dependency, separated as rosbag2 does:
a line of 80 '=' and ``MSG: pkg/Type``.
"""

import os
import re
import sys

__all__ = ['schema_text', 'find_msg_file']

_PRIMITIVES = {
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring', 'time', 'duration',
}
_SEP = '=' * 80


def _prefixes():
    out = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return out + [sys.prefix]


def find_msg_file(type_name):
    """Path of the .msg file of ``pkg/msg/Type`` (or ``pkg/Type``)."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        pkg, name = parts[0], parts[2]
    elif len(parts) == 2:
        pkg, name = parts
    else:
        raise ValueError(f'not a message type name: {type_name!r}')
    for prefix in _prefixes():
        path = os.path.join(prefix, 'share', pkg, 'msg', name + '.msg')
        if os.path.isfile(path):
            return path
    raise FileNotFoundError(f'no definition of {pkg}/msg/{name} under {_prefixes()}')


def _deps(pkg, text):
    out = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line or re.match(r'^\S+\s+\w+\s*=', line):
            continue                                  # blank, or a constant
        ftype = re.sub(r'\[.*\]$', '', line.split()[0])
        ftype = re.sub(r'<=\d+$', '', ftype)          # bounded strings
        if ftype in _PRIMITIVES:
            continue
        if ftype == 'Header':
            out.append('std_msgs/Header')
        elif '/' in ftype:
            p, n = ftype.split('/')[0], ftype.split('/')[-1]
            out.append(f'{p}/{n}')
        else:
            out.append(f'{pkg}/{ftype}')
    return out


def schema_text(type_name):
    """Return the ``ros2msg`` schema text of ``pkg/msg/Type`` with its dependencies."""
    with open(find_msg_file(type_name), encoding='utf-8') as fh:
        main = fh.read()
    pkg = type_name.split('/')[0]
    parts = [main.rstrip('\n')]
    seen = set()
    queue = _deps(pkg, main)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        with open(find_msg_file(dep), encoding='utf-8') as fh:
            text = fh.read()
        parts.append(f'{_SEP}\nMSG: {dep}\n{text.rstrip(chr(10))}')
        queue.extend(_deps(dep.split('/')[0], text))
    return '\n'.join(parts) + '\n'
