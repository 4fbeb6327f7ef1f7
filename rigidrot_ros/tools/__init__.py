"""Command-line tools: echo, record/replay/compare (thin mains over the library)."""
