"""The commands that make data and models: ``synth`` and ``show`` (simulated data), ``noise``
(detector noise on box files), ``baseline`` and ``ablate`` (the handcrafted baseline and its
studies), ``fit-geometry``, ``train`` and ``export`` (the learned matcher).

Like the other commands, they may import every folder of the package and the shared options of
:mod:`xvmatch.commands`, never :mod:`xvmatch.cli`.
"""
