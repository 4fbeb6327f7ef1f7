"""Estimators that ship with rigidrot_ros (the campaign's reference MEKF)."""
