"""Tests written to kill mutants of accrue/metrics.py that survived mutmut's second sweep (docs/MUTATION.md).

Each test's docstring names the mutmut ids it kills; every expected value is computed by hand.
"""
