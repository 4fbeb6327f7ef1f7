"""Benchmarks: the exact solution against the integrators a user would otherwise pick."""
