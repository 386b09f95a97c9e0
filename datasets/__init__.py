"""Readers of box files and synthetic scene generators."""
