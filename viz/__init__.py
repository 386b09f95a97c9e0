"""Pictures: one frame's cross-view matches, the canvases of box-only results and multicam's
bird's-eye view of the ground paths.

May import core, geometry, cues and formats.
"""
