"""One way to run and stop a node: spin until Ctrl-C, SIGTERM or a shutdown, then clean up."""

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

__all__ = ['spin_until_shutdown']


def spin_until_shutdown(node, loop=None):
    """Run ``loop(node)`` (default ``rclpy.spin``), then destroy the node and shut down.

    Ctrl-C, an external shutdown (SIGINT/SIGTERM through rclpy's handlers) and a publish
    that races the shutdown (``RCLError`` once the context is gone) end it quietly; any
    other error propagates. The node's ``destroy_node`` runs in every case, so a recorder
    finishes its file.
    """
    try:
        (loop or rclpy.spin)(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        if rclpy.ok():
            raise               # a real failure; after a shutdown it is only the race
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
