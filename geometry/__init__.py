"""Cameras and handcrafted geometric cues (numpy only)."""
