"""Runtime mechanisms of a live run, with no ROS and no model of their own.

``lookahead`` (the batch worker that evaluates ahead of the publishing thread, and its
slack gate), ``collector`` (the garbage collector held out of the hot path),
``realtime`` (real-time scheduling policy where permitted), ``diagnostics`` (timing
windows reported on ``/diagnostics``) and ``switches`` (every environment variable the
package reads, read there alone).
"""
