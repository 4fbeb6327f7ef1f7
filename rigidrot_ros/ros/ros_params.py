"""The parameter table in rclpy's terms: descriptors, unknown names (see ``run.params``)."""

import difflib

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType
from rclpy.exceptions import ParameterNotDeclaredException

from rigidrot_ros.run.params import BY_NAME

__all__ = ['descriptor', 'UnknownParameterError', 'warn_unknown_overrides', 'BUILTIN']

_TYPES = {'double': ParameterType.PARAMETER_DOUBLE,
          'double[]': ParameterType.PARAMETER_DOUBLE_ARRAY,
          'integer': ParameterType.PARAMETER_INTEGER, 'bool': ParameterType.PARAMETER_BOOL,
          'string': ParameterType.PARAMETER_STRING,
          'string[]': ParameterType.PARAMETER_STRING_ARRAY}
#: Parameters rclpy declares by itself (rclpy.time_source, rclpy.type_description_service).
BUILTIN = ('use_sim_time', 'start_type_description_service')


def descriptor(p):
    """Return the ``ParameterDescriptor`` of a table entry (a ``run.params.Param``).

    Description (with when a change applies), type, read_only, and the range of a double or
    an integer; dynamic typing, so that a wrong type reaches the validator and is named.
    """
    desc = ParameterDescriptor(description=p.full_description(), type=_TYPES[p.type],
                               read_only=p.read_only, dynamic_typing=True)
    if p.range is not None and p.type == 'double':
        desc.floating_point_range = [FloatingPointRange(from_value=float(p.range[0]),
                                                        to_value=float(p.range[1]))]
    if p.range is not None and p.type == 'integer':
        desc.integer_range = [IntegerRange(from_value=p.range[0], to_value=p.range[1],
                                           step=1)]
    return desc


class UnknownParameterError(ParameterNotDeclaredException):
    """A parameter name the node does not declare; the message names it and the known ones."""

    def __init__(self, names, known=None):
        known = sorted(BY_NAME) if known is None else known
        Exception.__init__(self, f'unknown parameter(s) {", ".join(map(str, names))}: '
                                 f'attitude_node declares {", ".join(known)}')


def warn_unknown_overrides(node):
    """Warn about ``-p name:=value`` overrides that name no parameter of ``node``.

    Returns the unknown names, sorted; each is logged with the closest known name.
    """
    known = set(BY_NAME) | set(BUILTIN)
    unknown = sorted(n for n in getattr(node, '_parameter_overrides', {})
                     if n not in known and not node.has_parameter(n))
    for name in unknown:
        close = difflib.get_close_matches(name, sorted(known), n=1)
        hint = f' (did you mean {close[0]}?)' if close else ''
        node.get_logger().warning(
            f'unknown parameter {name!r} ignored{hint}: attitude_node declares no such '
            f'parameter')
    return unknown
