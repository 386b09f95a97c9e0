"""Inference without training code (no torch), in stages, each importing only those before it:
``linking`` (assignment with a non-association cost, tracklets) -> ``adaptation`` (site
adaptation) -> ``matching`` (learned association of one frame, its checks) -> ``tracks``
(tracking over time) -> ``views`` (several egocentric views, several cameras)."""
