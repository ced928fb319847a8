"""`accrue bench`: methods x task orderings x seeds, each cell an ordinary workflow run in one store.

Modules: spec (load and validate a spec, derive each cell's workflow and name), cell (run one cell
through the planner and runner), execute (Ray or serial execution, retries), progress (live display),
state (each cell's state from the store alone), report (tables, CSV, Markdown, plots over cells).
Ray, torch and matplotlib are imported inside functions, so importing this package is cheap.
"""
