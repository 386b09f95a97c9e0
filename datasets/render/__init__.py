"""Pixels of the rendered scenes: people's bodies and clothes, the image renderer of a pair
(top and egocentric) and of several static cameras. May import ``core``, ``geometry``,
``formats`` and the scene simulators of ``datasets`` (``box_scene``, ``synthetic_scenes``,
``multicam_scenes``), never their writers."""
