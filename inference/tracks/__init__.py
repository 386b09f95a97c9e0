"""Tracking over time (CVMHAT Sec. 3.3-3.5): edge weights of the four-cluster graph, its
mixed-integer program and spectral relaxation, appearance over tracklets, stitching of clips, and
the track run.

May import the linking, adaptation and matching stages of inference (and core, geometry, cues,
formats and datasets).
"""
