"""The commands of ``xvmatch``, one module per command: :mod:`xvmatch.cli` builds its parser
from them.

Each command module adds its parser (``add_<command>_parser``), reads its options from the parsed
arguments, checks them and runs the library; the options and argument types several commands
share are defined once, in ``_options`` and ``_types`` (``_model``: the learned matcher's options,
``_cameras``: ``--top-view`` and the calibrated cameras' options, ``_image_size``: the note on an
assumed image size). The commands that make data and models
(``synth``, ``show``, ``noise``, ``baseline``, ``ablate``, ``fit-geometry``, ``train``,
``export``) are in :mod:`xvmatch.commands.lab`. The commands may import every folder of the
package, never :mod:`xvmatch.cli`.
"""
