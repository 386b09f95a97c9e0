"""Pictures: one frame's cross-view matches and the canvases of box-only results.

May import core, geometry, cues and formats.
"""
