"""Tests written to kill mutants of accrue/learner/agent.py, td3.py and sac.py that survived mutmut's second
sweep (docs/MUTATION.md). Each test's docstring names the mutmut ids it kills.
"""
