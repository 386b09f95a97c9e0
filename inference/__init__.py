"""Inference without training code: assignment with a non-association cost, learned association."""
