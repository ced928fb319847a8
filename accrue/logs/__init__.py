"""Episode and run logs: MCAP episode files (Foxglove) and rerun recordings.

Import the submodules directly (`accrue.logs.mcap_episodes`, `accrue.logs.rerun_log`); this
package imports nothing heavy so the CLI stays fast.
"""
