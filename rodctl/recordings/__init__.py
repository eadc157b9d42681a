"""Recordings made outside rodctl: readers, time sync and import into a rodctl run folder.

docs/recordings.md describes rodctl's dataset format (`points`: per-frame tracked points plus
one or two end-effector poses) and the commands that read it (`rodctl import`,
`rodctl estimate`).
"""
