"""Handcrafted cues and costs (numpy): colour histograms, the spatial-distribution vectors, their
matching and (O, theta) search with its compiled kernels, the learned matcher's box features,
cost fusion, motion of boxes and the temporal offset.

May import core and geometry.
"""
