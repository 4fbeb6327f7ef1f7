"""Benchmarks: the exact solution against the integrators a user would otherwise pick.

``rigidrot_bench`` (:mod:`.run`) loops over the parts of :mod:`.registry`, each a module
here: work-precision, horizon, stability and its cross-check, speed ratios against
DOP853, the envelope, the triaxial body, random access, offline generation, the node's
cost per tick, the node at kHz rates (with :mod:`.stalls`, a probe of the machine's own
stalls), the soak and the filter leaderboard (:mod:`.leaderboard`, with its cells in
:mod:`.leaderboard_cells`, its table in :mod:`.leaderboard_report` and its charts in
:mod:`.leaderboard_charts`). :mod:`.driver` runs them and writes results, charts and
Markdown tables (:mod:`.common`, :mod:`.charts`); :mod:`.peers` holds the integrators
compared against.
"""
