"""Runtime mechanisms of a live run, with no ROS and no model of their own.

``ahead`` (every stream's samples evaluated ahead in batches), ``worker`` (the thread
that runs those batches off the publishing thread), ``gate`` (that worker held to the
publishing thread's slack), ``collector`` (the garbage collector held out of the hot path),
``realtime`` (real-time scheduling policy where permitted), ``diagnostics`` (timing
windows reported on ``/diagnostics``), ``switches`` (every environment variable the
package reads, read there alone), ``processes`` (a console script found and a child
process stopped as Ctrl-C would, for the tools that start nodes) and ``interrupt`` (an
exception raised into a running thread without leaving the interpreter's flag up, which
stalls a profiled thread: the gated worker) and ``jit`` (numba's compiled code loaded
from its cache without its compiler's registries nor its BLAS probe).
"""
