"""Command-line tools, thin mains over the packages below them.

``echo``, ``record``, ``reindex``, ``replay``, ``compare``, ``generate``, ``campaign``
and ``demo_estimator`` (the console scripts ``rigidrot_<name>``), ``cli``, the
conventions they share (one line and exit status 2 for a bad argument), and ``scripts``,
every console script's entry point (its program imported under a Ctrl-C guard).
"""
