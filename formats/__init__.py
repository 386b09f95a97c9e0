"""Readers and writers of the user's files: MOT box files and prediction CSVs, detections, camera
files (one or one per frame), image sizes, frame sources, person crops, track's offset record,
multicam's ground CSVs and output folder, and the CVMHAT dev split's location.

May import core, geometry and cues.
"""
