"""Command-line tools (thin mains): echo, record, reindex, replay, compare, demo estimator."""
