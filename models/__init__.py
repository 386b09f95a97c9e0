"""Torch modules of the learned matcher: appearance, geometry encoder, fusion, losses."""
