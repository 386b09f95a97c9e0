"""Several views at once: one top view and several egocentric views (joint assignment with cycle
consistency, multi-ego tracking) and several static cameras (multicam: trajectory association on the
ground plane).

May import the linking, adaptation, matching and tracks stages of inference (and core, geometry,
cues, formats and datasets).
"""
