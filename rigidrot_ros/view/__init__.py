"""rigidrot_view: the truth, estimates, their errors and NEES in a browser (rerun)."""
