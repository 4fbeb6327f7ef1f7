"""Monte Carlo campaigns: spec, runs, engines, aggregation, charts (issue 18)."""
