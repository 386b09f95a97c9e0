"""Matching one frame of two views: ONNX bundles and their frame checks, the learned association and
its typed run (learned_pipeline), the appearance and camera checks, the top camera's refinement, and
the site bundle that ``xvmatch adapt`` writes.

May import the linking and adaptation stages of inference (and core, geometry, cues, formats and
datasets).
"""
