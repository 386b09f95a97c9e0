"""Linking boxes, what every later stage shares: one frame's assignment with a non-association
cost (geometric-priors Eqs. 1-2) and the matcher's verdict on a frame, and tracklets within one
view (IoU links over a clip).

The first stage of inference: may import no other stage of it (only core, geometry, cues, formats
and datasets).
"""
