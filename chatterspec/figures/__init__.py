"""Matplotlib figures (never imported by the numeric core): paper figure reproductions and study plots."""
