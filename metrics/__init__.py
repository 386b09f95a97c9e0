"""Scores, computed from counts: cross-view association (CVIDF1, CVMA, Eq. 9), tracks (CVIDF1, IDF1
to HOTA), several views, multi-camera association, and confidence intervals. Training, inference
and evaluation may all import it.

May import core, geometry, cues and formats.
"""
