"""Scoring against the exact truth: decode estimates from a bag, compare, NEES.

``decode`` (messages of any scored type -> quaternions, rates and their covariances) and
``score`` (errors against the truth recomputed from the run description, NEES).
"""
