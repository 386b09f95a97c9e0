"""The plumbing every layer uses, at the bottom of the pipeline: atomic writes, output-path and
input-file checks, the folder marker, JSON text, typed record fields, array checks and the
worker pool.

Imports nothing else of xvmatch (and no torch).
"""
