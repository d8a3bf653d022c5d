"""Trajectory evaluation: association, alignment, ATE/RPE, reports and plots."""
