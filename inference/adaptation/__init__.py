"""Site adaptation of the appearance cue: pairs mined from a site's unlabelled video (no
identities), the adaptation map fitted on them, its file and its verification AUC.

May import the linking stage of inference (and core, geometry, cues, formats and datasets).
"""
