"""Recordings made outside rodctl: readers, time sync and import into a rodctl run folder.

docs/recordings.md describes rodctl's dataset format (`points.py`: per-frame tracked points plus
one or two end-effector poses) and the other sources: ROS 2 bags (`ros2.py`: tracked points,
camera frames, poses; and the export of a run), image folders (`folder.py`), the colour
segmentation of real frames (`segment.py`). `importer.py` writes them as run folders that
`rodctl replay` and `rodctl estimate` read; `synthetic.py` makes a test recording.
"""
