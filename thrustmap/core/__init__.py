"""The shared ground under fitting, rig and protocols: units and scales, errors, the clock, safe
file writes, the strict JSON reader and the Ds log format (written by the rig, read by fitting).

Nothing here imports fitting, rig, protocols or the CLI.
"""
