"""Parameter values read as ROS 2 reads them (rcl's YAML parameter parser), without rclpy.

``attitude_node`` gets its parameters from rcl, whose parser (``rcl_yaml_param_parser``,
``get_value`` in ``parse.c``) types each scalar of a params file or of ``-p name:=value``
by its own rules, not by YAML 1.1's (PyYAML's). So that one file means one run in the
node, the offline generator and a campaign, they read values here, by rcl's rules:

- a quoted scalar (``'...'``, ``"..."``) or one tagged ``!!str`` is a string;
- ``y Y yes Yes YES true True TRUE on On ON`` are true, ``n N no No NO false False FALSE
  off Off OFF`` false (other spellings, e.g. ``tRue``, are strings);
- then C's ``strtol(value, &end, 0)`` over the whole text, without overflow: an integer
  (``+1``, ``010`` is 8, ``0x10`` is 16, ``1_000`` is not one);
- then ``.nan .NaN .NAN``, ``[+-].inf .Inf .INF``, else C's ``strtod`` over the whole
  text, without overflow or underflow: a double (``2e-4``, ``1E5``, ``.5``, ``1.``,
  ``nan``, ``inf``, ``0x1p3``; ``1e400`` and ``1e-310`` are not doubles);
- anything else is a string (``~`` and ``null`` too: rcl has no null);
- a sequence holds values of one type, else it is refused as rcl refuses it ("Sequence
  should be of same type"): ``[0.1, 0, 0]`` mixes a double and integers (write ``0.0``);
  a sequence inside a sequence is read into it, as rcl reads ``[[1, 2]]`` as ``[1, 2]``.

``strtol`` and ``strtod`` are the C library's own, called through :mod:`ctypes`, so the
edge cases (ranges, hexadecimal floats, what counts as an underflow) are rcl's. An
integer given to a double parameter stays an integer here, as in rcl; the parameter
table's validators accept it (:mod:`rigidrot_ros.run.params`), as the node does.
"""

import ctypes
import ctypes.util
import math
import re

import yaml

__all__ = ['scalar', 'load', 'ParameterValueError', 'MIXED_HINT']

_TRUE = ('Y', 'y', 'yes', 'Yes', 'YES', 'true', 'True', 'TRUE', 'on', 'On', 'ON')
_FALSE = ('N', 'n', 'no', 'No', 'NO', 'false', 'False', 'FALSE', 'off', 'Off', 'OFF')
_SPECIAL = ('.nan', '.NaN', '.NAN', '.inf', '.Inf', '.INF', '+.inf', '+.Inf', '+.INF',
            '-.inf', '-.Inf', '-.INF')
_NULLS = ('', '~', 'null', 'Null', 'NULL')
_DECIMAL = re.compile(r'[-+]?[0-9]+')
#: One line of help for a sequence of mixed types (rcl's "Sequence should be of same type").
MIXED_HINT = ('ROS reads a list as one type: write every number of a list of doubles with '
              'a decimal point, e.g. [0.1, 0.0, 0.0], not [0.1, 0, 0]')
_TYPE_NAMES = {bool: 'bool', int: 'integer', float: 'double', str: 'string'}

_libc = ctypes.CDLL(ctypes.util.find_library('c'), use_errno=True)
_libc.strtol.restype = ctypes.c_long
_libc.strtol.argtypes = (ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int)
_libc.strtod.restype = ctypes.c_double
_libc.strtod.argtypes = (ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p))


class ParameterValueError(ValueError):
    """A value rcl would refuse (a sequence of mixed types, an empty value), one line."""


def _whole(fn, text, *args):
    """Return ``fn(text, &end, *args)`` if it read all of ``text`` without ERANGE, else None."""
    raw = text.encode('utf-8')
    if not raw or b'\0' in raw:
        return None
    buf = ctypes.create_string_buffer(raw)
    end = ctypes.c_char_p()
    ctypes.set_errno(0)
    value = fn(buf, ctypes.byref(end), *args)
    if ctypes.get_errno() != 0:
        return None
    used = ctypes.cast(end, ctypes.c_void_p).value - ctypes.addressof(buf)
    return value if 0 < used == len(raw) else None


def scalar(text, quoted=False):
    """Return the value of one scalar as rcl types it: bool, int, float or str.

    Parameters
    ----------
    text : str
        The scalar's text as YAML gives it (plain scalars are stripped by YAML).
    quoted : bool
        True for a quoted scalar (or one tagged ``!!str``): always a string.

    Examples
    --------
    >>> [scalar(t) for t in ('2e-4', '+1', '.5', 'yes', '010', '1_000')]
    [0.0002, 1, 0.5, True, 8, '1_000']
    """
    if quoted:
        return text
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    value = _whole(_libc.strtol, text, 0)
    if value is not None:
        return int(value)
    if text in _SPECIAL:
        value = math.nan if 'nan' in text.lower() else math.inf
        return -value if text.startswith('-') else value
    value = _whole(_libc.strtod, text)
    if value is not None:
        return float(value)
    return text


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with rcl's typing of scalars (see the module text)."""

    spec = False

    def resolve(self, kind, value, implicit):
        """Tag every untagged scalar plain: :meth:`construct_rcl` types it."""
        if kind is yaml.ScalarNode:
            return _PLAIN
        return super().resolve(kind, value, implicit)

    def construct_rcl(self, node):
        """Return a scalar's value as rcl types it (``!!str`` and quotes: a string)."""
        quoted = node.style in ('"', "'") or node.tag == 'tag:yaml.org,2002:str'
        if not quoted and node.value in _NULLS:
            if self.spec:
                return None
            if node.value == '':
                raise ParameterValueError(f'no value at line {node.start_mark.line + 1}')
        value = scalar(node.value, quoted)
        if self.spec and not quoted and isinstance(value, str) and _DECIMAL.fullmatch(value):
            return int(value)           # past int64: a number all the same (its range named)
        return value

    def construct_rcl_map(self, node):
        """Return a mapping whose keys are strings, as rcl's parameter names are."""
        if not isinstance(node, yaml.MappingNode):
            raise yaml.constructor.ConstructorError(
                None, None, f'expected a mapping, found {node.id}', node.start_mark)
        self.flatten_mapping(node)
        out = {}
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else \
                self.construct_object(key_node, deep=True)
            if not isinstance(key, str):
                raise ParameterValueError(f'a key at line {key_node.start_mark.line + 1} '
                                          'is not a name')
            out[key] = self.construct_object(value_node, deep=True)
        return out

    def construct_rcl_seq(self, node):
        """Return a sequence of one type (nested ones read into it), as rcl reads it."""
        items = []
        for child in node.value:
            value = self.construct_object(child, deep=True)
            if isinstance(value, list):
                items.extend(value)
            elif isinstance(value, dict) and not self.spec:
                raise ParameterValueError(f'a mapping inside a list at line '
                                          f'{child.start_mark.line + 1}')
            else:
                items.append(value)
        kinds = [type(v) for v in items if v is not None and not isinstance(v, dict)]
        if not self.spec and kinds and any(k is not kinds[0] for k in kinds):
            odd = next(k for k in kinds if k is not kinds[0])
            raise ParameterValueError(
                f'{_show(items)} mixes {_TYPE_NAMES[kinds[0]]} and {_TYPE_NAMES[odd]} '
                f'values (line {node.start_mark.line + 1}); {MIXED_HINT}')
        return items


def _show(items):
    return '[' + ', '.join(str(v) for v in items) + ']'


_PLAIN = 'tag:rigidrot_ros,2025:rcl'
_Loader.add_constructor(_PLAIN, _Loader.construct_rcl)
_Loader.add_constructor('tag:yaml.org,2002:str', _Loader.construct_rcl)
_Loader.add_constructor('tag:yaml.org,2002:map', _Loader.construct_rcl_map)
_Loader.add_constructor('tag:yaml.org,2002:seq', _Loader.construct_rcl_seq)
for _tag in ('null', 'bool', 'int', 'float', 'timestamp', 'binary'):
    # rcl ignores every tag but !!str: the text is typed by its rules
    _Loader.add_constructor(f'tag:yaml.org,2002:{_tag}', _Loader.construct_rcl)


class _SpecLoader(_Loader):
    spec = True


def load(text, spec=False):
    """Read a YAML document (a params file, a ``-p`` value, a campaign spec) as rcl does.

    Parameters
    ----------
    text : str or file
        The document.
    spec : bool
        A campaign spec, which rcl never reads: its scalars are typed by rcl's rules, but
        an empty value, ``~`` and ``null`` are None (its optional keys), a list may mix
        integers and doubles (a dispersion's ``low: [0, 0, 0.04]``) and a decimal integer
        past int64 is an integer (so that its range is named); rcl itself has no null
        (``~`` is a string, an empty value is refused), refuses mixed lists and reads
        such an integer as a double or a string; and a list may hold mappings (a spec's
        ``estimators:``), which a params file cannot.

    Raises
    ------
    ParameterValueError
        A sequence of mixed types or an empty value (not ``spec``), a key that is not a
        name; the message says where.
    yaml.YAMLError
        Text that is not YAML.
    """
    return yaml.load(text, Loader=_SpecLoader if spec else _Loader)  # noqa: S506 - safe
